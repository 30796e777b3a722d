"""Exactly rounded summation (Shewchuk / math.fsum) for order-independent, mirror-exact sums."""

import numpy as np
from numba import njit


@njit(cache=True)
def fsum(values, count):
    """Correctly rounded sum of values[:count]; the result does not depend on their order."""
    partials = np.empty(80)
    npart = 0
    for idx in range(count):
        x = values[idx]
        i = 0
        for j in range(npart):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        npart = i
        partials[npart] = x
        npart += 1
    if npart == 0:
        return 0.0
    # sum the partials from the top, with CPython's half-way rounding correction
    npart -= 1
    hi = partials[npart]
    lo = 0.0
    while npart > 0:
        x = hi
        npart -= 1
        y = partials[npart]
        hi = x + y
        yr = hi - x
        lo = y - yr
        if lo != 0.0:
            break
    if npart > 0 and ((lo < 0.0 and partials[npart - 1] < 0.0) or
                      (lo > 0.0 and partials[npart - 1] > 0.0)):
        y = lo * 2.0
        x = hi + y
        yr = x - hi
        if y == yr:
            hi = x
    return hi
