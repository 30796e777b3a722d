"""emfabric's force evaluation + node update written for an NVIDIA GPU with numba.cuda.

The same arithmetic as ``emfabric._kernels.step.fabric_iterate`` on a regular sheet (the yarn
law of ``emfabric._kernels.materials``, one fixed-point iterate of the φ-scheme) and as
``warp_kernels.py``, in emfabric's own layout: (3, count) component-major float64 arrays, so a
warp of 32 threads reads 32 neighbouring doubles of one component (coalesced). Two launches per
evaluation: one thread per segment (tension vector and trial damage), then one thread per node
(gathering its four tensions and doing the φ-update with the Lorentz force implicit in v1).

Only imported by ``gpu.py`` on a machine with a CUDA GPU and numba-cuda.
"""

from __future__ import annotations

import math

import numpy as np

if not hasattr(np, "row_stack"):  # removed in NumPy 2.5; numba-cuda 0.30 still registers it
    np.row_stack = np.vstack

from numba import cuda  # noqa: E402

MATERIAL_FUNG = 1
REGION_HALF_SPACE = 1
THREADS = 256


@cuda.jit(cache=False)
def yarn_tension(x, nx, nw, ny, segs, alpha_c, coef, inv_l02, kind, fung_h, u_crit, rate,
                 t_out, alpha_out, err_rows):
    """Tension vector t_s = α·coef_s·S(U²)·d, d = x_b − x_a, and trial damage of segment s."""
    s = cuda.grid(1)
    if s >= segs:
        return
    # warp yarns first (a = j·nx + i = s + j, b = a + 1), then fill yarns (b = a + nx)
    if s < nw:
        a = s + s // (nx - 1)
        b = a + 1
    else:
        a = s - nw
        b = a + nx
    d0 = x[0, b] - x[0, a]
    d1 = x[1, b] - x[1, a]
    d2 = x[2, b] - x[2, a]
    u2 = (d0 * d0 + d1 * d1 + d2 * d2) * inv_l02[s]
    alpha = alpha_c[s]
    # damage, eq. 2.6: irreversible, only past the critical stretch
    if u2 > u_crit * u_crit and rate > 0.0:
        trial = math.exp(-rate * (math.sqrt(u2) - u_crit) / u_crit)
        alpha = min(alpha, trial)
    alpha_out[s] = alpha
    # relaxed Kirchhoff–Saint-Venant (or Fung) stress factor: zero in compression
    e = 0.5 * max(u2 - 1.0, 0.0)
    if kind == MATERIAL_FUNG:
        e = fung_h * e * math.exp(0.5 * fung_h * e * e)
    k = alpha * coef[s] * e
    t_out[0, s] = k * d0
    t_out[1, s] = k * d1
    t_out[2, s] = k * d2
    # the node launch accumulates the error row sums: clear them here (this launch runs first)
    if s < ny:
        err_rows[0, s] = 0.0
        err_rows[1, s] = 0.0


@cuda.jit(cache=False)
def node_update(xk, x0, v0, f0, t_seg, nx, ny, mass, inv_mass, charge, phi, dt, efield,
                bfield, region, z0, grav, skip_err, x1, v1, f1, err_rows):
    """One φ-scheme iterate of node n = j·nx + i, forces at the iterate xk (eqs. 3.2, A12–A13).

    A block holds THREADS nodes of one row j (blockIdx.y): its two error sums are reduced in
    shared memory and added to the row's sums with one atomic each (a thousand threads adding
    to one address serialise)."""
    i = cuda.blockIdx.x * cuda.blockDim.x + cuda.threadIdx.x
    j = cuda.blockIdx.y
    t = cuda.threadIdx.x
    red = cuda.shared.array((2, THREADS), np.float64)
    red[0, t] = 0.0
    red[1, t] = 0.0
    if i < nx:
        _node(xk, x0, v0, f0, t_seg, nx, ny, i, j, mass, inv_mass, charge, phi, dt, efield,
              bfield, region, z0, grav, skip_err, x1, v1, f1, red, t)
    cuda.syncthreads()
    half = THREADS // 2
    while half > 0:
        if t < half:
            red[0, t] += red[0, t + half]
            red[1, t] += red[1, t + half]
        cuda.syncthreads()
        half //= 2
    if t == 0:
        cuda.atomic.add(err_rows, (0, j), red[0, 0])
        cuda.atomic.add(err_rows, (1, j), red[1, 0])


