"""History recorder: one record per accepted step -> xarray.Dataset -> netCDF (history.nc)."""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path

import numpy as np
import xarray as xr

from emfabric._kernels import diagnostics as _k
from emfabric.diagnostics import fabric_diagnostics
from emfabric.io.netcdf import (
    CONVENTIONS,
    REFERENCES,
    TIME_ATTRS,
    write_netcdf,
    xyz_coordinate,
)
from emfabric.model import Model, State

# name -> (width, units, long name); width 3 means a (time, xyz) variable
VARIABLES: dict[str, tuple[int, str, str]] = {
    "dt": (1, "s", "accepted time step"),
    "iterations": (1, "1", "fixed-point iterations of the accepted step"),
    "error": (1, "1", "normalised iteration error at acceptance (eq. 3.10 step 5a)"),
    "rejected_steps": (1, "1", "rejected attempts so far (cumulative)"),
    "force_evaluations": (1, "1", "force evaluations so far (cumulative)"),
    "projectile_position": (3, "m", "projectile centre of mass"),
    "projectile_velocity": (3, "m s-1", "projectile centre-of-mass velocity"),
    "angular_velocity": (3, "rad s-1", "projectile angular velocity (inertial frame)"),
    "projectile_nose": (3, "m", "nose marker relative to the centre of mass"),
    "tilt": (1, "rad", "tilt angle of the nose marker (eq. 5.2)"),
    "contact_nodes": (1, "1", "fabric nodes in contact"),
    "max_deflection": (1, "m", "largest out-of-plane node displacement"),
    "max_stretch": (1, "1", "largest yarn stretch U = L/L0"),
    "fabric_momentum": (3, "kg m s-1", "linear momentum of the fabric"),
    "fabric_angular_momentum": (3, "kg m2 s-1", "angular momentum of the fabric about the origin"),
    "projectile_momentum": (3, "kg m s-1", "linear momentum of the projectile"),
    "projectile_angular_momentum": (3, "kg m2 s-1",
                                    "angular momentum of the projectile about the origin"),
    "kinetic_energy_projectile": (1, "J", "projectile kinetic energy (translation + rotation)"),
    "kinetic_energy_projectile_rotation": (1, "J", "projectile rotational kinetic energy"),
    "kinetic_energy_fabric": (1, "J", "fabric kinetic energy"),
    "strain_energy": (1, "J", "stored yarn energy (damaged)"),
    "broken_yarns": (1, "1", "yarns with damage α below fabric.damage.broken_below"),
    "min_damage": (1, "1", "smallest yarn damage variable α (1 intact)"),
    "work_field": (1, "J", "work of the electric field on fabric and projectile (cumulative)"),
    "work_gravity": (1, "J", "work of gravity (cumulative)"),
    "dissipation_friction": (1, "J", "energy dissipated by friction impulses (cumulative)"),
    "dissipation_contact": (1, "J", "energy dissipated by normal contact impulses (cumulative)"),
    "dissipation_projection": (1, "J", "work lost in contact position projections (cumulative)"),
    "dissipation_damage": (1, "J", "energy released by yarn damage (cumulative)"),
    "energy_balance_error": (1, "J", "kinetic + strain + dissipated − work − initial energy"),
}


def _layout() -> dict[str, slice]:
    out, col = {}, 1  # column 0 is time
    for name, (width, _u, _l) in VARIABLES.items():
        out[name] = slice(col, col + width)
        col += width
    return out


LAYOUT = _layout()
COLUMNS = 1 + sum(w for w, _u, _l in VARIABLES.values())


class Recorder:
    """Collects one row per accepted step in a growing array (amortised O(1) append)."""

    def __init__(self, model: Model, coef: np.ndarray):
        self.model = model
        self.coef = coef
        self._rows = np.empty((1024, COLUMNS))
        self.count = 0
        self._initial_energy = math.nan
        self.last_diag = np.empty(_k.COUNT)

    def record(self, state: State, dt: float = 0.0, iterations: int = 0,
               error: float = 0.0) -> None:
        if self.count == self._rows.shape[0]:
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        m = self.model
        d = fabric_diagnostics(m, state, self.coef)
        self.last_diag = d
        self._initial_energy = _k.history_row(
            state.t, dt, iterations, error, state.rejected, state.evaluations,
            state.contact_count, state.body, m.has_body, m.body_mass, m.body_inertia,
            m.body_nose, d, state.energy, self._initial_energy, self._rows[self.count])
        self.count += 1

    def to_dataset(self, attrs: dict[str, str]) -> xr.Dataset:
        rows = self._rows[: self.count]
        data = {}
        for name, (width, units, long_name) in VARIABLES.items():
            col = rows[:, LAYOUT[name]]
            meta = {"units": units, "long_name": long_name}
            if width == 3:
                data[name] = (("time", "xyz"), col.copy(), meta)
            else:
                vals = col[:, 0].copy()
                if units == "1" and name in ("iterations", "rejected_steps", "force_evaluations",
                                             "contact_nodes", "broken_yarns"):
                    vals = vals.astype(np.int64)
                data[name] = (("time",), vals, meta)
        coords = {"time": ("time", rows[:, 0].copy(), TIME_ATTRS), "xyz": xyz_coordinate()}
        ds = xr.Dataset(data, coords=coords, attrs=dict(attrs))
        return ds


def run_attributes(model: Model, status: str, end_reason: str, wall: float) -> dict:
    """Global attributes: package version, full scenario text, status."""
    from emfabric import __version__

    sc = model.scenario
    return {
        "title": f"emfabric run of scenario {sc.name!r}",
        "Conventions": CONVENTIONS,
        "source": f"emfabric {__version__} (yarn-network impact simulation)",
        "references": REFERENCES,
        "emfabric_version": __version__,
        "scenario_name": sc.name,
        "has_projectile": int(model.has_body),
        "projectile_radius": model.body_radius if model.has_body else 0.0,
        "scenario": sc.to_toml(),
        "status": status,
        "end_reason": end_reason,
        "wall_time_s": f"{wall:.3f}",
        "history": f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')} emfabric run",
    }


def write_history(ds: xr.Dataset, path: str | Path) -> None:
    """Write the dataset as netCDF4, atomically."""
    write_netcdf(ds, path)
