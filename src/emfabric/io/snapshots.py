"""Snapshots: node positions, velocities and yarn damage at intervals.

Written twice over: ``snapshots.nc`` (xarray-readable, what the plotting code reads) and a
ParaView time series ``fabric.pvd`` + ``projectile.pvd`` over ``vtk/*.vtu`` files.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np
import xarray as xr

from emfabric._kernels.records import BODY_R0, BODY_ROWS, BODY_V, BODY_W, BODY_X
from emfabric.io.atomic import write_atomic
from emfabric.io.netcdf import (
    TIME_ATTRS,
    append_records,
    read_records,
    write_netcdf,
    xyz_coordinate,
)
from emfabric.sim.model import Model
from emfabric.sim.state import State


class Snapshots:
    """The snapshots of one run: each is written to vtk/*.vtu when taken; flush() appends the
    ones taken since the last flush to snapshots.nc and rewrites the .pvd collections."""

    def __init__(self, model: Model, out_dir: Path | None, times: list[float] | None = None):
        """times: the snapshots already on disk (a resumed run)."""
        self.model = model
        self.out_dir = out_dir
        self.times: list[float] = list(times or [])
        self.written = len(self.times)
        self._pending: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        # the projectile's surface in the body frame (its frame at t = 0)
        self._surface = None
        if model.has_body:
            pts, tris = model.geometry.mesh()
            self._surface = (pts @ model.body.frame, tris)

    @property
    def count(self) -> int:
        return len(self.times)

    def take(self, state: State) -> None:
        self.times.append(state.t)
        if self.out_dir is None:
            return
        snap = (state.t, state.node_x.T.copy(), state.node_v.T.copy(), state.seg_alpha.copy(),
                state.body.copy())
        self._pending.append(snap)
        self._write_vtk(len(self.times) - 1, snap)

    def _records(self, attrs: dict[str, str]) -> xr.Dataset:
        m = self.model
        times = np.array([p[0] for p in self._pending])
        x, v, alpha, body = (np.array([p[k] for p in self._pending]) for k in (1, 2, 3, 4))
        body = body.reshape(-1, BODY_ROWS, 3)
        return xr.Dataset(
            {
                "node_position": (("snapshot", "node", "xyz"), x,
                                  {"units": "m", "long_name": "node position"}),
                "node_velocity": (("snapshot", "node", "xyz"), v,
                                  {"units": "m s-1", "long_name": "node velocity"}),
                "yarn_damage": (("snapshot", "segment"), alpha,
                                {"units": "1", "long_name": "yarn damage α (1 intact, 0 broken)"}),
                "projectile_position": (("snapshot", "xyz"), body[:, BODY_X],
                                        {"units": "m", "long_name": "projectile centre of mass"}),
                "projectile_velocity": (("snapshot", "xyz"), body[:, BODY_V],
                                        {"units": "m s-1",
                                         "long_name": "projectile centre-of-mass velocity"}),
                "angular_velocity": (("snapshot", "xyz"), body[:, BODY_W],
                                     {"units": "rad s-1", "long_name":
                                      "projectile angular velocity (inertial frame)"}),
                "projectile_rotation": (("snapshot", "xyz", "body_axis"),
                                        body[:, BODY_R0:BODY_R0 + 3],
                                        {"units": "1",
                                         "long_name": "rotation matrix body -> inertial frame"}),
                "segment_nodes": (("segment", "end"), m.yarns.ends,
                                  {"units": "1",
                                   "long_name": "node indices of each yarn segment"}),
                "reference_position": (("node", "xyz"), m.nodes.x0.T,
                                       {"units": "m", "long_name": "node position at t = 0"}),
                "projectile_nose_body": (("xyz",), m.body.nose,
                                         {"units": "m", "long_name": "nose marker, body frame"}),
                **self._surface_variables(),
            },
            coords={
                "time": ("snapshot", times, TIME_ATTRS),
                "xyz": xyz_coordinate(),
            },
            attrs={**attrs, "grid_nx": m.nx, "grid_ny": m.ny,
                   "projectile_radius": m.body.radius if m.has_body else 0.0,
                   "projectile_shape": m.projectile_shape,
                   "projectile_size": m.geometry.bound if m.has_body else 0.0,
                   "has_projectile": int(m.has_body)},
        )

    def _surface_variables(self) -> dict:
        """The projectile's surface mesh (body frame), for plots and animations."""
        if self._surface is None:
            return {}
        pts, tris = self._surface
        return {
            "projectile_surface": (("surface_point", "xyz"), pts,
                                   {"units": "m", "long_name":
                                    "projectile surface points relative to the centre of "
                                    "mass, body frame"}),
            "projectile_surface_triangles": (("surface_triangle", "corner"), tris,
                                             {"units": "1", "long_name":
                                              "projectile surface triangles (point indices)"}),
        }

    def flush(self, attrs: dict[str, str]) -> None:
        """Append the snapshots taken since the last flush to snapshots.nc (created with
        `attrs` by the first) and rewrite the .pvd collections."""
        if self.out_dir is None:
            return
        if self._pending:
            path = self.out_dir / "snapshots.nc"
            ds = self._records(attrs)
            if self.written == 0 or not path.exists():
                write_netcdf(ds, path, unlimited="snapshot")
            else:
                append_records(path, "snapshot", {
                    name: ds[name].values for name in ds.variables
                    if ds[name].dims[:1] == ("snapshot",)})
            self.written += len(self._pending)
            self._pending.clear()
        self._write_pvd("fabric")
        if self.model.has_body:
            self._write_pvd("projectile")

    def _write_vtk(self, k: int, snap: tuple) -> None:
        m = self.model
        folder = self.out_dir / "vtk"
        folder.mkdir(parents=True, exist_ok=True)
        _t, x, v, alpha, b = snap
        mesh = meshio.Mesh(
            points=x,
            cells=[("line", m.yarns.ends)],
            point_data={"velocity": v, "displacement": x - m.nodes.x0.T},
            cell_data={"damage": [alpha]},
        )
        write_atomic(folder / f"fabric_{k:05d}.vtu", lambda tmp: meshio.write(
            tmp, mesh, file_format="vtu", binary=True, compression=None))
        if self._surface is not None:
            pts, tris = self._surface
            rot = b[BODY_R0:BODY_R0 + 3]
            nose = rot @ m.body.nose
            world = pts @ rot.T + b[BODY_X]
            # +1 at the nose, −1 opposite: how each surface point lies along the nose axis
            along = (pts @ (m.body.nose / np.linalg.norm(m.body.nose))) / m.geometry.bound
            body_mesh = meshio.Mesh(
                points=world, cells=[("triangle", tris)],
                point_data={"nose_alignment": along,
                            "velocity": np.tile(b[BODY_V], (len(pts), 1))},
                field_data={"nose": nose},
            )
            write_atomic(folder / f"projectile_{k:05d}.vtu", lambda tmp: meshio.write(
                tmp, body_mesh, file_format="vtu", binary=True, compression=None))

    def _write_pvd(self, stem: str) -> None:
        lines = ['<?xml version="1.0"?>',
                 '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                 "  <Collection>"]
        for k, t in enumerate(self.times):
            name = quoteattr(f"vtk/{stem}_{k:05d}.vtu")
            lines.append(f'    <DataSet timestep="{t:.9e}" part="0" file={name}/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        text = "\n".join(lines)
        write_atomic(self.out_dir / f"{stem}.pvd", lambda tmp: tmp.write_text(text))


def snapshot_times(path: Path, count: int) -> list[float]:
    """Times of the first `count` snapshots in snapshots.nc (a resumed run's snapshots)."""
    if count == 0:
        return []
    return [float(t) for t in read_records(path, "snapshot", count)["time"]]


def truncate_snapshots(path: Path, count: int) -> None:
    """Keep only the first `count` snapshots of snapshots.nc (atomically): those written after
    the checkpoint a run resumes from are taken again."""
    if count == 0:
        path.unlink(missing_ok=True)
        return
    with xr.open_dataset(path, mask_and_scale=False) as ds:
        if ds.sizes["snapshot"] == count:
            return
        part = ds.isel(snapshot=slice(0, count)).load()
    write_netcdf(part, path, unlimited="snapshot")
