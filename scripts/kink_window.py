"""Would a kink treated in time let central differences take a larger step? (docs/theory.md §4.1)

Central differences gain energy where a yarn's stretch crosses 1 within a step (the kink of the
tension-only law) and the field keeps the sheet crossing it: at courant 0.5 the paper's
charged sheet ringing in B gains ~0.5–0.7 J of its 89 J over 600 µs, which is what keeps the
default at 0.25. This script tries the remedy of giving each segment whose stretch crosses 1
within the kick's window [t_n − Δt/2, t_n + Δt/2] the mean of its tension over that window
instead of its value at t_n, along the straight paths of its two nodes: the drift that reached
x_n before t_n, the next drift after it (predicted with the force itself, `--iterations`
times). Segments that stay on one side keep their tension at t_n; the force stays along the
segment (momentum and angular momentum as before). A NumPy model of the same sheet (no
damage, a fixed step: courant × the stable step of the initial state, kick–drift–kick with
the exact magnetic rotation), not the package's kernels:

1. A mass through a one-sided linear spring (ω = 1, as ring_energy.py part 3): the energy
   gained per passage, mean and spread over where the step grid meets the spring.
2. The paper's 100 × 100 charged sheet, clamped, launched at 150 m/s with no projectile in
   B = 0.05 e_x T (ring_energy.py part 1, without damage): the fabric's energy (kinetic +
   stored) at --end-time less at the start, plain and windowed.

    python scripts/kink_window.py                       # courant 0.5 0.25, about 4 minutes
    python scripts/kink_window.py --courant 0.4 --iterations 4
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

import emfabric
from emfabric.integrators import make_integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state


def _window_mean(g0: np.ndarray, g_before: np.ndarray, g_after: np.ndarray) -> np.ndarray:
    """Mean of max(g, 0)/2 over the window, g = U² − 1 linear on each half: g_before at its
    start, g0 at t_n, g_after at its end."""
    def half(p, q):  # mean over a half of max(linear from p to q, 0)/2
        pos = np.maximum(np.maximum(p, q), 0.0)
        den = np.abs(q - p)
        part = np.where(den > 0, pos * pos / (2 * np.where(den > 0, den, 1.0)), 0.0)
        return 0.5 * np.where((p >= 0) & (q >= 0), 0.5 * (p + q), part)
    return 0.5 * (half(g0, g_before) + half(g0, g_after))


def spring_passage(courant: float, phase: float, iterations: int) -> float:
    """Energy gained by a unit mass at speed 1 through a one-sided spring (k = 1), plain
    (iterations 0) or windowed."""
    h = 2.0 * courant
    x, v = -h * (5.0 + phase), 1.0  # v: the velocity of the drift that reached x

    def force(x):
        return -x if x > 0.0 else 0.0

    for _ in range(100_000):
        f = force(x)
        for _ in range(iterations):
            ahead = v + h * f  # the next drift's velocity with this force
            before, after = x - 0.5 * h * v, x + 0.5 * h * ahead
            if min(before, x, after) < 0.0 < max(before, x, after):
                # U² − 1 ↔ x here: the mean of max(x, 0) over the window, times −1
                f = -2.0 * float(_window_mean(np.array(x), np.array(before),
                                              np.array(after)))
        v += h * f
        x += h * v
        if v < 0.0 and x < -3.0 * h * abs(v):
            break
    return 0.5 * v * v - 0.5


def ringing_sheet(courant: float, iterations: int, end_time: float, b: float = 0.05) -> float:
    """Fabric energy gained [J] by the ringing sheet by end_time, plain (iterations 0) or
    windowed."""
    sc = emfabric.load_scenario("paper-field", {
        "projectile.shape": "none", "fabric.velocity": [0.0, 0.0, -150.0],
        "solver.integrator": "central-difference", "field.B": [b, 0.0, 0.0],
        "fabric.damage.rate": 0.0})
    model = build_model(sc)
    h = courant * make_integrator(model).stable_dt(initial_state(model)) / model.options.courant
    nodes, yarns = model.nodes, model.yarns
    n = nodes.x0.shape[1]
    ia, ib = yarns.ends[:, 0], yarns.ends[:, 1]
    k, ir2, rest = yarns.stiffness, yarns.inv_rest2, yarns.rest_length
    inv_m, free = nodes.inv_mass, nodes.inv_mass > 0
    x = nodes.x0.copy()
    v = np.where(free, np.asarray(model.node_v0, dtype=float).reshape(3, -1), 0.0)
    bn = abs(b)
    axis = np.array([np.sign(b) or 1.0, 0.0, 0.0])
    angle = -nodes.charge * inv_m * bn * h / 2.0  # dv/dt = (q/m) v × B, half a step
    cos, sin = np.cos(angle), np.sin(angle)

    def rotate(v):
        along = axis @ v
        return (v * cos + np.cross(axis[:, None], v, axis=0) * sin
                + np.outer(axis, along) * (1 - cos))

    def node_forces(d, factor):
        t = (k * factor) * d
        return np.stack([np.bincount(ia, t[i], n) - np.bincount(ib, t[i], n) for i in range(3)])

    def forces(x, v_before, v_now):
        d = x[:, ib] - x[:, ia]
        g0 = (d * d).sum(0) * ir2 - 1.0
        factor = 0.5 * np.maximum(g0, 0.0)
        f = node_forces(d, factor)
        for _ in range(iterations):
            ahead = rotate(v_now + h * f * inv_m)  # the next drift's velocity with this force
            rate_b = 2.0 * (d * (v_before[:, ib] - v_before[:, ia])).sum(0) * ir2
            rate_a = 2.0 * (d * (ahead[:, ib] - ahead[:, ia])).sum(0) * ir2
            gb, ga = g0 - 0.5 * h * rate_b, g0 + 0.5 * h * rate_a
            lo, hi = np.minimum(np.minimum(gb, ga), g0), np.maximum(np.maximum(gb, ga), g0)
            cross = (lo < 0) & (hi > 0)
            windowed = factor.copy()
            windowed[cross] = _window_mean(g0[cross], gb[cross], ga[cross])
            f = node_forces(d, windowed)
        return f

    def energy(x, v):
        d = x[:, ib] - x[:, ia]
        e = 0.5 * np.maximum((d * d).sum(0) * ir2 - 1.0, 0.0)
        return (0.5 * (nodes.mass[free] * (v[:, free] ** 2).sum(0)).sum()
                + (k * rest * rest * e * e / 2.0).sum())

    f = forces(x, v, v)
    e0, t = energy(x, v), 0.0
    while t < end_time:
        v = rotate(v + 0.5 * h * f * inv_m)
        x = x + h * v
        drift = v
        v = rotate(v)
        f = forces(x, drift, v)
        v = v + 0.5 * h * f * inv_m
        t += h
    return float(energy(x, v) - e0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--courant", type=float, nargs="+", default=[0.5, 0.25])
    p.add_argument("--spring-courant", type=float, nargs="+", default=[0.25, 0.4, 0.45],
                   help="part 1's (at 0.5 the step is 1/ω and every phase gives the same)")
    p.add_argument("--iterations", type=int, default=2,
                   help="predictions of the next drift per step (windowed)")
    p.add_argument("--end-time", type=float, default=6e-4)
    p.add_argument("--phases", type=int, default=3000)
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    phases = np.random.default_rng(0).random(a.phases)
    print("1. one-sided spring, energy gained per passage of 0.5 (mean / spread over phases)")
    for c in a.spring_courant:
        plain = np.array([spring_passage(c, ph, 0) for ph in phases])
        window = np.array([spring_passage(c, ph, a.iterations) for ph in phases])
        print(f"   courant {c:g}: plain {plain.mean():+.2e} / {plain.std():.1e}, "
              f"windowed {window.mean():+.2e} / {window.std():.1e}")
    print(f"2. ringing sheet in B = 0.05 e_x T, fabric energy gained by {a.end_time:g} s "
          "(of 89.1 J)")
    for c in a.courant:
        print(f"   courant {c:g}: plain {ringing_sheet(c, 0, a.end_time):+.3f} J, windowed "
              f"{ringing_sheet(c, a.iterations, a.end_time):+.3f} J", flush=True)


if __name__ == "__main__":
    main()
