"""The applied field outside a run: E and B at given points and time (``emfabric field``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from emfabric._kernels.fields import field_at
from emfabric._kernels.records import Field
from emfabric.source_grid import magnet_fields


@njit(cache=True)
def _fields_at(fld, points, t, e, b):
    for k in range(points.shape[0]):
        ek, bk = field_at(fld, (points[k, 0], points[k, 1], points[k, 2]), t)
        for c in range(3):
            e[k, c] = ek[c]
            b[k, c] = bk[c]


def fields_at(fld: Field, points: Sequence[Sequence[float]], t: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """E [V/m] and B [T] of the Field record at the points (N, 3) [m] and time t [s]: the same
    field_at the run's kernels call. A record without a source grid (built from the scenario
    alone, as ``emfabric field`` does) has the loops exactly and the magnets from magpylib; a
    run's record takes both from its grid (emfabric.source_grid)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    e = np.empty_like(pts)
    b = np.empty_like(pts)
    _fields_at(fld, pts, float(t), e, b)
    if fld.grid_values is None and fld.magnets.shape[0]:
        b += magnet_fields(fld.magnets, pts)
    return e, b
