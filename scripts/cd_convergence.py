"""Central differences against a converged run: the largest error of each component of ω that
matters (peak above 1 % of the largest) over the run and at its end, as a fraction of that
component's peak, and the energy balance error, per courant number.

    python scripts/cd_convergence.py [SCENARIO] [--end-time T] [--courant C ...]
                                     [--reference converged | defaults | fine-cd]

Default: demo-small (30 × 30) to 50 µs, courant 0.5 0.25 0.125 0.0625 0.03125, the reference a
φ run at dt_max = 1e-8 s and tolerance 1e-9 (docs/theory.md §4.1 quotes its output). Several
minutes on two cores. `paper-field --end-time 1.5e-3 --courant 0.5 --reference defaults`
compares with the φ-scheme at its defaults instead (a converged φ run of the whole paper-field
takes hours); `--reference fine-cd` with central differences at courant 0.0625 (minutes).
"""

from __future__ import annotations

import argparse

import numpy as np

import emfabric


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenario", nargs="?", default="demo-small")
    p.add_argument("--end-time", type=float, default=50e-6)
    p.add_argument("--courant", type=float, nargs="+",
                   default=[0.5, 0.25, 0.125, 0.0625, 0.03125])
    p.add_argument("--reference", choices=["converged", "defaults", "fine-cd"],
                   default="converged")
    args = p.parse_args()
    base = {"solver.end_time": args.end_time}
    reference = {"converged": {"solver.dt_max": 1e-8, "solver.tolerance": 1e-9},
                 "defaults": {"solver.integrator": "phi"},
                 "fine-cd": {"solver.integrator": "central-difference",
                             "solver.courant": 0.0625}}[args.reference]
    ref = emfabric.run(emfabric.load_scenario(args.scenario, {**base, **reference})).history
    t_ref = ref.time.values
    w_ref = ref.angular_velocity.values
    peaks = np.abs(w_ref).max(axis=0)
    # the components that matter: those with a peak above 1 % of the largest
    comps = [c for c in range(3) if peaks[c] > 0.01 * peaks.max()]
    print(f"{args.scenario} to {args.end_time:g} s; reference ({args.reference}): "
          f"{ref.sizes['time'] - 1} steps, peak |ω| = "
          + ", ".join(f"{'xyz'[c]}: {peaks[c]:.4g}" for c in range(3)) + " rad/s")
    phi = [("phi (defaults)", {"solver.integrator": "phi"})]
    runs = (phi if args.reference != "defaults" else []) + [
        (f"central-difference {c:g}", {"solver.integrator": "central-difference",
                                       "solver.courant": c}) for c in args.courant]
    print(f"{'scheme':28s}{'steps':>8s}{'evals':>8s}"
          + "".join(f"{'max/peak ' + 'xyz'[c]:>12s}{'end/peak ' + 'xyz'[c]:>12s}" for c in comps)
          + f"{'balance [J]':>13s}")
    for name, over in runs:
        res = emfabric.run(emfabric.load_scenario(args.scenario, {**base, **over}))
        ds = res.history
        cols = ""
        for c in comps:
            w = np.interp(t_ref, ds.time.values, ds.angular_velocity.values[:, c])
            cols += (f"{np.abs(w - w_ref[:, c]).max() / peaks[c]:12.4f}"
                     f"{abs(w[-1] - w_ref[-1, c]) / peaks[c]:12.4f}")
        print(f"{name:28s}{res.summary['steps']:8d}{res.summary['force_evaluations']:8d}"
              + cols + f"{float(ds.energy_balance_error[-1]):13.4g}", flush=True)


if __name__ == "__main__":
    main()
