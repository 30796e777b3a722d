"""The ballistic limit of packs of plies (issue 23): V_BL against the number of plies, 0/90
against ±45 stacking, the field on and off, each measured with `emfabric ballistic-limit`.

    python scripts/ply_study.py [--out runs/ply-study] [--nodes 20] [--plies 1 2 4 8]
                                [--angled 2 4] [--workers 1]

Every point is `emfabric ballistic-limit rupture --set fabric.plies=K ...` (the rupture
scenario: the paper's sphere into the paper's Zylon sheet with yarns that break near 3–4 %
stretch) at --nodes × --nodes per ply run as the 100 × 100 fabric, with and without the paper's
field B = 0.05 e_x T; ±45 packs alternate +45° and −45° (`fabric.ply_angles`), 0/90 packs
alternate 0° and 90° (on the square grid, the aligned pack). A case already in --out (its
ballistic.json) is reused. Writes ply_study.json and ply_study.png in --out and prints the table
that docs/packs.md quotes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path


def case_name(plies: int, stacking: str, field: bool) -> str:
    return f"p{plies}-{stacking}-{'field' if field else 'nofield'}"


def run_case(out: Path, nodes: int, plies: int, stacking: str, field: bool,
             workers: int) -> dict:
    folder = out / case_name(plies, stacking, field)
    done = folder / "ballistic.json"
    if done.exists():
        return json.loads(done.read_text())
    angles = ([45.0 if p % 2 == 0 else -45.0 for p in range(plies)] if stacking == "pm45"
              else [0.0 if p % 2 == 0 else 90.0 for p in range(plies)])
    sets = [f"fabric.nodes=[{nodes},{nodes}]", f"fabric.plies={plies}",
            f"fabric.ply_angles={json.dumps(angles)}",
            f"field.B={'[0.05,0,0]' if field else '[0,0,0]'}"]
    cmd = [sys.executable, "-m", "emfabric", "ballistic-limit", "rupture", "--out", str(folder),
           "--workers", str(workers), "--json"]
    for s in sets:
        cmd += ["--set", s]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    data = json.loads(res.stdout)
    data["wall_s"] = time.perf_counter() - t0
    done.write_text(json.dumps(data, indent=2))
    return data


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/ply-study"))
    p.add_argument("--nodes", type=int, default=20)
    p.add_argument("--plies", type=int, nargs="+", default=[1, 2, 4, 8])
    p.add_argument("--angled", type=int, nargs="*", default=[2, 4],
                   help="pack sizes also run as ±45 (none: skip)")
    p.add_argument("--workers", type=int, default=1)
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    cases = [(k, "0-90", f) for k in a.plies for f in (False, True)]
    cases += [(k, "pm45", f) for k in a.angled for f in (False, True)]
    rows = []
    for plies, stacking, field in cases:
        r = run_case(a.out, a.nodes, plies, stacking, field, a.workers)
        rows.append({"plies": plies, "stacking": stacking, "field": field,
                     "v_bl": r["v_bl"], "wall_s": r.get("wall_s")})
        print(f"{plies:>3} plies {stacking:>5} field {'on ' if field else 'off'}: "
              f"V_BL = {r['v_bl']:.1f} m/s", flush=True)
    (a.out / "ply_study.json").write_text(json.dumps(rows, indent=2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 4.0), constrained_layout=True)
    for stacking, marker in (("0-90", "o"), ("pm45", "s")):
        for field, style in ((False, "-"), (True, "--")):
            pts = sorted((r["plies"], r["v_bl"]) for r in rows
                         if r["stacking"] == stacking and r["field"] == field)
            if not pts:
                continue
            ks, vs = zip(*pts, strict=True)
            label = (f"{'0/90' if stacking == '0-90' else '±45'}, "
                     f"{'B = 0.05 T' if field else 'no field'}")
            ax.plot(ks, vs, style, marker=marker, label=label)
    ax.set_xlabel("plies")
    ax.set_ylabel("ballistic limit V_BL [m/s]")
    ax.set_xscale("log", base=2)
    ax.set_xticks(sorted({r["plies"] for r in rows}))
    ax.get_xaxis().set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_title(f"Paper's sphere into packs of the rupture sheet ({a.nodes} × {a.nodes} per ply)")
    ax.legend()
    fig.savefig(a.out / "ply_study.png", dpi=130)
    print(f"wrote {a.out / 'ply_study.json'} and {a.out / 'ply_study.png'}")


if __name__ == "__main__":
    main()
