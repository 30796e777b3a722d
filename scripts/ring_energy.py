"""Why central differences gain energy at a large step when a charged sheet rings in a field.

docs/theory.md §4.1 ("Where the energy comes from"). Three measurements:

1. The fabric's energy (kinetic + stored + released by damage) of the paper's 100 × 100 charged
   sheet, clamped, launched at 150 m/s normal to itself with no projectile, over 600 µs, with
   and without the paper's B = 0.05 e_x T, for each courant number. Nothing else does work or
   dissipates (no contact, E = 0, and the magnetic force does no work), so every joule gained
   is the scheme's.
2. How often a yarn segment goes slack or taut (its stretch U crosses 1, the kink of the
   tension-only law) per step, with and without the field, at one courant number.
3. The mechanism alone: a mass through a one-sided linear spring (force −k x for x > 0, none
   for x < 0) under the same kick–drift–kick, its kinetic energy after leaving against before,
   averaged over where the step grid meets the spring (20 000 phases).
4. What it is not: linear springs (a dense random stiffness) in a uniform B under the same
   step (half kick, half rotation, drift, half rotation, half kick): the largest |λ| − 1 of
   the step matrix, which is 0 (round-off) for a scheme that neither gains nor loses.
With --phi, the ringing sheet also under the φ-scheme at its defaults (B = 0 and B).
With --long T, 5. the ringing sheet in the field run on to T with a step loop: the gain of its
energy E = Σ ½m|v|² + V (kinetic and stored; damage's release would show as a loss) and of
the modified energy Ẽ = E − Σ (h²/8m)|f|² (f the node force without its magnetic part) that
kick–drift–kick keeps where each step's trapezoid of the yarns' work is exact, every 2000
steps, at each courant number of --long-courant: a gain of E that Ẽ does not share would be
energy moved into the highest modes (bounded), one that both share is heating (theory §4.1).
With --bulk-viscosity Q [Q ...], 6. the ringing sheet in the field with the yarns' linear bulk
viscosity q (`solver.bulk_viscosity`, the damping ratio of the highest mode) at each courant
number: whether damping the highest modes takes out the heating, and what it takes from the
sheet (the viscous dissipation, `dissipation_viscous`), which the paper's model does not have.

    python scripts/ring_energy.py                      # courant 0.5 0.4 0.3 0.25, ~2 min
    python scripts/ring_energy.py --courant 0.5 0.25 --end-time 3e-4 --phi
    python scripts/ring_energy.py --long 2.4e-3 --long-courant 0.5 0.25   # ~12 min more
    python scripts/ring_energy.py --courant 0.5 --bulk-viscosity 0.0002 0.001 0.005
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

import emfabric
from emfabric.integrators import make_integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state

RING = {"projectile.shape": "none", "fabric.velocity": [0.0, 0.0, -150.0],
        "solver.integrator": "central-difference"}


def ring(courant: float | None, b: float, end_time: float,
         viscosity: float = 0.0) -> tuple[float, float, int, float]:
    """(fabric energy at the end less at the start, the energy balance error at the end, steps,
    the viscous dissipation) of the ringing sheet; courant None: the φ-scheme at its defaults;
    viscosity: solver.bulk_viscosity (central differences)."""
    over = {**RING, "field.B": [b, 0.0, 0.0], "solver.end_time": end_time}
    if courant is None:
        over["solver.integrator"] = "phi"
    else:
        over["solver.courant"] = courant
        over["solver.bulk_viscosity"] = viscosity
    sc = emfabric.load_scenario("paper-field", over)
    h = emfabric.run(sc, None).history
    e = (h.kinetic_energy_fabric + h.strain_energy + h.dissipation_damage).values
    return (float(e[-1] - e[0]), float(h.energy_balance_error[-1]), len(h.time) - 1,
            float(h.dissipation_viscous[-1]))


def _stepped(courant: float, b: float, end_time: float):
    """The ringing sheet's model and integrator in B = b e_x at `courant`, for a step loop."""
    sc = emfabric.load_scenario("paper-field", {**RING, "field.B": [b, 0.0, 0.0],
                                                "solver.courant": courant,
                                                "solver.end_time": end_time})
    model = build_model(sc)
    return model, make_integrator(model)


