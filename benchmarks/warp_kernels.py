"""emfabric's force evaluation + node update written for NVIDIA Warp, to time on its CPU device.

The same arithmetic as ``emfabric._kernels.nodes.fused_iterate`` (the yarn law of
``emfabric._kernels.materials``, one fixed-point iterate of the φ-scheme), written the
way a Warp simulator would: node arrays of ``wp.vec3d`` (array of structures), one thread per
segment, then one thread per node gathering its four neighbouring tensions. Each evaluation is
two launches, recorded once (``record_cmd=True``) so that Python's share of a launch is as small
as Warp allows. Only imported by ``bench.py`` when warp-lang is installed.
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.config.log_level = wp.LOG_ERROR  # no banner, no per-module load lines

f64 = wp.float64
vec3d = wp.vec3d

MATERIAL_FUNG = wp.constant(1)
REGION_HALF_SPACE = wp.constant(1)


@wp.kernel
def yarn_tension_kernel(
    x: wp.array(dtype=vec3d),
    nx: int,
    nw: int,
    ny: int,
    alpha_c: wp.array(dtype=f64),
    coef: wp.array(dtype=f64),
    inv_l02: wp.array(dtype=f64),
    kind: int,
    fung_h: f64,
    u_crit: f64,
    rate: f64,
    t_out: wp.array(dtype=vec3d),
    alpha_out: wp.array(dtype=f64),
    err_rows: wp.array2d(dtype=f64),
):
    """Tension vector t_s = α·coef_s·S(U²)·d, d = x_b − x_a, and trial damage of segment s."""
    s = wp.tid()
    # warp yarns first (a = j·nx + i = s + j, b = a + 1), then fill yarns (b = a + nx)
    a = s - nw
    step = nx
    if s < nw:
        a = s + s // (nx - 1)
        step = 1
    d = x[a + step] - x[a]
    u2 = wp.dot(d, d) * inv_l02[s]
    alpha = alpha_c[s]
    # damage, eq. 2.6: irreversible, only past the critical stretch
    if u2 > u_crit * u_crit:
        if rate > f64(0.0):
            trial = wp.exp(-rate * (wp.sqrt(u2) - u_crit) / u_crit)
            alpha = wp.min(alpha, trial)
    alpha_out[s] = alpha
    # relaxed Kirchhoff–Saint-Venant (or Fung) stress factor: zero in compression
    e = f64(0.5) * wp.max(u2 - f64(1.0), f64(0.0))
    if kind == MATERIAL_FUNG:
        e = fung_h * e * wp.exp(f64(0.5) * fung_h * e * e)
    t_out[s] = (alpha * coef[s] * e) * d
    # the node launch accumulates the error row sums: clear them here (this launch runs first)
    if s < ny:
        err_rows[0, s] = f64(0.0)
        err_rows[1, s] = f64(0.0)


@wp.kernel
def node_update_kernel(
    xk: wp.array(dtype=vec3d),
    x0: wp.array(dtype=vec3d),
    v0: wp.array(dtype=vec3d),
    f0: wp.array(dtype=vec3d),
    t_seg: wp.array(dtype=vec3d),
    nx: int,
    ny: int,
    mass: wp.array(dtype=f64),
    inv_mass: wp.array(dtype=f64),
    charge: wp.array(dtype=f64),
    phi: f64,
    dt: f64,
    efield: vec3d,
    bfield: vec3d,
    region: int,
    z0: f64,
    grav: vec3d,
    skip_err: wp.array(dtype=wp.uint8),
    x1: wp.array(dtype=vec3d),
    v1: wp.array(dtype=vec3d),
    f1: wp.array(dtype=vec3d),
    err_rows: wp.array2d(dtype=f64),
):
    """One φ-scheme iterate of node (i, j), forces at the iterate xk (eqs. 3.2, A12-A13)."""
    j, i = wp.tid()
    n = j * nx + i
    im = inv_mass[n]
    if im == f64(0.0):
        # fixed node: never moves
        x1[n] = x0[n]
        v1[n] = v0[n]
        f1[n] = vec3d()
        return
    # yarn forces: right minus left tension, up minus down
    nw = ny * (nx - 1)
    sr = j * (nx - 1) + i
    su = nw + n
    f = vec3d()
    if i < nx - 1:
        f = t_seg[sr]
    if i > 0:
        f = f - t_seg[sr - 1]
    g = vec3d()
    if j < ny - 1:
        g = t_seg[su]
    if j > 0:
        g = g - t_seg[su - nx]
    m = mass[n]
    xn = xk[n]
    q = f64(0.0)
    if region != REGION_HALF_SPACE or xn[2] < z0:
        q = charge[n]
    # electric part of eq. 2.7 and gravity
    f = f + g + (m * grav + q * efield)
    h = dt * im
    vn = v0[n]
    a = vn + h * (phi * f + (f64(1.0) - phi) * f0[n])
    # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m
    u = (phi * h * q) * bfield
    au = wp.dot(a, u)
    inv = f64(1.0) / (f64(1.0) + u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    v = (a + wp.cross(a, u) + au * u) * inv
    v1[n] = v
    f1[n] = f + q * wp.cross(v, bfield)
    p = x0[n] + dt * (phi * v + (f64(1.0) - phi) * vn)
    x1[n] = p
    if skip_err[n] == wp.uint8(0):
        wp.atomic_add(err_rows, 0, j, wp.length(p - xn))
        wp.atomic_add(err_rows, 1, j, wp.length(p - x0[n]))


def _vec(a: np.ndarray) -> wp.array:
    """A (3, count) component-major float64 array as a Warp array of vec3d."""
    return wp.array(np.ascontiguousarray(a.T), dtype=vec3d, device="cpu")


def _scalar(a: np.ndarray, dtype=f64) -> wp.array:
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device="cpu")


class WarpEvaluation:
    """Warp copies of one emfabric evaluation's inputs and outputs, and its two launches.

    Built from tuples of the model's records (``grid, fab, mat, fld``: grid size; node mass,
    inverse mass, charge, yarn stiffness and 1/L0²; material law; field) and the arrays of one
    iterate; ``evaluate()`` runs both launches and waits.
    """

    def __init__(self, grid, fab, mat, fld, xk, x0, v0, f0, alpha_c, skip_err, phi, dt):
        nx, ny = (int(c) for c in grid)
        mass, inv_mass, charge, coef, inv_l02 = fab
        kind, fung_h, u_crit, rate = mat
        efield, bfield, region, z0, grav = fld
        nodes = nx * ny
        segs = ny * (nx - 1) + (ny - 1) * nx
        self.node_count, self.seg_count = nodes, segs
        self.xk, self.x0, self.v0, self.f0 = _vec(xk), _vec(x0), _vec(v0), _vec(f0)
        self.alpha_c = _scalar(alpha_c)
        self.t_seg = wp.zeros(segs, dtype=vec3d, device="cpu")
        self.alpha_t = wp.zeros(segs, dtype=f64, device="cpu")
        self.err_rows = wp.zeros((2, ny), dtype=f64, device="cpu")
        self.x1 = wp.zeros(nodes, dtype=vec3d, device="cpu")
        self.v1 = wp.zeros(nodes, dtype=vec3d, device="cpu")
        self.f1 = wp.zeros(nodes, dtype=vec3d, device="cpu")
        self._keep = (_scalar(coef), _scalar(inv_l02), _scalar(mass), _scalar(inv_mass),
                      _scalar(charge), _scalar(skip_err, wp.uint8))
        coef_w, inv_l02_w, mass_w, inv_mass_w, charge_w, skip_w = self._keep
        self._launches = (
            wp.launch(yarn_tension_kernel, dim=segs, device="cpu", record_cmd=True, inputs=[
                self.xk, nx, ny * (nx - 1), ny, self.alpha_c, coef_w, inv_l02_w, int(kind),
                f64(fung_h), f64(u_crit), f64(rate), self.t_seg, self.alpha_t,
                self.err_rows]),
            wp.launch(node_update_kernel, dim=(ny, nx), device="cpu", record_cmd=True, inputs=[
                self.xk, self.x0, self.v0, self.f0, self.t_seg, nx, ny, mass_w, inv_mass_w,
                charge_w, f64(phi), f64(dt), vec3d(*efield), vec3d(*bfield), int(region),
                f64(z0), vec3d(*grav), skip_w, self.x1, self.v1, self.f1, self.err_rows]),
        )

    def evaluate(self) -> None:
        """One force evaluation + node update (both launches, synchronised)."""
        for launch in self._launches:
            launch.launch()
        wp.synchronize_device("cpu")

    def results(self) -> dict[str, np.ndarray]:
        """Outputs in emfabric's layout: (3, count) vectors, (seg_count,) damage, (2, ny) sums."""
        return {
            "t_seg": self.t_seg.numpy().T,
            "alpha_t": self.alpha_t.numpy(),
            "x1": self.x1.numpy().T,
            "v1": self.v1.numpy().T,
            "f1": self.f1.numpy().T,
            "err_rows": self.err_rows.numpy(),
        }


def init() -> str:
    """Initialise Warp (CPU device); returns its version."""
    wp.init()
    return wp.__version__
