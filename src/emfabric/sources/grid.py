"""The source grid: coils' and magnets' fields precomputed over the region the fabric can reach.

A loop's field is linear in its current, B(x, t) = I(t) b(x), and its induced electric field is
E = −(dI/dt) a(x) with a its vector potential per ampere. Loops that share one waveform (the two
coils of a Helmholtz pair, the loops of a solenoid) form a *group*; the grid holds each group's
b and a at the points of an evenly spaced box, and a node's field is the trilinear
interpolation of the groups times their waveforms at t: six numbers per corner instead of the
elliptic integrals of every loop. Permanent magnets (magpylib) form one more group, constant in
time.

The box covers the fabric's extent (5 % more on each side) and half its larger side above and
below its plane; its cells are cubes, `field.grid_cells` across the larger side. The grid is
checked when it is built: at the midpoints of each cell's three edges the interpolated b and a
are compared with the exact ones (not at the centre, where a harmonic field's interpolation
error cancels to second order: see EDGES), and a cell whose summed error exceeds
`field.grid_tolerance` × (the exact value + 1 % of the median over the grid) is marked exact —
there (near a wire) and outside the box the loops are evaluated exactly. A magnet has no exact
evaluation in the kernels: its field is zero outside the box and interpolated in every cell
(the cells that miss the tolerance are counted in a warning).
"""

from __future__ import annotations

import logging

import numpy as np

from emfabric._kernels.coils import loop_values_on_grid
from emfabric._kernels.records import Field

log = logging.getLogger(__name__)

MAGNET_WAVE = -1
"""grid_wave of the magnets' group: constant 1, no induced E."""


EDGES = ((0.5, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.5))
"""Where each cell's interpolation is checked: the midpoints of its three edges from its first
corner. Not the centre: b and a are harmonic away from the sources (∇²b = 0), so the mean of
a cube's corners meets the centre value to fourth order while the interpolation errs to second
order elsewhere; on an edge the error is h²/8 ∂²f along it, and the sum over the three edges
bounds the second-order error anywhere in the cell."""


def _edge_means(values: np.ndarray, axis: int) -> np.ndarray:
    """Linear interpolation at the midpoints of the cells' edges along `axis` (1, 2, 3 for x,
    y, z of (groups, nx + 1, ny + 1, nz + 1, 6)) from each cell's first corner."""
    lo = values[:, :-1, :-1, :-1]
    sl = [slice(None), slice(None, -1), slice(None, -1), slice(None, -1)]
    sl[axis] = slice(1, None)
    return 0.5 * (lo + values[tuple(sl)])


