"""netCDF conventions shared by history.nc and snapshots.nc (CF-1.8, checked with cfchecker).

- `time` is simulated time in seconds from the start of the run, with no `standard_name`
  (CF's `time` standard name needs a reference date, which a simulation does not have).
- Vector components run along the `xyz` dimension, labelled by a character coordinate
  ("x", "y", "z"): stored as a char array (not a variable-length string, which CF does not
  allow), read back by xarray as strings, so `.sel(xyz="x")` works.
- Every variable has `units` and `long_name`; the global attributes say what made the file
  (`source`, the package version, the full scenario) and what it implements (`references`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from emfabric.io.atomic import write_atomic

CONVENTIONS = "CF-1.8"
REFERENCES = ('T. I. Zohdi, "High-speed impact of electromagnetically sensitive fabric and '
              'induced projectile spin" (the model emfabric implements)')
TIME_ATTRS = {"units": "s", "long_name": "simulated time since the start of the run"}


def xyz_coordinate() -> tuple:
    """The `xyz` label coordinate for vector-valued variables."""
    return ("xyz", np.array(["x", "y", "z"]), {"long_name": "Cartesian component"})


def write_netcdf(ds: xr.Dataset, path: str | Path) -> None:
    """Write the dataset as netCDF4, atomically, with `xyz` as a CF character label."""
    encoding = {"xyz": {"dtype": "S1"}} if "xyz" in ds.variables else {}
    write_atomic(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4",
                                               encoding=encoding))