def crossings(courant: float, b: float, end_time: float) -> tuple[float, float]:
    """(segments whose stretch crosses 1 per step, mean fraction of segments slack) of the
    ringing sheet, from a step loop."""
    model, integ = _stepped(courant, b, end_time)
    ends = model.yarns.ends
    rest = model.yarns.rest_length
    s_in = initial_state(model)
    s_out = s_in.copy()

    def taut(x: np.ndarray) -> np.ndarray:
        d = x[:, ends[:, 1]] - x[:, ends[:, 0]]
        return np.sqrt((d * d).sum(axis=0)) > rest

    prev = taut(s_in.node_x)
    crossed = 0
    slack = 0.0
    steps = 0
    while s_in.t < end_time:
        integ.step(s_in, s_out, dt_limit=end_time - s_in.t)
        s_in, s_out = s_out, s_in
        now = taut(s_in.node_x)
        crossed += int((now != prev).sum())
        slack += float((~now).mean())
        prev = now
        steps += 1
    return crossed / steps, slack / steps


def long_ring(courant: float, b: float, end_time: float, every: int = 2000) -> None:
    """Print the ringing sheet's E and Ẽ gained (see the module docstring), every `every`
    steps and at the end, stepping to end_time at `courant` in B = b e_x."""
    model, integ = _stepped(courant, b, end_time)
    ends = model.yarns.ends
    rest = model.yarns.rest_length
    coef = model.yarns.stiffness
    mass, inv_mass, charge = model.nodes.mass, model.nodes.inv_mass, model.nodes.charge
    field = np.array([b, 0.0, 0.0])

    def energy(st) -> float:
        d = st.node_x[:, ends[:, 1]] - st.node_x[:, ends[:, 0]]
        e = 0.5 * np.maximum((d * d).sum(axis=0) / rest**2 - 1.0, 0.0)
        return float(0.5 * (mass * (st.node_v**2).sum(axis=0)).sum()
                     + (st.seg_alpha * coef * rest**2 * 0.5 * e * e).sum())

    def gap(st, h: float) -> float:
        f = st.node_f - charge * np.cross(st.node_v.T, field).T
        return float((h * h / 8.0 * inv_mass * (f * f).sum(axis=0)).sum())

    s_in = initial_state(model)
    s_out = s_in.copy()
    e0 = energy(s_in)
    g0 = None
    steps = 0
    h = 0.0
    while s_in.t < end_time:
        integ.step(s_in, s_out, dt_limit=end_time - s_in.t)
        if s_out.t < end_time:  # the last step, cut short to end_time, is not the scheme's h
            h = s_out.t - s_in.t
        if g0 is None:
            g0 = gap(s_in, h)
        s_in, s_out = s_out, s_in
        steps += 1
        if steps % every == 0 or s_in.t >= end_time:
            e = energy(s_in)
            print(f"{courant:>9g} {steps:>7d} {s_in.t * 1e6:>9.1f} {e - e0:+10.4f} "
                  f"{e - gap(s_in, h) - (e0 - g0):+10.4f}", flush=True)


def one_sided_spring(courant: float, phases: int = 20000) -> tuple[float, float]:
    """(mean, rms) of the relative kinetic-energy gain of a unit mass at unit speed through a
    one-sided spring of ω = 1, kick–drift–kick with Δt = courant·2/ω, over `phases` offsets of
    the step grid."""
    h = 2.0 * courant
    x = -1.0 + h * (np.arange(phases) + 0.5) / phases
    v = np.ones(phases)
    f = -np.maximum(x, 0.0)
    for _ in range(int(10.0 / h) + 10):  # in at t ≈ 1, out at t ≈ 1 + π, then free
        v += 0.5 * h * f
        x += h * v
        f = -np.maximum(x, 0.0)
        v += 0.5 * h * f
    assert (x < 0.0).all(), "a phase is still in the spring"
    gain = v * v - 1.0  # (½v² − ½)/½
    return float(gain.mean()), float(gain.std())


