"""The Field record of a scenario: uniform fields, half-space region, loops and solenoids (as
sums of loops with their current waveforms), permanent magnets and field maps, as data for the
kernels (emfabric._kernels.fields.field_at). The source grid is added by
emfabric.sources.grid; evaluation outside a run is emfabric.sources.evaluate."""

from __future__ import annotations

import logging

import numpy as np

from emfabric._kernels.coils import WAVE_CONSTANT, WAVE_DAMPED_SINE, WAVE_RAMP, WAVE_TABLE
from emfabric._kernels.records import REGION_HALF_SPACE, REGION_UNIFORM, Field
from emfabric.config.scenario import Scenario, ScenarioError

log = logging.getLogger(__name__)


SOLENOID_MAX_LOOPS = 200
"""A solenoid of more turns is this many loops, each carrying current × turns / loops."""
WIRE_FRACTION = 0.01
"""Default wire radius of a loop or solenoid, as a fraction of its radius."""


def build_field(scenario: Scenario) -> Field:
    """The Field record of a scenario: the uniform part (field.E, field.B and the "uniform"
    sources, summed) and the current loops (a solenoid is a row of loops), each with its
    waveform. Needs no fabric (``emfabric field`` uses it alone)."""
    fld = scenario.field
    e = np.asarray(fld.E, dtype=float)
    b = np.asarray(fld.B, dtype=float)
    loops, waves, tables = [], [], []
    field_map = None
    magnets: list[list[float]] = []
    kinds = {"constant": WAVE_CONSTANT, "ramp": WAVE_RAMP, "damped-sine": WAVE_DAMPED_SINE,
             "table": WAVE_TABLE}
    for i, src in enumerate(fld.sources):
        if src.kind == "uniform":
            e = e + np.asarray(src.E, dtype=float)
            b = b + np.asarray(src.B, dtype=float)
            continue
        if src.kind == "magnet":
            from emfabric.sources.grid import import_magpylib
            try:
                import_magpylib()
            except ImportError as err:
                raise ScenarioError(f"field.sources[{i}].kind = \"magnet\": {err}") from None
            magnets.append([0.0 if src.shape == "cuboid" else 1.0, *src.polarization,
                            *(list(src.dimension) + [0.0])[:3], *src.position,
                            *np.radians(np.asarray(src.orientation, dtype=float))])
            continue
        if src.kind == "map":
            if field_map is not None:
                raise ScenarioError(f"field.sources[{i}]: a second field map; allowed: one "
                                    f"source of kind \"map\" (sum the maps into one file)")
            field_map = read_field_map(src.file, src.scale, f"field.sources[{i}].file")
            continue
        direction = np.asarray(src.normal if src.kind == "loop" else src.axis, dtype=float)
        size = float(np.linalg.norm(direction))
        if not size > 0.0:
            key = "normal" if src.kind == "loop" else "axis"
            raise ScenarioError(f"field.sources[{i}].{key} = {direction.tolist()}: allowed: a "
                                f"non-zero vector")
        n = direction / size
        wire = src.wire_radius if src.wire_radius is not None else WIRE_FRACTION * src.radius
        if src.kind == "loop":
            centres, per_loop = [np.asarray(src.centre, dtype=float)], float(src.turns)
        else:
            count = min(src.turns, SOLENOID_MAX_LOOPS)
            offsets = (np.arange(count) + 0.5) / count - 0.5
            centres = [np.asarray(src.centre, dtype=float) + o * src.length * n
                       for o in offsets]
            per_loop = src.turns / count
        amp = per_loop * (src.current if src.current is not None else 1.0)
        wave = [kinds[src.waveform], amp, src.start_time, src.rise_time or 0.0,
                src.frequency or 0.0, src.decay_time or 1.0]
        table = np.asarray(src.table if src.table is not None else [(0.0, 0.0)], dtype=float)
        for c in centres:
            loops.append([*c, *n, src.radius, wire])
            waves.append(wave)
            tables.append(table)
    width = max((len(tb) for tb in tables), default=1)
    padded = np.zeros((len(tables), width, 2))
    for k, tb in enumerate(tables):
        padded[k, :len(tb)] = tb
    return Field(
        E=e,
        B=b,
        region=REGION_UNIFORM if fld.region == "uniform" else REGION_HALF_SPACE,
        z0=float(fld.z0),
        gravity=np.asarray(fld.gravity, dtype=float),
        loops=np.asarray(loops, dtype=float).reshape(-1, 8) if loops else None,
        currents=np.asarray(waves, dtype=float).reshape(-1, 6),
        tables=padded,
        table_len=np.array([len(tb) for tb in tables], dtype=np.int64),
        magnets=np.asarray(magnets, dtype=float).reshape(-1, 13),
        **({} if field_map is None else field_map),
    )


