"""The applied field outside a run: E and B at given points and time (``emfabric field``, the
field figure, the history's field at the projectile, field design)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from emfabric._kernels.fields import fields_at_points
from emfabric._kernels.records import Field
from emfabric.sources.grid import magnet_fields


def fields_at(fld: Field, points: Sequence[Sequence[float]], t: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """E [V/m] and B [T] of the Field record at the points (N, 3) [m] and time t [s]: the same
    field_at the run's kernels call. A record without a source grid (built from the scenario
    alone, as ``emfabric field`` does) has the loops exactly and the magnets from magpylib; a
    run's record takes both from its grid (emfabric.sources.grid)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    e = np.empty_like(pts)
    b = np.empty_like(pts)
    fields_at_points(fld, pts, float(t), e, b)
    if magnets_outside_kernels(fld):
        b += magnet_fields(fld.magnets, pts)
    return e, b


def magnets_outside_kernels(fld: Field) -> bool:
    """Whether the record's magnets are not in its source grid (built from the scenario alone):
    fields_at_points leaves them out and fields_at adds them from magpylib."""
    return bool((fld.grid_values is None or fld.grid_values.shape[0] == 0)
                and fld.magnets.shape[0])
