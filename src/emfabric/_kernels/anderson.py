"""Anderson acceleration (type II) of the coupled fixed-point map x ↦ G(x) on node positions.

With residuals f_k = G(x_k) − x_k, the next iterate is x_{k+1} = G(x_k) − ΔG γ, where γ
minimises ‖f_k − ΔF γ‖ over the last `depth` differences ΔF, ΔG (Walker & Ni 2011). It leaves
the fixed point, and so the discrete φ-scheme, unchanged; only the iterates differ.
"""

import numpy as np
from numba import njit

from emfabric._kernels.vec3 import copy_into, solve_in_place


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for c in range(3):
        ac = a[c]
        bc = b[c]
        for n in range(ac.shape[0]):
            s += ac[n] * bc[n]
    return s


@njit(cache=True, _nrt=True)
def anderson_mix(k, x, g, d_f, d_g, f_prev, g_prev, gram):
    """Overwrite the iterate x (3, N) with the Anderson update from g = G(x), iteration k ≥ 1.

    d_f, d_g: (depth, 3, N) ring buffers; f_prev, g_prev: (3, N); gram: (depth, depth).
    """
    depth = d_f.shape[0]
    # residual f_k = g − x, kept in x until the update
    for c in range(3):
        for n in range(x.shape[1]):
            x[c, n] = g[c, n] - x[c, n]
    if k > 1:
        col = (k - 2) % depth
        for c in range(3):
            for n in range(x.shape[1]):
                d_f[col, c, n] = x[c, n] - f_prev[c, n]
                d_g[col, c, n] = g[c, n] - g_prev[c, n]
        for i in range(min(k - 1, depth)):
            gram[col, i] = _dot(d_f[col], d_f[i])
            gram[i, col] = gram[col, i]
    copy_into(f_prev, x)
    copy_into(g_prev, g)
    m = min(k - 1, depth)
    if m == 0:
        copy_into(x, g)
        return
    rhs = np.empty(m)
    for i in range(m):
        rhs[i] = _dot(d_f[i], x)
    a = gram[:m, :m].copy()
    # a little Tikhonov regularisation keeps nearly dependent columns harmless
    scale = 0.0
    for i in range(m):
        scale = max(scale, a[i, i])
    for i in range(m):
        a[i, i] += 1e-12 * scale + 1e-300
    solve_in_place(a, rhs, m)
    gamma = rhs
    for c in range(3):
        for n in range(x.shape[1]):
            v = g[c, n]
            for i in range(m):
                v -= gamma[i] * d_g[i, c, n]
            x[c, n] = v
