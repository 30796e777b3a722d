"""Snapshots: node positions, velocities and yarn damage at intervals.

Written twice over: ``snapshots.nc`` (xarray-readable, what the plotting code reads) and a
ParaView time series ``fabric.pvd`` + ``projectile.pvd`` over ``vtk/*.vtu`` files.

A pack of plies: snapshots.nc holds every node and segment of every ply, with `node_ply` and
`segment_ply` (1 is the top ply, at z = 0: the numbering of the history's `ply` coordinate and
of the ParaView `ply` fields), `node_carries_load` and `segment_carries_load` (0 for the parts
of a rotated ply, clipped to the frame, that carry nothing: nodes of mass 0, segments of
stiffness 0), and the attributes `plies`, `ply_grid_nx`, `ply_grid_ny` (each ply's grid; a
ply's nodes are consecutive, in row-major order of its grid). `grid_nx`, `grid_ny` are ply 1's grid.

The fabric's .vtu files leave out what carries nothing (renumbering the points): they hold
the point arrays "ply" (1-based: 1 is the top ply), "node_index" (the node's index in
snapshots.nc), "velocity", "displacement", and the cell arrays "ply" (1-based),
"segment_index" (the segment's index in snapshots.nc), "damage".

Where the step kernel runs on one thread (``background=True``), the .vtu files of a snapshot
are written by a thread of their own while the run goes on (the step kernel releases the GIL),
each still atomically; ``wait()`` returns once every one taken is on disk, raising the first
write error, and ``flush()`` waits first, so the .pvd collections (and the checkpoint written
after them) list only files that are there. A threaded step kernel keeps the writes in line:
a busy thread beside it would make its barriers wait for a descheduled thread.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
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
    """The snapshots of one run: each is written to vtk/*.vtu when taken (by a thread of its
    own where `background`); flush() appends the ones taken since the last flush to
    snapshots.nc and rewrites the .pvd collections; close() when the run is done."""

    def __init__(self, model: Model, out_dir: Path | None, times: list[float] | None = None,
                 paraview: bool = True, background: bool = False):
        """times: the snapshots already on disk (a resumed run); paraview: write the .vtu and
        .pvd files (output.paraview); background: write them beside the run (module
        docstring)."""
        self.model = model
        self.out_dir = out_dir
        self.paraview = paraview
        self._writer: ThreadPoolExecutor | None = (
            ThreadPoolExecutor(1, thread_name_prefix="emfabric-vtu")
            if background and paraview and out_dir is not None else None)
        self._writing: list[Future] = []
        self.times: list[float] = list(times or [])
        self.written = len(self.times)
        self._pending: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        # the fabric's .vtu: the nodes and segments that carry load, points renumbered
        self._vtk_segments = np.flatnonzero(model.yarns.stiffness != 0)
        ends = model.yarns.ends[self._vtk_segments]
        keep = model.nodes.mass != 0
        keep[ends.ravel()] = True  # a point a shown segment ends on is always shown
        self._vtk_nodes = np.flatnonzero(keep)
        renumber = np.full(model.node_count, -1, dtype=np.int64)
        renumber[self._vtk_nodes] = np.arange(self._vtk_nodes.size)
        self._vtk_cells = renumber[ends]
        self._vtk_node_ply = (model.node_ply()[self._vtk_nodes] + 1).astype(np.int32)
        self._vtk_segment_ply = (model.segment_ply()[self._vtk_segments] + 1).astype(np.int32)
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
        if not self.paraview:
            return
        if self._writer is None:
            self._write_vtk(len(self.times) - 1, snap)
            return
        # a write that failed meanwhile stops the run here, as one in line would have
        done = [f for f in self._writing if f.done()]
        self._writing = [f for f in self._writing if not f.done()]
        for f in done:
            f.result()
        self._writing.append(self._writer.submit(self._write_vtk_quiet, len(self.times) - 1,
                                                 snap))

    def wait(self) -> None:
        """Return once every .vtu file taken so far is written; raise the first write's error
        (an OSError, as a write in line would)."""
        writing, self._writing = self._writing, []
        error: BaseException | None = None
        for f in writing:
            exc = f.exception()  # waits
            if exc is not None and error is None:
                error = exc
        if error is not None:
            raise error

    def close(self) -> None:
        """Wait for the .vtu writes (errors are the caller's to have seen through wait()) and
        end the writing thread."""
        if self._writer is not None:
            for f in self._writing:
                f.exception()
            self._writing = []
            self._writer.shutdown(wait=True)
            self._writer = None

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
                "node_ply": (("node",), (m.node_ply() + 1).astype(np.int32),
                             {"units": "1", "long_name": "ply of each node "
                              "(1 is the top one, at z = 0)"}),
                "segment_ply": (("segment",), (m.segment_ply() + 1).astype(np.int32),
                                {"units": "1", "long_name": "ply of each yarn segment "
                                 "(1 is the top one, at z = 0)"}),
                "node_carries_load": (("node",), (m.nodes.mass != 0).astype(np.int32),
                                      {"units": "1", "long_name":
                                       "1 for a node of the sheet, 0 for a node of a clipped "
                                       "ply outside the frame (mass 0, carries nothing)"}),
                "segment_carries_load": (("segment",),
                                         (m.yarns.stiffness != 0).astype(np.int32),
                                         {"units": "1", "long_name":
                                          "1 for a yarn segment of the sheet, 0 for one of a "
                                          "clipped ply that carries nothing (stiffness 0)"}),
                "projectile_nose_body": (("xyz",), m.body.nose,
                                         {"units": "m", "long_name": "nose marker, body frame"}),
                **self._surface_variables(),
            },
            coords={
                "time": ("snapshot", times, TIME_ATTRS),
                "xyz": xyz_coordinate(),
            },
            attrs={**attrs, **ply_attributes(m),
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
        self.wait()
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
        if not self.paraview:
            return
        self._write_pvd("fabric")
        if self.model.has_body:
            self._write_pvd("projectile")

    def _write_vtk_quiet(self, k: int, snap: tuple) -> None:
        # the writer thread's NumPy warnings as quiet as the run's (runner.loop._loop: errstate
        # is per thread)
        with np.errstate(all="ignore"):
            self._write_vtk(k, snap)

    def _write_vtk(self, k: int, snap: tuple) -> None:
        m = self.model
        folder = self.out_dir / "vtk"
        folder.mkdir(parents=True, exist_ok=True)
        _t, x, v, alpha, b = snap
        nodes, segments = self._vtk_nodes, self._vtk_segments
        mesh = meshio.Mesh(
            points=x[nodes],
            cells=[("line", self._vtk_cells)],
            point_data={"velocity": v[nodes], "displacement": (x - m.nodes.x0.T)[nodes],
                        "ply": self._vtk_node_ply,
                        "node_index": nodes.astype(np.int32)},
            cell_data={"damage": [alpha[segments]],
                       "ply": [self._vtk_segment_ply],
                       "segment_index": [segments.astype(np.int32)]},
        )
        write_atomic(folder / f"fabric_{k:05d}.vtu", lambda tmp: meshio.write(
            tmp, mesh, file_format="vtu", binary=True, compression=None))
        if self._surface is not None:
            pts, tris = self._surface
            rot = b[BODY_R0:BODY_R0 + 3]
            nose = rot @ m.body.nose
            arm = pts @ rot.T  # from the centre of mass
            world = arm + b[BODY_X]
            # +1 at the nose, −1 opposite: how each surface point lies along the nose axis
            along = (pts @ (m.body.nose / np.linalg.norm(m.body.nose))) / m.geometry.bound
            body_mesh = meshio.Mesh(
                points=world, cells=[("triangle", tris)],
                # each surface point's own velocity, v + ω × r (the spin shows)
                point_data={"nose_alignment": along,
                            "velocity": b[BODY_V] + np.cross(b[BODY_W], arm)},
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


def ply_attributes(model: Model) -> dict[str, object]:
    """snapshots.nc's grid attributes: `plies`, each ply's grid (`ply_grid_nx`, `ply_grid_ny`,
    int32 arrays) and ply 1's as `grid_nx`, `grid_ny` (the one grid of a single sheet)."""
    grids = np.array([model.ply_grid(p) for p in range(model.ply_count)], dtype=np.int32)
    return {"plies": np.int32(model.ply_count),
            "grid_nx": np.int32(grids[0, 0]), "grid_ny": np.int32(grids[0, 1]),
            "ply_grid_nx": grids[:, 0], "ply_grid_ny": grids[:, 1]}


def snapshot_times(path: Path, count: int) -> list[float]:
    """Times of the first `count` snapshots in snapshots.nc (a resumed run's snapshots)."""
    if count == 0:
        return []
    return [float(t) for t in read_records(path, "snapshot", count)["time"]]


def truncate_snapshots(path: Path, count: int, attrs: dict | None = None) -> None:
    """Keep only the first `count` snapshots of snapshots.nc (atomically): those written after
    the checkpoint a run resumes from are taken again. attrs: global attributes that replace
    the file's own of the same names (a run continued past its end: its scenario, with the
    later end_time, and its status), the file rewritten even at the same count."""
    if count == 0:
        path.unlink(missing_ok=True)
        return
    with xr.open_dataset(path, mask_and_scale=False) as ds:
        if ds.sizes["snapshot"] == count and attrs is None:
            return
        part = ds.isel(snapshot=slice(0, count)).load()
    if attrs is not None:
        part.attrs = {**part.attrs, **attrs}
    write_netcdf(part, path, unlimited="snapshot")
