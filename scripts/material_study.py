"""Real fabrics against the same threat (issue 24): the ballistic limit of single plies of three
materials at two areal densities, struck by a .22 FSP, in Cunniff's dimensionless form; the
residual-speed curve against Lambert–Jonas; and the V50 spread that yarn-strength scatter gives.

    python scripts/material_study.py [--out runs/material-study] [--size 0.05]
                                     [--seeds 3] [--workers 2] [--tolerance 4]

Every point is one `emfabric ballistic-limit km2-fsp --set fabric.style=S ...`: one ply of the
style on a --size square frame, one network line per yarn, brittle yarns at the library's
failure strain, no field and no charge, the km2-fsp .22 FSP (5.56 mm, 1.1 g). The heavier ply
of each style doubles its yarns' linear density and its areal density (the same weave of yarns
twice as heavy). Cunniff (1999) found that V50/U*^(1/3), U* = σ_f ε_f/(2ρ)·√(E/ρ), against
A_d·A_p/m_p (areal density × the projectile's presented area / its mass) puts armour of
different fibres on one curve. Then, for the Kevlar 29 ply (the cheapest network), V_BL for
--seeds draws of the yarns' strengths (fabric.material.seed) with the strength scattered
(fabric.damage.weibull_shape = 5) and without: the spread strength scatter gives. A case
already in --out is reused. Each shot runs to its rebound or perforation (a perforating FSP
that carries a plug of torn-out yarn has perforated once the fabric still joined to the frame
is behind it), at most 600 µs. Writes material_study.json, cunniff.png, residual.png and prints
the tables that docs/materials.md quotes.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

STYLES = ("km2-600d-plain", "k29-3000d-plain", "sk76-1760dtex-plain")
RADIUS, MASS = 0.00278, 0.0011  # the km2-fsp .22 FSP [m, kg]


def run_limit(out: Path, name: str, sets: list[str], workers: int, tolerance: float) -> dict:
    folder = out / name
    done = folder / "study_case.json"
    if done.exists():
        return json.loads(done.read_text())
    cmd = [sys.executable, "-m", "emfabric", "ballistic-limit", "km2-fsp", "--out", str(folder),
           "--workers", str(workers), "--tolerance", str(tolerance), "--json"]
    for s in sets:
        cmd += ["--set", s]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    data = json.loads(res.stdout)
    data["wall_s"] = time.perf_counter() - t0
    data["command"] = " ".join(cmd[1:])
    done.write_text(json.dumps(data, indent=2))
    return data


def shots(folder: Path) -> list[dict]:
    """The unseeded shots of a ballistic-limit folder (its ballistic.json)."""
    res = json.loads((folder / "ballistic.json").read_text())
    return [s for s in res["shots"] if s["seed"] is None]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/material-study"))
    p.add_argument("--size", type=float, default=0.05, help="frame side [m]")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--tolerance", type=float, default=4.0)
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)

    from emfabric.config.library import fabric_style, library_material

    base = [f"fabric.size=[{a.size},{a.size}]", "field.B=[0,0,0]", "fabric.charge_per_node=0.0",
            "solver.end_time=6e-4", "output.snapshot_interval=1e-4"]
    area_p = math.pi * RADIUS**2
    rows = []
    for style in STYLES:
        st = fabric_style(style)
        mat = library_material(st.material)
        u_star = mat.tensile_strength * mat.failure_strain / (2 * mat.density) * math.sqrt(
            mat.youngs_modulus / mat.density)
        for heavy in (1, 2):
            sets = [*base, f"fabric.style={style}"]
            if heavy == 2:
                sets += [f"fabric.yarn_linear_density={2 * st.linear_density_tex}",
                         f"fabric.areal_density={2 * st.areal_density}"]
            name = f"{style}-x{heavy}"
            r = run_limit(a.out, name, sets, a.workers, a.tolerance)
            ad = heavy * st.areal_density
            rows.append({"case": name, "style": style, "material": st.material,
                         "areal_density": ad, "v_bl": r["v_bl"], "u_star": u_star,
                         "x": ad * area_p / MASS, "y": r["v_bl"] / u_star ** (1 / 3),
                         "lambert_jonas": r["lambert_jonas"], "wall_s": r.get("wall_s")})
            print(f"{name:>24}: A_d = {1e3 * ad:6.1f} g/m², V_BL = {r['v_bl']:6.1f} m/s, "
                  f"U*^(1/3) = {u_star ** (1 / 3):6.1f} m/s, A_d A_p/m_p = "
                  f"{rows[-1]['x']:.4f}, V50/U*^(1/3) = {rows[-1]['y']:.3f}", flush=True)

    import numpy as np

    # does one curve hold them? a power law y = c x^k by least squares in log-log, and each
    # point's residual from it
    k, logc = np.polyfit(np.log([r["x"] for r in rows]), np.log([r["y"] for r in rows]), 1)
    power = {"c": float(math.exp(logc)), "k": float(k),
             "residuals": [r["y"] / (math.exp(logc) * r["x"] ** k) - 1.0 for r in rows]}
    print(f"power law through the six: V_BL/U*^(1/3) = {power['c']:.3g} (A_d A_p/m_p)^"
          f"{power['k']:.2f}; residuals "
          f"{', '.join(f'{100 * e:+.0f} %' for e in power['residuals'])} (rms "
          f"{100 * math.sqrt(statistics.mean(e * e for e in power['residuals'])):.1f} %)")
    for r in rows:
        lj = r["lambert_jonas"]
        print(f"{r['case']:>24}: Lambert–Jonas a = {lj['a']:.2f}, p = {lj['p']:.2f}, rms "
              f"residual {lj['rms_residual']:.1f} m/s")

    # the spread that strength scatter gives: V_BL of the same ply for several draws of the
    # yarns' strengths (fabric.material.seed), Weibull modulus 5 against none (the modulus
    # scatter, cv 0.1, is drawn from the same seed in both)
    spread = {}
    for m in (0.0, 5.0):
        limits = []
        for seed in range(a.seeds):
            sets = [*base, f"fabric.style={STYLES[1]}", f"fabric.material.seed={seed}"]
            if m:
                sets.append(f"fabric.damage.weibull_shape={m}")
            name = (f"{STYLES[1]}-x1" if seed == 0 and not m else
                    f"{STYLES[1]}-m{m:g}-seed{seed}")
            limits.append(run_limit(a.out, name, sets, a.workers, a.tolerance)["v_bl"])
        spread[m] = {"v_bl": limits, "mean": statistics.mean(limits),
                     "stdev": statistics.stdev(limits) if len(limits) > 1 else 0.0}
        print(f"Kevlar 29, weibull_shape = {m:g}: V_BL over {a.seeds} strength draws = "
              f"{', '.join(f'{v:.1f}' for v in limits)} m/s: mean {spread[m]['mean']:.1f}, "
              f"standard deviation {spread[m]['stdev']:.1f} m/s", flush=True)
    (a.out / "material_study.json").write_text(json.dumps(
        {"cunniff": rows, "power_law": power,
         "v50_spread": {str(m): v for m, v in spread.items()}}, indent=2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 4.2), constrained_layout=True)
    for style, marker in zip(STYLES, "os^", strict=True):
        pts = [(r["x"], r["y"]) for r in rows if r["style"] == style]
        ax.plot(*zip(*pts, strict=True), marker=marker, ls="", ms=8,
                label=f"{fabric_style(style).material} ({style})")
    xs = np.geomspace(min(r["x"] for r in rows), max(r["x"] for r in rows), 50)
    ax.plot(xs, power["c"] * xs ** power["k"], "k--", lw=0.8,
            label=f"{power['c']:.3g} $x^{{{power['k']:.2f}}}$ (least squares, log–log)")
    ax.set_xlabel(r"$A_d A_p / m_p$ [-]")
    ax.set_ylabel(r"$V_{50} / U^{*1/3}$ [-]")
    ax.set_xscale("log")
    ax.set_title("Single plies vs a .22 FSP, Cunniff's dimensionless form")
    ax.legend(fontsize=8)
    fig.savefig(a.out / "cunniff.png", dpi=130)

    from emfabric.studies.ballistic import lambert_jonas

    fig, ax = plt.subplots(figsize=(6.0, 4.2), constrained_layout=True)
    for style, colour in zip(STYLES, ("C0", "C1", "C2"), strict=True):
        r = next(r for r in rows if r["case"] == f"{style}-x1")
        got = [s for s in shots(a.out / r["case"]) if s["perforated"] in (0, 1)]
        vs = np.array([s["speed"] for s in got])
        vr = np.array([s["residual_speed"] if s["perforated"] == 1 else 0.0 for s in got])
        ax.plot(vs, vr, "o", color=colour, label=f"{r['material']}: shots")
        lj = r["lambert_jonas"]
        grid = np.linspace(lj["v_bl"], vs.max(), 100)
        ax.plot(grid, lambert_jonas(grid, lj["a"], lj["p"], lj["v_bl"]), "-", color=colour,
                label=f"Lambert–Jonas a = {lj['a']:.2f}, p = {lj['p']:.2f}")
    ax.set_xlabel("striking speed [m/s]")
    ax.set_ylabel("residual speed [m/s] (0: stopped)")
    ax.set_title("Residual speed of a .22 FSP through one ply")
    ax.legend(fontsize=7)
    fig.savefig(a.out / "residual.png", dpi=130)
    print(f"wrote {a.out / 'material_study.json'}, cunniff.png and residual.png")


if __name__ == "__main__":
    main()
