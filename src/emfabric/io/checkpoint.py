"""A checkpoint is a State: ``checkpoint.nc`` holds every field of the State (arrays and scalars,
float64 exactly), where the run's outputs stood (history records and snapshots written, the next
snapshot time, wall time so far), the package version and the full scenario text. netCDF, no
pickle: reading it executes nothing. Written atomically (a kill leaves the previous checkpoint)
and read back before it replaces the previous one: a write that failed without saying so (a
full disk can leave a broken HDF5 file behind a successful close) never replaces the last good
checkpoint.

Nothing random is drawn while a run steps (the yarn moduli are drawn from ``material.seed`` when
the model is built), so there is no RNG state to keep: the model is rebuilt from the scenario.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import xarray as xr

from emfabric.config.scenario import Scenario, ScenarioError, scenario_from_dict
from emfabric.io.atomic import write_atomic
from emfabric.io.netcdf import to_netcdf
from emfabric.sim.model import Model
from emfabric.sim.state import State

CHECKPOINT = "checkpoint.nc"
FORMAT = 6  # 2: the State holds node_e; 3: node_contact; 4: node_fv, dissipation_viscous;
# 5: seg_strain; 6: seg_contact
_ADDED: dict[str, int] = {}
"""State fields added since format 6 was written, with the value a checkpoint without them
reads as (a field that describes the step that wrote the checkpoint, which the resumed run
does not record again, as contact_segments was within format 3)."""
_DIMS = {"node_x": ("xyz", "node"), "node_v": ("xyz", "node"), "node_f": ("xyz", "node"),
         "node_e": ("xyz", "node"), "node_contact": ("contact_row", "node"),
         "node_fv": ("xyz", "viscous_node"),
         "seg_alpha": ("segment",), "seg_strain": ("averaged_segment",),
         "seg_contact": ("contact_segment",),
         "body": ("body_row", "xyz"), "energy": ("energy_term",),
         "contact_force": ("xyz",)}


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read or does not belong to the scenario or version."""


@dataclass
class RunPosition:
    """Where the run's outputs stood at the checkpoint (beyond the State)."""

    history_rows: int
    """History records written to history.nc (the State's own record is the last)."""
    snapshots: int
    """Snapshots taken."""
    next_snapshot: float
    """Time of the next snapshot [s]."""
    wall_time: float
    """Wall time spent so far [s]."""
    history_digest: str = ""
    """netcdf.record_digest of the last history record counted (history_rows − 1), "" if not
    recorded: a resume compares it with the file's."""
    snapshots_digest: str = ""
    """netcdf.record_digest of the last snapshot counted, "" if none."""


def write_checkpoint(path: Path, model: Model, state: State, pos: RunPosition) -> None:
    from emfabric import __version__

    data = {}
    for f in fields(State):
        value = getattr(state, f.name)
        if isinstance(value, np.ndarray):
            data[f.name] = (_DIMS[f.name], value)
        else:
            data[f.name] = ((), np.float64(value) if isinstance(value, float) else np.int64(value))
    texts = {}
    for f in fields(RunPosition):
        value = getattr(pos, f.name)
        if isinstance(value, str):
            texts[f"run_{f.name}"] = value
            continue
        data[f"run_{f.name}"] = ((), np.float64(value) if isinstance(value, float)
                                 else np.int64(value))
    ds = xr.Dataset(data, attrs={
        "title": "emfabric checkpoint (a State; resume with `emfabric run --resume DIR`)",
        "emfabric_version": __version__,
        "checkpoint_format": FORMAT,
        "scenario": model.scenario.to_toml(),
        **texts,
    })

    def write_and_check(tmp: Path) -> None:
        import netCDF4

        to_netcdf(ds, tmp, "NETCDF4")
        with netCDF4.Dataset(tmp, "r") as nc:  # every variable reads back
            for var in nc.variables.values():
                var[...]

    write_atomic(path, write_and_check)


def read_checkpoint(path: Path) -> tuple[Scenario, str, State, RunPosition]:
    """(scenario, version that wrote it, State, RunPosition) from a checkpoint file."""
    if not path.is_file():
        raise CheckpointError(f"no checkpoint in {path.parent} (expected {path.name}): "
                              f"nothing to resume")
    try:
        with xr.open_dataset(path, engine="netcdf4", mask_and_scale=False) as ds:
            ds.load()
    except (OSError, ValueError) as err:
        raise CheckpointError(f"{path}: not a readable checkpoint ({err})") from None
    if ds.attrs.get("checkpoint_format") != FORMAT:
        raise CheckpointError(f"{path}: checkpoint format {ds.attrs.get('checkpoint_format')!r}"
                              f", this emfabric reads format {FORMAT}")
    try:
        scenario = scenario_from_dict(tomllib.loads(ds.attrs["scenario"]), str(path))
    except (KeyError, tomllib.TOMLDecodeError, ScenarioError) as err:
        raise CheckpointError(f"{path}: the scenario stored in the checkpoint cannot be read "
                              f"({err})") from None
    values = {}
    for f in fields(State):
        if f.name not in ds and f.name in _ADDED:
            values[f.name] = _ADDED[f.name]
            continue
        if f.name not in ds:
            raise CheckpointError(f"{path}: checkpoint lacks the State field {f.name!r}")
        var = ds[f.name].values
        values[f.name] = (np.array(var, dtype=np.float64) if var.ndim else
                          (float(var) if var.dtype.kind == "f" else int(var)))
    state = State(**values)
    pos = RunPosition(**{f.name: (str(ds.attrs.get(f"run_{f.name}", "")) if f.type == "str"
                                  else (float if f.type == "float" else int)(
                                      ds[f"run_{f.name}"].values))
                         for f in fields(RunPosition)})
    return scenario, str(ds.attrs.get("emfabric_version", "?")), state, pos


END_TIME = "solver.end_time"
"""The one scenario key a resume may change: made later, it continues the run further."""


def check_matches(scenario: Scenario, version: str, stored: Scenario, where: Path) -> bool:
    """Refuse to resume with another scenario or package version than the checkpoint's, but for
    a later solver.end_time: returns whether the scenario extends the stored one that way (the
    run is continued past the end it had)."""
    from emfabric import __version__

    if version != __version__:
        raise CheckpointError(f"{where} was written by emfabric {version}, this is "
                              f"{__version__}: a resumed run would not continue the same "
                              f"computation; rerun it from the start")
    if scenario.to_dict() == stored.to_dict():
        return False
    mine, theirs = _flat(scenario.to_dict()), _flat(stored.to_dict())
    keys = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
    if keys == [END_TIME]:
        if mine[END_TIME] > theirs[END_TIME]:
            return True
        raise CheckpointError(f"{END_TIME} can only be made later on resume (checkpoint "
                              f"{theirs[END_TIME]!r}, given {mine[END_TIME]!r}): a resumed run "
                              f"is continued, not cut short")
    diff = "; ".join(f"{k}: checkpoint {theirs.get(k)!r}, given {mine.get(k)!r}"
                     for k in keys[:5])
    raise CheckpointError(f"the scenario does not match the checkpoint in {where} ({diff}"
                          f"{' …' if len(keys) > 5 else ''}); resume with "
                          f"`emfabric run --resume {where.parent}` alone to continue the "
                          f"stored scenario (a later {END_TIME} alone continues it further)")


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
