"""netCDF conventions shared by history.nc and snapshots.nc (CF-1.8, checked with cfchecker).

- history.nc and snapshots.nc are written as the run goes: created with the first records, then
  appended along their unlimited dimension (`time`, `snapshot`). They use the classic netCDF
  format with 64-bit offsets (netCDF-C, read by xarray, ncdump, ParaView, MATLAB, NCO like any
  netCDF file) because appending a record there only writes the new data and then the record
  count in the header: a process killed in the middle of an append leaves the file readable
  with the records it had. An HDF5-based (netCDF-4) file being appended to can be left
  unreadable by a kill. Integer variables are therefore 32-bit. Files written whole
  (checkpoint.nc, study results) are netCDF-4, written to a temporary name and renamed.

- `time` is simulated time in seconds from the start of the run, with no `standard_name`
  (CF's `time` standard name needs a reference date, which a simulation does not have).
- Vector components run along the `xyz` dimension, labelled by a character coordinate
  ("x", "y", "z"): stored as a char array (not a variable-length string, which CF does not
  allow), read back by xarray as strings, so `.sel(xyz="x")` works.
- Every variable has `units` and `long_name`; the global attributes say what made the file
  (`source`, the package version, the full scenario) and what it implements (`references`).

- Where dask is installed (the `studies` extra), writing a run's files imported dask.array
  (with scipy.fft) and distributed, ~0.5 s of every run, for files that hold NumPy arrays
  only: xarray asks of each array it wraps whether it is a dask array, importing dask.array
  to ask, and `Dataset.to_netcdf` looks for an active dask scheduler. The files are written
  through xarray's encoding and netCDF4 store as to_netcdf writes them, less the look
  (`to_netcdf` below), and `_DaskArrayType` answers the question without the import while
  dask.array is not imported (nothing can be a dask array then).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Hashable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from emfabric.io.atomic import write_atomic


class _DaskArrayType:
    """xarray's record of dask as an array library (xarray.namedarray.pycompat's
    DuckArrayModule("dask"), which imports dask.array when made) made only when something
    needs more than the array type while dask.array is not imported: `type` is () then, as an
    object can be a dask array only once dask.array is imported. Anything else (`module`,
    `version`, `available`), or `type` once dask.array is imported, makes xarray's own record,
    which then replaces this one."""

    def __init__(self, cache: dict, make: type):
        self._cache, self._make = cache, make

    def _real(self):
        real = self._make("dask")
        if self._cache.get("dask") is self:
            self._cache["dask"] = real
        return real

    @property
    def type(self) -> tuple:
        if "dask.array" not in sys.modules:
            return ()
        return self._real().type

    def __getattr__(self, name: str):
        return getattr(self._real(), name)


def _ask_dask_only_once_imported() -> None:
    """Put _DaskArrayType in xarray's cache of array libraries (unless xarray keeps it
    otherwise, or already holds dask's record)."""
    try:
        from xarray.namedarray import pycompat
    except ImportError:  # another xarray layout: it keeps its own behaviour
        return
    cache = getattr(pycompat, "_cached_duck_array_modules", None)
    make = getattr(pycompat, "DuckArrayModule", None)
    if isinstance(cache, dict) and make is not None and "dask" not in cache:
        cache["dask"] = _DaskArrayType(cache, make)


_ask_dask_only_once_imported()

CONVENTIONS = "CF-1.8"
REFERENCES = ('T. I. Zohdi, "High-speed impact of electromagnetically sensitive fabric and '
              'induced projectile spin" (the model emfabric implements)')
TIME_ATTRS = {"units": "s", "long_name": "simulated time since the start of the run"}


def xyz_coordinate() -> tuple:
    """The `xyz` label coordinate for vector-valued variables."""
    return ("xyz", np.array(["x", "y", "z"]), {"long_name": "Cartesian component"})


APPENDABLE = "NETCDF3_64BIT_OFFSET"


