"""Compare two runs' history.nc (or snapshots.nc) number by number.

    python scripts/compare_histories.py RUN_A/history.nc RUN_B/history.nc

Prints "identical" when every variable holds the same values bit for bit over the records both
files have (attributes such as the wall time are not compared); otherwise, for each variable
that differs, the largest absolute difference, the largest magnitude in B and the first record
that differs. Exit status 0 when identical, 1 otherwise.
"""

from __future__ import annotations

import sys

import numpy as np
import xarray as xr


def compare(path_a: str, path_b: str) -> list[tuple[str, float, float, int]]:
    a, b = xr.open_dataset(path_a), xr.open_dataset(path_b)
    dim = "time" if "time" in a.dims else "snapshot"
    n = min(a.sizes[dim], b.sizes[dim])
    print(f"records along {dim!r}: {a.sizes[dim]} and {b.sizes[dim]}")
    out = []
    for name in sorted(set(a.variables) & set(b.variables)):
        x, y = a[name].values, b[name].values
        if a[name].dims[:1] == (dim,):
            x, y = x[:n], y[:n]
        if x.shape != y.shape:
            out.append((name, float("nan"), float("nan"), -1))
            continue
        if np.array_equal(x, y):
            continue
        if x.dtype.kind not in "fiu":
            out.append((name, float("nan"), float("nan"), -1))
            continue
        diff = np.abs(x.astype(float) - y.astype(float))
        first = int(np.argwhere(diff.reshape(diff.shape[0], -1).max(axis=1) > 0)[0][0]) \
            if diff.ndim else 0
        out.append((name, float(diff.max()), float(np.abs(y).max()), first))
    if a.sizes[dim] != b.sizes[dim]:
        out.append((f"<{dim} length>", float(abs(a.sizes[dim] - b.sizes[dim])), 0.0, n))
    return out


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    diffs = compare(sys.argv[1], sys.argv[2])
    if not diffs:
        print("identical")
        return 0
    for name, d, scale, first in diffs:
        print(f"{name}: max |A − B| = {d:.3g} (max |B| = {scale:.3g}), first at record {first}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
