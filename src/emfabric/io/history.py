"""History recorder: one record per accepted step -> xarray.Dataset -> netCDF (history.nc)."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np
import xarray as xr

from emfabric.io.netcdf import (
    CONVENTIONS,
    REFERENCES,
    TIME_ATTRS,
    append_records,
    read_records,
    write_netcdf,
    xyz_coordinate,
)
from emfabric.sim.diagnostics import COLUMNS, LAYOUT, PLY_RECORD, RECORD, ply_layout, row_width
from emfabric.sim.model import Model

VARIABLES = RECORD
INTEGER_VARIABLES = ("iterations", "rejected_steps", "force_evaluations", "contact_nodes",
                     "contact_segments", "broken_yarns")




class Recorder:
    """Stores history records (rows filled by emfabric.sim.diagnostics.measure) in a growing array
    (amortised O(1) append); computes nothing."""

    def __init__(self, rows: np.ndarray | None = None, plies: int = 1) -> None:
        """rows: records to start from (a resumed run's history so far); plies: the pack's
        plies (the rows' per-ply columns, diagnostics.row_width)."""
        self.count = 0 if rows is None else rows.shape[0]
        self._rows = np.empty((max(1024, 2 * self.count), row_width(plies)))
        if rows is not None:
            self._rows[: self.count] = rows

    def new_row(self) -> np.ndarray:
        """The next record, to be filled in place."""
        if self.count == self._rows.shape[0]:
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self.count += 1
        return self._rows[self.count - 1]

    @property
    def rows(self) -> np.ndarray:
        return self._rows[: self.count]

    def to_dataset(self, attrs: dict[str, str], start: int = 0) -> xr.Dataset:
        """Records start … count − 1 as an xarray Dataset."""
        return rows_to_dataset(self._rows[start: self.count], attrs)


NO_PROJECTILE = ("projectile_position", "projectile_velocity", "angular_velocity",
                 "projectile_nose", "tilt", "yaw")
"""The variables that describe the projectile itself: not a number in the history of a run
without one (projectile.shape = "none"; the attribute has_projectile = 0). Its momenta, kinetic
energy and contact force are 0, as the sums of the fabric and the projectile take them."""


def rows_to_dataset(rows: np.ndarray, attrs: dict[str, str]) -> xr.Dataset:
    """The records as a Dataset with these global attributes; where they say has_projectile =
    0, the NO_PROJECTILE variables are NaN (the rows hold the scenario's unused pose)."""
    body = bool(int(attrs.get("has_projectile", 1)))
    data = {}
    for name, (width, units, long_name) in VARIABLES.items():
        col = rows[:, LAYOUT[name]]
        meta = {"units": units, "long_name": long_name}
        if not body and name in NO_PROJECTILE:
            col = np.full(col.shape, np.nan)
            meta["comment"] = 'no projectile (projectile.shape = "none")'
        if width == 3:
            data[name] = (("time", "xyz"), col.copy(), meta)
        else:
            vals = col[:, 0].copy()
            if name in INTEGER_VARIABLES:
                vals = vals.astype(np.int64)
            data[name] = (("time",), vals, meta)
    coords = {"time": ("time", rows[:, 0].copy(), TIME_ATTRS), "xyz": xyz_coordinate()}
    plies = (rows.shape[1] - COLUMNS) // len(PLY_RECORD)
    for name, sl in ply_layout(plies).items():
        units, long_name = PLY_RECORD[name]
        vals = rows[:, sl].copy()
        if name != "max_deflection_per_ply":
            vals = vals.astype(np.int64)
        data[name] = (("time", "ply"), vals, {"units": units, "long_name": long_name})
    if plies:
        coords["ply"] = ("ply", np.arange(1, plies + 1, dtype=np.int32),
                         {"long_name": "ply, from the top (the side the projectile comes "
                                       "from)", "units": "1"})
    return xr.Dataset(data, coords=coords, attrs=dict(attrs))


def run_attributes(model: Model, status: str, end_reason: str, wall: float) -> dict:
    """Global attributes: package version, full scenario text, status."""
    from emfabric import __version__

    sc = model.scenario
    name = sc.name if sc is not None else "model built in Python"
    return {
        "title": f"emfabric run of scenario {name!r}",
        "Conventions": CONVENTIONS,
        "source": f"emfabric {__version__} (yarn-network impact simulation)",
        "references": REFERENCES,
        "emfabric_version": __version__,
        "scenario_name": name,
        "fabric_reference": fabric_reference(sc) if sc is not None else "",
        "has_projectile": int(model.has_body),
        "projectile_radius": model.body.radius if model.has_body else 0.0,
        "scenario": sc.to_toml() if sc is not None else "",
        "status": status,
        "end_reason": end_reason,
        "wall_time_s": f"{wall:.3f}",
        "history": f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')} emfabric run",
    }


def write_history(ds: xr.Dataset, path: str | Path) -> None:
    """Write the whole history (appendable along time), atomically."""
    write_netcdf(ds, path, unlimited="time")


def append_history(path: Path, rows: np.ndarray, attrs: dict[str, str], written: int) -> int:
    """Add records to history.nc, creating it with these attributes if nothing is written yet;
    returns the number of records now in the file."""
    if written == 0 or not path.exists():
        write_history(rows_to_dataset(rows, attrs), path)
        return rows.shape[0]
    if rows.shape[0] == 0:
        return written
    ds = rows_to_dataset(rows, attrs)
    names = ("time", *VARIABLES, *(n for n in PLY_RECORD if n in ds))
    return append_records(path, "time", {name: ds[name].values for name in names})


def read_history_rows(path: Path, count: int, plies: int = 1) -> np.ndarray:
    """The first `count` records of history.nc as rows (a resumed run's history so far) of a
    pack of `plies` plies."""
    raw = read_records(path, "time", count)
    rows = np.empty((count, row_width(plies)))
    rows[:, 0] = raw["time"]
    for name, sl in {**LAYOUT, **ply_layout(plies)}.items():
        rows[:, sl] = raw[name].reshape(count, -1)
    return rows


def history_status(path: Path) -> tuple[str, str, str] | None:
    """(status, end_reason, scenario_name) of a history.nc, or None if it cannot be read."""
    import netCDF4

    try:
        with netCDF4.Dataset(path, "r") as nc:
            return tuple(str(nc.getncattr(k)) for k in ("status", "end_reason",
                                                        "scenario_name"))
    except (OSError, AttributeError, KeyError):
        return None


def history_records(path: Path) -> int | None:
    """The number of records in a history.nc, or None if it cannot be read."""
    import netCDF4

    try:
        with netCDF4.Dataset(path, "r") as nc:
            return len(nc.dimensions["time"])
    except (OSError, KeyError):
        return None


_KEPT: list = []
"""netCDF4 Datasets whose close failed, never collected (netCDF4 would close them again)."""


def mark_status(path: Path, status: str, end_reason: str, wall_time: str | None = None) -> bool:
    """Set history.nc's `status` and `end_reason` in place, without writing anything else: the
    way to record a run's end when the disk is full (a rewrite of the file needs room), and
    snapshots.nc's at a run's end. The file's header never grows (it would move the records):
    `end_reason` is cut to the room of the one it replaces (a running run's is long enough for
    a write error, see emfabric.runner.loop.RUNNING); `wall_time` (wall_time_s's text) is set
    where it fits the room of the one written when the file was created (up to 9999.999 s
    after one of 0.x s). Returns whether it was done."""
    import netCDF4

    def room(text) -> int:  # bytes of header a text attribute takes (padded to 4)
        return -(-len(str(text).encode("utf-8")) // 4) * 4

    if not Path(path).is_file():
        return False  # (netCDF4's "a" would create an empty file, which no run can read)
    try:
        nc = netCDF4.Dataset(path, "a")
    except (OSError, RuntimeError):
        return False
    done = False
    try:
        budget = room(nc.getncattr("end_reason"))
        if room(status) <= room(nc.getncattr("status")):
            reason = end_reason.encode("utf-8")
            if len(reason) > budget:
                reason = reason[:max(0, budget - 3)].decode("utf-8", "ignore").encode() + \
                    "…".encode()
            nc.setncattr("status", status)
            nc.setncattr("end_reason", reason.decode("utf-8"))
            if (wall_time is not None and "wall_time_s" in nc.ncattrs()
                    and room(wall_time) <= room(nc.getncattr("wall_time_s"))):
                nc.setncattr("wall_time_s", wall_time)
            done = True
    except (OSError, RuntimeError, AttributeError, KeyError):
        done = False
    try:
        nc.close()
    except (OSError, RuntimeError):
        _KEPT.append(nc)
        return False
    return done


def fabric_reference(scenario) -> str:
    """Which fabric the grid runs as (fabric.rescale and reference_nodes), in words."""
    fab = scenario.fabric
    grid = f"{fab.nodes[0]} x {fab.nodes[1]}"
    if not fab.rescale:
        return f"{grid} as given (rescale = false: yarn_radius and charge_per_node at this spacing)"
    ref = f"{fab.reference_nodes[0]} x {fab.reference_nodes[1]}"
    if tuple(fab.nodes) == tuple(fab.reference_nodes):
        return f"{grid}, the reference grid"
    return (f"{grid} run as the {ref} reference fabric (yarn area scaled with the spacing, "
            f"charge with the node mass)")