def _errors(exact: np.ndarray, interpolated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per cell and group part (b, a): |error| and |exact| at one set of check points,
    (2 × groups, nx, ny, nz) each."""
    err, size = [], []
    for g in range(exact.shape[0]):
        for part in (slice(0, 3), slice(3, 6)):
            size.append(np.linalg.norm(exact[g, ..., part], axis=-1))
            err.append(np.linalg.norm(exact[g, ..., part] - interpolated[g, ..., part],
                                      axis=-1))
    return np.array(err), np.array(size)


def _misses(checks: list[tuple[np.ndarray, np.ndarray]], tolerance: float) -> np.ndarray:
    """Cells where the summed edge errors of b or a of any group exceed tolerance × (the
    field there + 1 % of its median over the grid)."""
    err = sum(c[0] for c in checks)
    size = np.max([c[1] for c in checks], axis=0)
    floor = 0.01 * np.median(size.reshape(size.shape[0], -1), axis=1)
    return np.any(err > tolerance * (size + floor[:, None, None, None]), axis=0)


def magnet_fields(magnets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """B [T] of the magnets (Field.magnets rows) at the points (N, 3), by magpylib."""
    magpy = import_magpylib()
    from scipy.spatial.transform import Rotation

    parts = []
    for row in magnets:
        pol, dim, pos, rotvec = row[1:4], row[4:7], row[7:10], row[10:13]
        orient = Rotation.from_rotvec(rotvec)
        if int(row[0]) == 0:
            parts.append(magpy.magnet.Cuboid(polarization=pol, dimension=dim, position=pos,
                                             orientation=orient))
        else:
            parts.append(magpy.magnet.Cylinder(polarization=pol, dimension=dim[:2],
                                               position=pos, orientation=orient))
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.asarray(magpy.Collection(*parts).getB(pts), dtype=float).reshape(-1, 3)


def import_magpylib():
    try:
        import magpylib
    except ImportError:
        raise ImportError("a source of kind \"magnet\" needs magpylib: pip install "
                          "'emfabric[magnets]'") from None
    return magpylib


def build_source_grid(fld: Field, x0: np.ndarray, cells: int, tolerance: float,
                      loops_in_grid: bool = True) -> Field:
    """The Field record with its source grid over the reach of the fabric whose nodes start at
    x0 (3, N); unchanged if it has neither loops (in the grid) nor magnets."""
    loops = fld.loops if (fld.loops is not None and fld.loops.shape[0] and loops_in_grid) else None
    has_magnets = fld.magnets.shape[0] > 0
    if loops is None and not has_magnets:
        return fld
    lo = x0.min(axis=1)
    hi = x0.max(axis=1)
    side = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-9))
    h = 1.1 * side / cells
    centre = 0.5 * (lo + hi)
    half = np.array([0.5 * (hi[0] - lo[0]) + 0.05 * side, 0.5 * (hi[1] - lo[1]) + 0.05 * side,
                     0.5 * (hi[2] - lo[2]) + 0.5 * side])
    n_cells = np.maximum(np.ceil(2 * half / h).astype(np.int64), 1)
    origin = centre - 0.5 * n_cells * h
    step = np.full(3, h)
    # groups: loops with one waveform row and table, in order of first appearance; then magnets
    waves: list[int] = []
    group_of = np.zeros(0 if loops is None else loops.shape[0], dtype=np.int64)
    keys: dict[bytes, int] = {}
    for m in range(group_of.shape[0]):
        key = fld.currents[m].tobytes() + fld.tables[m, :fld.table_len[m]].tobytes()
        if key not in keys:
            keys[key] = len(waves)
            waves.append(m)
        group_of[m] = keys[key]
    n_loop_groups = len(waves)
    groups = n_loop_groups + (1 if has_magnets else 0)
    points = n_cells + 1
    values = np.zeros((groups, *points, 6))
    exact_cells = np.zeros(tuple(n_cells), dtype=np.uint8)
    if loops is not None:
        corner = np.zeros((n_loop_groups, *points, 6))
        loop_values_on_grid(loops, group_of, origin, step, points, np.zeros(3), corner)
        checks = []
        for axis, offset in enumerate(EDGES, start=1):
            mid = np.zeros((n_loop_groups, *n_cells, 6))
            loop_values_on_grid(loops, group_of, origin, step, n_cells, np.array(offset), mid)
            checks.append(_errors(mid, _edge_means(corner, axis)))
        values[:n_loop_groups] = corner
        exact_cells = _misses(checks, tolerance).astype(np.uint8)
        log.info("source grid: %d × %d × %d cells of %.3g mm, %d loop group(s); %d cells "
                 "(%.1f %%) evaluate the loops exactly", *n_cells, 1e3 * h, n_loop_groups,
                 int(exact_cells.sum()), 100.0 * exact_cells.mean())
    if has_magnets:
        axes = [origin[c] + h * np.arange(points[c]) for c in range(3)]
        grid_pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        values[-1, ..., :3] = magnet_fields(fld.magnets, grid_pts).reshape(*points, 3)
        checks = []
        for axis, offset in enumerate(EDGES, start=1):
            mid_pts = grid_pts.reshape(*points, 3)[:-1, :-1, :-1] + np.array(offset) * h
            mid = np.zeros((1, *n_cells, 6))
            mid[0, ..., :3] = magnet_fields(fld.magnets, mid_pts.reshape(-1, 3)).reshape(
                *n_cells, 3)
            checks.append(_errors(mid[:, ..., :3], _edge_means(values[-1:, ..., :3], axis)))
        missed = _misses(checks, tolerance)
        if missed.any():
            log.warning("the magnets' field is interpolated with an error above "
                        "field.grid_tolerance = %g in %d of %d grid cells (%.0f %%: near a "
                        "magnet, where its field varies fastest); the error falls as the "
                        "square of field.grid_cells (now %d)", tolerance, int(missed.sum()),
                        missed.size, 100.0 * missed.mean(), cells)
    # stored z-major, x-minor, (groups, nz + 1, ny + 1, nx + 1, 6): the nodes of a row (along
    # x) read neighbouring memory (x-major made a lookup ~10× slower: a page per corner)
    return fld._replace(
        grid_values=np.ascontiguousarray(values.transpose(0, 3, 2, 1, 4)),
        grid_origin=origin,
        grid_step=step,
        grid_cells=n_cells,
        grid_exact=np.ascontiguousarray(exact_cells.transpose(2, 1, 0)),
        grid_wave=np.array(waves + ([MAGNET_WAVE] if has_magnets else []), dtype=np.int64),
        grid_loops=loops is not None,
    )