@cuda.jit(device=True, inline=True)
def _node(xk, x0, v0, f0, t_seg, nx, ny, i, j, mass, inv_mass, charge, phi, dt, efield,
          bfield, region, z0, grav, skip_err, x1, v1, f1, red, t):
    """Node (i, j) of node_update; its error terms into red[:, t]."""
    n = j * nx + i
    im = inv_mass[n]
    if im == 0.0:  # fixed node: never moves
        for c in range(3):
            x1[c, n] = x0[c, n]
            v1[c, n] = v0[c, n]
            f1[c, n] = 0.0
        return
    nw = ny * (nx - 1)
    sr = j * (nx - 1) + i
    su = nw + n
    m = mass[n]
    q = 0.0
    if region != REGION_HALF_SPACE or xk[2, n] < z0:
        q = charge[n]
    h = dt * im
    f = cuda.local.array(3, np.float64)
    a = cuda.local.array(3, np.float64)
    for c in range(3):
        # yarn forces: right minus left tension, up minus down (emfabric's order of the sums)
        fw = 0.0
        if i < nx - 1:
            fw = t_seg[c, sr]
        if i > 0:
            fw = fw - t_seg[c, sr - 1]
        ff = 0.0
        if j < ny - 1:
            ff = t_seg[c, su]
        if j > 0:
            ff = ff - t_seg[c, su - nx]
        fc = fw + ff + (m * grav[c] + q * efield[c])  # electric part of eq. 2.7 and gravity
        f[c] = fc
        a[c] = v0[c, n] + h * (phi * fc + (1.0 - phi) * f0[c, n])
    # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m
    s = phi * h * q
    u0, u1, u2 = s * bfield[0], s * bfield[1], s * bfield[2]
    au = a[0] * u0 + a[1] * u1 + a[2] * u2
    inv = 1.0 / (1.0 + u0 * u0 + u1 * u1 + u2 * u2)
    w0 = (a[0] + (a[1] * u2 - a[2] * u1) + au * u0) * inv
    w1 = (a[1] + (a[2] * u0 - a[0] * u2) + au * u1) * inv
    w2 = (a[2] + (a[0] * u1 - a[1] * u0) + au * u2) * inv
    v1[0, n] = w0
    v1[1, n] = w1
    v1[2, n] = w2
    f1[0, n] = f[0] + q * (w1 * bfield[2] - w2 * bfield[1])
    f1[1, n] = f[1] + q * (w2 * bfield[0] - w0 * bfield[2])
    f1[2, n] = f[2] + q * (w0 * bfield[1] - w1 * bfield[0])
    p0 = x0[0, n] + dt * (phi * w0 + (1.0 - phi) * v0[0, n])
    p1 = x0[1, n] + dt * (phi * w1 + (1.0 - phi) * v0[1, n])
    p2 = x0[2, n] + dt * (phi * w2 + (1.0 - phi) * v0[2, n])
    x1[0, n] = p0
    x1[1, n] = p1
    x1[2, n] = p2
    if skip_err[n] == 0:
        e0, e1, e2 = p0 - xk[0, n], p1 - xk[1, n], p2 - xk[2, n]
        g0, g1, g2 = p0 - x0[0, n], p1 - x0[1, n], p2 - x0[2, n]
        red[0, t] = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        red[1, t] = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)


@cuda.jit(cache=False)
def spin(ms):
    """Sleeps about ms milliseconds on the GPU: the evaluations queued behind it then run back
    to back, and events around them time the kernels alone (gpu.py)."""
    if cuda.grid(1) == 0:
        for _ in range(ms):
            for _ in range(100):
                cuda.nanosleep(10000)


class CudaEvaluation:
    """Device copies of one evaluation's inputs and outputs (the arrays of ``gpu.py``'s case
    files) and its two launches; ``evaluate()`` launches both, ``synchronize()`` waits."""

    def __init__(self, case: dict):
        nx, ny = int(case["nx"]), int(case["ny"])
        self.node_count = nx * ny
        self.seg_count = ny * (nx - 1) + (ny - 1) * nx
        dev = {k: cuda.to_device(np.ascontiguousarray(case[k])) for k in (
            "xk", "x0", "v0", "f0", "alpha_c", "coef", "inv_l02", "mass", "inv_mass", "charge",
            "skip_err", "efield", "bfield", "grav")}
        self.t_seg = cuda.device_array((3, self.seg_count))
        self.alpha_t = cuda.device_array(self.seg_count)
        self.err_rows = cuda.device_array((2, ny))
        self.x1 = cuda.device_array((3, self.node_count))
        self.v1 = cuda.device_array((3, self.node_count))
        self.f1 = cuda.device_array((3, self.node_count))
        blocks_s = (self.seg_count + THREADS - 1) // THREADS
        blocks_n = ((nx + THREADS - 1) // THREADS, ny)  # a block: THREADS nodes of one row
        kind, fung_h, u_crit, rate = (int(case["kind"]), float(case["fung_h"]),
                                      float(case["u_crit"]), float(case["rate"]))
        self._dev = dev
        self._launches = (
            (yarn_tension[blocks_s, THREADS],
             (dev["xk"], nx, ny * (nx - 1), ny, self.seg_count, dev["alpha_c"], dev["coef"],
              dev["inv_l02"], kind, fung_h, u_crit, rate, self.t_seg, self.alpha_t,
              self.err_rows)),
            (node_update[blocks_n, THREADS],
             (dev["xk"], dev["x0"], dev["v0"], dev["f0"], self.t_seg, nx, ny, dev["mass"],
              dev["inv_mass"], dev["charge"], float(case["phi"]), float(case["dt"]),
              dev["efield"], dev["bfield"], int(case["region"]), float(case["z0"]),
              dev["grav"], dev["skip_err"], self.x1, self.v1, self.f1, self.err_rows)),
        )

    def evaluate(self) -> None:
        """One force evaluation + node update: both launches, queued (no wait)."""
        for kernel, args in self._launches:
            kernel(*args)

    @staticmethod
    def synchronize() -> None:
        cuda.synchronize()

    def results(self) -> dict[str, np.ndarray]:
        """Outputs in emfabric's layout: (3, count) vectors, (seg_count,) damage, (2, ny) sums."""
        cuda.synchronize()
        return {"alpha_t": self.alpha_t.copy_to_host(), "x1": self.x1.copy_to_host(),
                "v1": self.v1.copy_to_host(), "f1": self.f1.copy_to_host(),
                "err_rows": self.err_rows.copy_to_host()}