def to_netcdf(ds: xr.Dataset, path: str | Path, fmt: str, *,
              encoding: Mapping[Hashable, Mapping[str, Any]] | None = None,
              unlimited_dims: Iterable[Hashable] | None = None) -> None:
    """`ds.to_netcdf(path, engine="netcdf4", format=fmt, ...)` for a dataset of NumPy arrays:
    the same store and encoding (Dataset.dump_to_store; the arrays are written as it goes),
    with the netCDF library's process-wide lock that to_netcdf would take, less the per-file
    lock it asks an active dask scheduler for (a temporary file is no other writer's), so
    that nothing imports distributed (module docstring)."""
    from xarray.backends import NetCDF4DataStore
    from xarray.backends.locks import HDF5_LOCK, NETCDFC_LOCK, combine_locks

    lock = combine_locks([NETCDFC_LOCK, HDF5_LOCK]) if fmt.startswith("NETCDF4") \
        else NETCDFC_LOCK
    store = NetCDF4DataStore.open(os.fspath(path), mode="w", format=fmt, lock=lock)
    try:
        ds.dump_to_store(store, encoding=dict(encoding or {}),
                         unlimited_dims=list(unlimited_dims or []))
    finally:
        store.close()


def write_netcdf(ds: xr.Dataset, path: str | Path, *, unlimited: str | None = None) -> None:
    """Write the dataset atomically, with `xyz` as a CF character label: netCDF-4, or the
    appendable classic format with `unlimited` as the record dimension."""
    encoding = {"xyz": {"dtype": "S1"}} if "xyz" in ds.variables else {}
    if unlimited is None:
        write_atomic(path, lambda tmp: to_netcdf(ds, tmp, "NETCDF4", encoding=encoding))
    else:
        # xarray writes the header and the first record; the other records are appended
        # directly (xarray's own write of a record dimension goes variable by variable through
        # the interleaved records with fill mode on: 1.08 s for a paper-field history.nc,
        # 0.37 s this way, the same file as read back)
        first = ds.isel({unlimited: slice(0, 1)})
        rest = {name: var.values[1:] for name, var in ds.variables.items()
                if var.dims[:1] == (unlimited,)}

        def write(tmp: Path) -> None:
            to_netcdf(first, tmp, APPENDABLE, encoding=encoding, unlimited_dims=[unlimited])
            if ds.sizes[unlimited] > 1:
                append_records(tmp, unlimited, rest)

        write_atomic(path, write)


def append_records(path: str | Path, dim: str, records: dict[str, np.ndarray]) -> int:
    """Append records (name -> array whose first axis runs along `dim`) to a file written by
    write_netcdf(..., unlimited=dim); returns the new length of `dim`."""
    import netCDF4

    with netCDF4.Dataset(path, "a") as nc:
        # no fill values written ahead of the data: a kill before the close leaves the record
        # count in the header as it was, and the records beyond it unread
        nc.set_fill_off()
        start = len(nc.dimensions[dim])
        count = 0
        for name, values in records.items():
            count = values.shape[0]
            nc.variables[name][start:start + count] = values
        return start + count


def read_records(path: str | Path, dim: str, count: int) -> dict[str, np.ndarray]:
    """The first `count` records of every variable along `dim` (raw values)."""
    import netCDF4

    with netCDF4.Dataset(path, "r") as nc:
        nc.set_auto_maskandscale(False)
        if len(nc.dimensions[dim]) < count:
            raise ValueError(f"{path} holds {len(nc.dimensions[dim])} records along {dim!r}, "
                             f"expected at least {count}")
        return {name: np.array(var[:count]) for name, var in nc.variables.items()
                if var.dimensions[:1] == (dim,)}


def record_digest(path: str | Path, dim: str, index: int) -> str:
    """SHA-256 (hex) of record `index` along `dim` of every variable along it (raw values, by
    variable name): what a checkpoint records of the last history record and snapshot it
    counts, so that a resume can tell the records it keeps from a file that lost them."""
    import hashlib

    import netCDF4

    digest = hashlib.sha256()
    with netCDF4.Dataset(path, "r") as nc:
        nc.set_auto_maskandscale(False)
        for name in sorted(nc.variables):
            var = nc.variables[name]
            if var.dimensions[:1] == (dim,):
                digest.update(name.encode("utf-8"))
                digest.update(np.ascontiguousarray(var[index]).tobytes())
    return digest.hexdigest()