def _numbers(values, key: str, path: str, what: str, unit: str) -> np.ndarray:
    """A map's array as float64, refusing what is not numbers (strings, dates, booleans)."""
    arr = np.asarray(values)
    if arr.dtype.kind not in "iuf":
        raise ScenarioError(f"{key} = {path!r}: {what} holds {arr.dtype} values; allowed: "
                            f"numbers [{unit}]")
    return arr.astype(float)


def read_field_map(path: str, scale: float, key: str) -> dict:
    """The map_axes, map_size and map_values of a Field record from a netCDF field map
    (coordinates x, y, z [m], increasing; Bx, By, Bz [T], optional Ex, Ey, Ez [V/m]), times
    `scale`. Errors name the key, the file and what is wrong."""
    import xarray as xr

    try:
        ds = xr.open_dataset(path)
    except (OSError, ValueError) as err:
        raise ScenarioError(f"{key} = {path!r}: cannot be read as netCDF ({err}); allowed: a "
                            f"netCDF file with coordinates x, y, z and variables Bx, By, Bz") \
            from None
    with ds:
        axes = []
        for name in "xyz":
            if name not in ds.variables or ds[name].ndim != 1:
                raise ScenarioError(f"{key} = {path!r}: no one-dimensional coordinate {name!r}")
            a = _numbers(ds[name].values, key, path, f"coordinate {name!r}", "m")
            if a.size < 2 or not np.all(np.isfinite(a)) or np.any(np.diff(a) <= 0):
                raise ScenarioError(f"{key} = {path!r}: coordinate {name!r} must hold at least "
                                    f"two finite, increasing values [m]")
            axes.append(a)
        values = np.zeros((axes[0].size, axes[1].size, axes[2].size, 6))
        for c, name in enumerate(("Ex", "Ey", "Ez", "Bx", "By", "Bz")):
            if name not in ds.variables:
                if name.startswith("B"):
                    raise ScenarioError(f"{key} = {path!r}: variable {name!r} is missing "
                                        f"(B in T on the grid x, y, z)")
                continue
            var = ds[name]
            if set(var.dims) != {"x", "y", "z"}:
                raise ScenarioError(f"{key} = {path!r}: {name} has dimensions {var.dims}; "
                                    f"allowed: x, y, z")
            v = _numbers(var.transpose("x", "y", "z").values, key, path, name,
                         "T" if name.startswith("B") else "V/m")
            if not np.all(np.isfinite(v)):
                raise ScenarioError(f"{key} = {path!r}: {name} holds non-finite values")
            values[..., c] = scale * v
    width = max(a.size for a in axes)
    padded = np.zeros((3, width))
    for c, a in enumerate(axes):
        padded[c, :a.size] = a
    steps = np.array([(a[-1] - a[0]) / (a.size - 1)
                      if np.allclose(np.diff(a), (a[-1] - a[0]) / (a.size - 1), rtol=1e-9, atol=0)
                      else 0.0 for a in axes])
    return {"map_axes": padded, "map_size": np.array([a.size for a in axes], dtype=np.int64),
            "map_step": steps,
            "map_values": values, "map_has_e": bool(np.any(values[..., :3] != 0.0))}


def one_type(fld: Field) -> Field:
    """The record with every absent source member (loops, map, grid) an empty array once any
    source is present, so that every field with sources has one Numba type: a run compiles
    its step kernels once for a coil, a map, magnets or any mix of them (the kernels test the
    sizes at run time; emfabric._kernels.fields). A uniform field keeps its None members,
    which compile the source lookups away from the node kernel's vectorised loops."""
    if fld.loops is None and fld.map_axes is None and fld.grid_values is None:
        return fld
    return fld._replace(
        loops=np.zeros((0, 8)) if fld.loops is None else fld.loops,
        map_axes=np.zeros((3, 0)) if fld.map_axes is None else fld.map_axes,
        grid_values=np.zeros((0, 1, 1, 1, 6)) if fld.grid_values is None else fld.grid_values,
    )


def nodes_outside_map(fld: Field, points: np.ndarray) -> int:
    """How many of the points (3, N) lie outside the field map's box (0 without a map)."""
    if fld.map_axes is None or fld.map_axes.shape[1] == 0:
        return 0
    inside = np.ones(points.shape[1], dtype=bool)
    for c in range(3):
        grid = fld.map_axes[c, :fld.map_size[c]]
        inside &= (points[c] >= grid[0]) & (points[c] <= grid[-1])
    return int((~inside).sum())
