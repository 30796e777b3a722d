"""The spin a strong magnetic field induces, against the step: central differences at courant
0.25 (the default) and 0.125 against a run at a sixteenth of the default step, for several
uniform fields B e_x on a small sheet (docs/theory.md §4.1, "The gyration limit").

    python scripts/gyration_convergence.py [--field B ...] [--nodes N] [--end-time T]

Default: demo-small on 20 × 20 nodes to 50 µs in 0.05, 1 and 5 T (about two minutes on two
cores). Prints, per field and step: the steps taken, the largest cyclotron turn ω_c Δt of a
charged node in one step, ω_x at the end (the reference's beside it), the largest |Δω_x| over
the run as a fraction of the reference's peak |ω_x|, and the energy balance error at the end.
Only public keys and history variables: it runs on any checkout (PYTHONPATH=CHECKOUT/src).
"""

from __future__ import annotations

import argparse

import numpy as np

import emfabric
from emfabric.sim.builder import build_model


def _run(b: float, courant: float, nodes: int, end: float):
    sc = emfabric.load_scenario("demo-small", {
        "fabric.nodes": [nodes, nodes], "solver.end_time": end, "field.B": [b, 0.0, 0.0],
        "solver.courant": courant})
    h = emfabric.run(sc).history
    model = build_model(sc)
    free = model.nodes.inv_mass > 0.0
    wc = float(np.max(np.abs(model.nodes.charge[free]) * model.nodes.inv_mass[free])) * abs(b)
    return (h.time.values, h.angular_velocity.values[:, 0], int(h.time.size) - 1,
            wc * float(h.dt.values[1:].max()), float(h.energy_balance_error.values[-1]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--field", type=float, nargs="+", default=[0.05, 1.0, 5.0],
                   help="uniform B along x [T]")
    p.add_argument("--nodes", type=int, default=20)
    p.add_argument("--end-time", type=float, default=50e-6)
    a = p.parse_args()
    print(f"emfabric {emfabric.__version__}: demo-small {a.nodes} x {a.nodes} to "
          f"{a.end_time:g} s, against courant 0.25/16")
    print(f"{'B [T]':>6} {'courant':>8} {'steps':>7} {'max ω_cΔt':>10} {'ω_x end':>9} "
          f"{'reference':>10} {'ω_x error':>10} {'energy err [J]':>15}")
    for b in a.field:
        t_r, w_r, n_r, turn_r, e_r = _run(b, 0.25 / 16, a.nodes, a.end_time)
        peak = float(np.abs(w_r).max())
        for courant in (0.25, 0.125):
            t, w, n, turn, e = _run(b, courant, a.nodes, a.end_time)
            err = float(np.abs(w - np.interp(t, t_r, w_r)).max()) / peak
            print(f"{b:6g} {courant:8g} {n:7d} {turn:10.3g} {w[-1]:9.1f} {w_r[-1]:10.1f} "
                  f"{100 * err:9.2f}% {e:15.3g}")
        print(f"{b:6g} {0.25 / 16:8g} {n_r:7d} {turn_r:10.3g} {w_r[-1]:9.1f} {'':>10} "
              f"{'':>10} {e_r:15.3g}")


if __name__ == "__main__":
    main()