def boris_linear(courant: float, wc_over_w: float, nodes: int = 6, seed: int = 1) -> float:
    """Largest |λ| − 1 of the step matrix of central differences (half kick, half rotation,
    drift, half rotation, half kick) on `nodes` unit masses joined by a dense random stiffness
    K (3 nodes × 3 components), in a uniform B along x with cyclotron frequency wc_over_w × the
    highest ω of K, at Δt = courant · 2/ω_max."""
    a = np.random.default_rng(seed).normal(size=(3 * nodes, 3 * nodes))
    k = a @ a.T
    w = float(np.sqrt(np.linalg.eigvalsh(k).max()))
    h = courant * 2.0 / w
    theta = wc_over_w * w * h / 2.0  # the angle of each half rotation
    c, s = np.cos(theta), np.sin(theta)
    r = np.kron(np.eye(nodes), np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]]))
    i, z = np.eye(3 * nodes), np.zeros((3 * nodes, 3 * nodes))
    kick = np.block([[i, z], [-0.5 * h * k, i]])
    turn = np.block([[i, z], [z, r]])
    drift = np.block([[i, h * i], [z, i]])
    step = kick @ turn @ drift @ turn @ kick
    return float(np.abs(np.linalg.eigvals(step)).max() - 1.0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--courant", type=float, nargs="+", default=[0.5, 0.4, 0.3, 0.25])
    p.add_argument("--field", type=float, default=0.05, help="B_x with the field [T]")
    p.add_argument("--end-time", type=float, default=6e-4, help="[s]")
    p.add_argument("--crossings-courant", type=float, default=0.25)
    p.add_argument("--phi", action="store_true", help="also the φ-scheme at its defaults")
    p.add_argument("--long", type=float, default=0.0, metavar="T",
                   help="5.: the ringing sheet in the field on to T [s] (0: not run)")
    p.add_argument("--long-courant", type=float, nargs="+", default=[0.5, 0.25])
    p.add_argument("--bulk-viscosity", type=float, nargs="+", default=[], metavar="Q",
                   help="6.: the ringing sheet in the field with solver.bulk_viscosity = Q, "
                        "at each --courant")
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    print("1. the ringing sheet: fabric energy gained over the run [J] (balance error [J], steps)")
    print(f"{'courant':>9} {'B = 0':>26} {f'B = {a.field:g} T':>26}")
    for c in a.courant:
        cols = []
        for b in (0.0, a.field):
            gain, balance, steps, _ = ring(c, b, a.end_time)
            cols.append(f"{gain:+9.3f} ({balance:+7.3f}, {steps:5d})")
        print(f"{c:>9g} {cols[0]:>26} {cols[1]:>26}", flush=True)
    if a.phi:
        cols = []
        for b in (0.0, a.field):
            gain, balance, steps, _ = ring(None, b, a.end_time)
            cols.append(f"{gain:+9.3f} ({balance:+7.3f}, {steps:5d})")
        print(f"{'phi':>9} {cols[0]:>26} {cols[1]:>26}", flush=True)
    print(f"\n2. segments going slack or taut per step at courant {a.crossings_courant:g}")
    for b in (0.0, a.field):
        per_step, slack = crossings(a.crossings_courant, b, a.end_time)
        print(f"   B = {b:g} T: {per_step:8.1f} per step; {100 * slack:5.2f} % of the segments "
              f"slack on average", flush=True)
    print("\n3. a mass through a one-sided spring, kick-drift-kick: energy gained per passage")
    print(f"{'courant':>9} {'mean':>11} {'rms':>10}")
    for c in (0.1, 0.2, 0.25, 0.3, 0.4, 0.45):
        mean, rms = one_sided_spring(c)
        print(f"{c:>9g} {mean:+11.3e} {rms:10.2e}")
    print("\n4. linear springs in a uniform B, the same step: largest |lambda| - 1 of the step")
    print(f"{'courant':>9} " + " ".join(f"{f'wc/w = {r:g}':>14}" for r in (0.003, 0.01, 0.1)))
    for c in (0.25, 0.5, 0.75, 0.9):
        print(f"{c:>9g} " + " ".join(f"{boris_linear(c, r):>14.1e}" for r in (0.003, 0.01, 0.1)))
    if a.long > 0.0:
        print(f"\n5. the ringing sheet in B = {a.field:g} T on to {a.long:g} s: E and the "
              "modified energy gained [J]")
        print(f"{'courant':>9} {'steps':>7} {'t [us]':>9} {'E':>10} {'E~':>10}")
        for c in a.long_courant:
            long_ring(c, a.field, a.long)
    if a.bulk_viscosity:
        print(f"\n6. the ringing sheet in B = {a.field:g} T with the bulk viscosity q: fabric "
              "energy gained, viscous dissipation, their sum [J]")
        print(f"{'courant':>9} {'q':>8} {'gained':>10} {'viscous':>10} {'sum':>10}")
        for c in a.courant:
            for q in a.bulk_viscosity:
                gain, _, _, visc = ring(c, a.field, a.end_time, q)
                print(f"{c:>9g} {q:>8g} {gain:+10.4f} {visc:10.4f} {gain + visc:+10.4f}",
                      flush=True)


if __name__ == "__main__":
    main()
