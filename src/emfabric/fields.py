"""The applied field outside a run: E and B at given points and time (``emfabric field``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from emfabric._kernels.fields import field_at
from emfabric._kernels.records import Field


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
    field_at the run's kernels call."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    e = np.empty_like(pts)
    b = np.empty_like(pts)
    _fields_at(fld, pts, float(t), e, b)
    return e, b
