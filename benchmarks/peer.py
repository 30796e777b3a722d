"""emfabric against VibeDynaLITE on the struck sheet of `paper-no-field`: one table.

VibeDynaLITE (github.com/bennames/VibeDynaLITE, MIT, Python package ``kevlargrid``) is the other
open-source Numba fabric-impact code: a lumped-mass spring grid (yarn springs plus diagonal
shear springs), explicit leapfrog (velocity Verlet) with a CFL step, penalty contact with a
signed-distance body, progressive damage, stacked plies. This script

1. sets up in it the sheet of emfabric's built-in scenario ``paper-no-field`` as closely as its
   inputs allow (100 × 100 nodes, 0.254 m square, clamped edges, the Zylon-like yarns, the steel
   sphere at 250 m/s) and runs it, in its own virtual environment, through
   ``benchmarks/peer_driver.py`` (a subprocess: ``--peer-python benchmarks/peer_driver.py``);
2. runs emfabric on the same problem with ``solver.integrator = "central-difference"`` and
   ``"phi"`` through the Python API, to the same end time;
3. prints, for each, the number of steps, the step size, the wall time of a warm run (a first run
   compiles, or loads Numba's cache, and is not timed) and the simulated microseconds per wall
   second; then the list of what still differs between the two set-ups.

Both run on the same number of Numba threads (``--threads``, default 1, exported as
NUMBA_NUM_THREADS to both processes and passed to both codes explicitly). Run it on an otherwise
idle machine; the load average is printed with the table.

Setup of the peer (once; nothing of it goes into emfabric's environment)::

    git clone https://github.com/bennames/VibeDynaLITE /work/peer/VibeDynaLITE
    python3 -m venv /work/peer/venv            # Python 3.11+, the peer's requirement
    /work/peer/venv/bin/pip install numba==0.68.1 numpy==2.4.6 scipy==1.17.1 \
        -e /work/peer/VibeDynaLITE              # numba as emfabric's lock file; scipy: the
                                                # peer's np.linalg.norm in Numba needs it

then, with emfabric's environment active::

    python benchmarks/peer.py                  # 30 s warm; some minutes more the first time
                                               # (both codes' Numba kernels compile)
    python benchmarks/peer.py --threads 2 --repeat 3
    python benchmarks/peer.py --peer-dir DIR --peer-python DIR/../venv/bin/python

Options: ``--after-contact`` (simulated time after the first contact, default 50e-6 s),
``--schemes`` (emfabric's integrators), ``--repeat`` (timed runs, best reported), ``--json FILE``
(all figures), ``--no-peer`` / ``--no-emfabric``, ``--plies K`` (below). benchmarks/PEER.md has
the measured figures.

``--plies K`` (default 1: the single sheet above) runs a pack of K identical touching plies in
both codes: emfabric with ``fabric.plies = K`` (default spacing: touching, the sum of the yarn
radii, 2 × 0.185 mm; ply 1 at z = 0, the others below; its ply-to-ply contact) and central
differences only (its φ-scheme refuses packs: ``--schemes phi`` is refused with K > 1); the peer
in its stacked mode (``generate_rectangular_grid(n_plies=K, t_ply=...)``: K full sheets t_ply
apart along +z, the sphere the same gap above the top one, every layer clamped). The peer's
t_ply is the layers' mid-plane spacing and at the same time the distance below which its
inter-ply penalty pushes a node and the node of the same index in the next layer apart (the
same k_pen as the body's): the touching spacing, the same as emfabric's. E.g.::

    python benchmarks/peer.py --plies 4 --repeat 3
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENARIO = "paper-no-field"
PEER_DIR = "/work/peer/VibeDynaLITE"
PEER_PYTHON = "/work/peer/venv/bin/python"
COURANT = 0.25
"""emfabric's default solver.courant (config/scenario.py SolverSpec)."""
PEER_CFL = COURANT * math.sqrt(2.0)
"""The peer's Δt = cfl · min sqrt(m/Σk); emfabric's central differences take courant ×
2/ω_max with ω_max² ≤ 2Σk/m, i.e. courant·√2·sqrt(m/Σk): the same fraction of the same
bound. (The peer's GUI default is cfl = 0.8; --peer-cfl changes it.)"""


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer-dir", default=PEER_DIR, help=f"VibeDynaLITE checkout ({PEER_DIR})")
    ap.add_argument("--peer-python", default=PEER_PYTHON,
                    help=f"Python of the peer's own venv ({PEER_PYTHON})")
    ap.add_argument("--threads", type=int, default=1,
                    help="Numba threads for both codes (NUMBA_NUM_THREADS; default 1)")
    ap.add_argument("--after-contact", type=float, default=50e-6,
                    help="simulated time after the first contact [s] (default 50e-6)")
    ap.add_argument("--schemes", nargs="+", default=None, choices=["central-difference", "phi"],
                    help="emfabric's integrators (default: both; central-difference only with "
                         "--plies > 1)")
    ap.add_argument("--plies", type=int, default=1,
                    help="plies in the pack, touching, in both codes (default 1: one sheet)")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs after the warm-up (best)")
    ap.add_argument("--peer-cfl", type=float, default=PEER_CFL,
                    help="the peer's CFL factor (default 0.25·√2, emfabric's rule; its GUI: 0.8)")
    ap.add_argument("--peer-k-penalty", type=float, default=None,
                    help="the peer's contact penalty [N/m] (default: its worker's rule, 10 × "
                         "the mean spring stiffness)")
    ap.add_argument("--peer-chunk", type=int, default=100,
                    help="steps per call of the peer's fused loop (its worker: 100)")
    ap.add_argument("--peer-save-interval", type=int, default=10,
                    help="steps between the peer's history frames (its worker: 10)")
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument("--no-emfabric", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="write every figure here")
    args = ap.parse_args(argv)
    if not 1 <= args.plies <= 64:
        ap.error(f"--plies {args.plies}: allowed 1 … 64 (emfabric's fabric.plies range)")
    if args.schemes is None:
        args.schemes = ["central-difference", "phi"] if args.plies == 1 else ["central-difference"]
    elif args.plies > 1 and "phi" in args.schemes:
        ap.error(f"--schemes phi with --plies {args.plies}: emfabric runs packs of plies with "
                 "central differences only (its φ-scheme refuses fabric.plies > 1); allowed: "
                 "--schemes central-difference, or --plies 1")
    if args.peer_chunk % args.peer_save_interval:
        ap.error("--peer-chunk must be a multiple of --peer-save-interval (the peer writes its "
                 "history past the end of its arrays otherwise)")
    return args


# --- the problem -----------------------------------------------------------------------------

def problem(sc, args) -> dict:
    """The paper-no-field sheet in the peer's inputs, and the common end time."""
    f, p = sc.fabric, sc.projectile
    nx, ny = f.nodes
    if nx != ny or f.size[0] != f.size[1]:
        raise SystemExit("the peer has one spacing: a square sheet with nx = ny is needed")
    h = f.size[0] / (nx - 1)
    node_mass = f.areal_density * f.size[0] * f.size[1] / (nx * ny)  # emfabric: total / nodes
    area = math.pi * f.yarn_radius ** 2  # rescale is a no-op on the reference 100 × 100 grid
    k_yarn = f.material.youngs_modulus * area / h  # small-strain stiffness of a segment [N/m]
    areal = node_mass / h ** 2  # the peer lumps ρ_A·h² on an interior node: the same mass
    thickness = k_yarn / f.material.youngs_modulus  # the peer's k = E·t, t = ρ_A/ρ_fibre
    plies = args.plies
    # emfabric's default ply spacing: touching, r + r for identical plies (sim/builder.ply_z);
    # the peer gets it with its mantissa cut to 40 bits (a relative change below 1e-12) so that
    # its ply·t_ply heights and their differences are exact: with t_ply = 0.37 mm as it is,
    # plies 3 and 4 start 1e-19 m "inside" each other by rounding, and its step rule adds
    # k_pen to every node of both (clamped corners too) from the start
    spacing = f.ply_spacing if f.ply_spacing is not None else 2.0 * f.yarn_radius
    mant, expo = math.frexp(spacing)
    t_ply = math.ldexp(round(mant * 2.0 ** 40) / 2.0 ** 40, expo)
    speed = -p.velocity[2]
    if p.shape != "sphere" or p.velocity[0] or p.velocity[1] or speed <= 0 or p.position:
        raise SystemExit("the peer set-up is written for a sphere falling along −z")
    u_crit, rate = f.damage.critical_stretch, f.damage.rate
    # the body's lowest point is `gap` above the flat sheet in both; an even grid has no node
    # under the axis, so the first contact is at the nodes nearest to it, r = h/√2 away
    r_near = math.hypot(*((0.0 if n % 2 else h / 2) for n in (nx, ny)))
    t_contact = (p.gap + p.radius - math.sqrt(p.radius ** 2 - r_near ** 2)) / speed
    return {
        "nodes": nx, "size": f.size[0], "tensile_modulus_gpa": f.material.youngs_modulus / 1e9,
        "areal_density_kgm2": areal, "fiber_density_gcc": areal / thickness / 1000.0,
        "shear_ratio": 0.0,
        # the peer's linear softening D = (ε − ε_on)/(ε_f − ε_on) with ε_on = U_crit − 1 and the
        # slope of Zohdi's α = exp(−λ(U − U_crit)/U_crit) at the onset: ε_f = ε_on + U_crit/λ
        "damage_onset_strain": u_crit - 1.0,
        "failure_strain": (u_crit - 1.0) + (u_crit / rate if rate > 0 else 1e6),
        "k_penalty": args.peer_k_penalty, "cfl_factor": args.peer_cfl,
        "mu_s": sc.contact.dynamic_friction, "rayleigh_beta": 0.0,
        "radius": p.radius, "mass": p.mass, "speed": speed, "gap": p.gap,
        "end_time": t_contact + args.after_contact, "t_contact_nominal": t_contact,
        "chunk": args.peer_chunk, "save_interval": args.peer_save_interval,
        "threads": args.threads, "repeat": args.repeat,
        "plies": plies, "t_ply": t_ply if plies > 1 else None,
        # for the report only
        "ply_spacing_emfabric": spacing if plies > 1 else None,
        "h": h, "node_mass": node_mass, "k_yarn": k_yarn,
    }


# --- the two codes ---------------------------------------------------------------------------

def run_peer(args, cfg: dict) -> dict:
    """The peer's figures, from peer_driver.py in the peer's own interpreter."""
    python, peer_dir = Path(args.peer_python), Path(args.peer_dir)
    if not python.exists() or not (peer_dir / "src" / "kevlargrid").is_dir():
        raise SystemExit(f"no peer at {peer_dir} / {python}: see the set-up in this docstring")
    env = dict(os.environ, NUMBA_NUM_THREADS=str(args.threads))
    env.pop("PYTHONPATH", None)
    t0 = time.perf_counter()
    out = subprocess.run([str(python), str(HERE / "peer_driver.py"), "--peer-dir", str(peer_dir),
                          "--config", json.dumps(cfg)], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"the peer's driver failed ({out.returncode}): {tail[:400]}")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["process_wall_s"] = time.perf_counter() - t0
    return res


def source_of(module) -> str:
    """Where the module was imported from, and its git commit (+ '-dirty': uncommitted edits)."""
    where = Path(module.__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "-C", str(where), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        rev = ""
    return f"{where} ({rev or 'not a git checkout'})"


def run_emfabric(scheme: str, end_time: float, args) -> dict:
    """emfabric's figures for one integrator: a warm-up run, then args.repeat timed runs."""
    import numba
    import numpy as np

    import emfabric

    over = {"solver.end_time": end_time, "solver.integrator": scheme}
    if args.plies > 1:
        over["fabric.plies"] = args.plies  # default spacing: touching
    sc = emfabric.load_scenario(SCENARIO, over)
    t0 = time.perf_counter()
    first = emfabric.run(sc, threads=args.threads)
    first_wall = time.perf_counter() - t0
    best = None
    walls = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        res = emfabric.run(sc, threads=args.threads)
        call = time.perf_counter() - t0
        walls.append(res.wall_time)
        if best is None or res.wall_time < best[0].wall_time:
            best = (res, call)
    res, call = best
    h, s = res.history, res.summary
    dt = np.asarray(h["dt"].values[1:-1])  # not the last: cut to end exactly at end_time
    contact = np.asarray(h["contact_nodes"].values)
    times = np.asarray(h["time"].values)
    hit = np.nonzero(contact > 0)[0]
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel region ran (the serial kernels)
        layer = "none used (serial kernels)"
    return {
        "wall_s": res.wall_time, "call_wall_s": call, "first_run_wall_s": first_wall,
        "timed_walls_s": walls, "status": res.status, "end_reason": res.end_reason,
        "steps": int(s["steps"]), "rejected_steps": int(s.get("rejected_steps", 0)),
        "force_evaluations": int(s.get("force_evaluations", s["steps"])),
        "t_end": float(s["time_s"]), "dt_mean": float(s["time_s"]) / int(s["steps"]),
        "dt_min": float(dt.min()), "dt_max": float(dt.max()),
        "first_contact_between": ([float(times[hit[0] - 1]), float(times[hit[0]])]
                                  if len(hit) else None),
        "projectile_vz": float(s["final_velocity_m_s"][2]),
        "max_deflection": float(s["max_deflection_m"]),
        "max_deflection_per_ply": ([float(x) for x in h["max_deflection_per_ply"].values[-1]]
                                   if "max_deflection_per_ply" in h else None),
        "max_strain_yarn": float(s["max_stretch"]) - 1.0,
        "broken_yarns": int(s["broken_yarns"]),
        "numba_num_threads": numba.config.NUMBA_NUM_THREADS,
        "numba_threads_used": numba.get_num_threads(), "threading_layer": layer,
        "numba_version": numba.__version__, "emfabric_version": emfabric.__version__,
        "plies": int(s.get("plies", sc.fabric.plies)),
        "plies_perforated": int(s.get("plies_perforated", 0)),
        "first_status": first.status, "emfabric_source": source_of(emfabric),
    }


# --- the report ------------------------------------------------------------------------------

def mismatches(cfg: dict, peer: dict | None, emf: dict, threads: int) -> list[tuple[str, str, str]]:
    """(aspect, emfabric, VibeDynaLITE as run here) for everything the two set-ups differ in."""
    k = cfg["k_yarn"]
    kp = peer["k_penalty"] if peer else float("nan")
    m = cfg["node_mass"]
    gersh = math.sqrt(m / (4 * k))  # sqrt(m/Σk) of a free node at rest, Σk = 4 yarns
    cd = emf.get("central-difference")
    plies = cfg.get("plies", 1)
    rows = [
        ("time integration",
         "central differences (one force evaluation a step) or the implicit φ-scheme "
         "(φ = 0.5, fixed-point iteration, adaptive Δt of eq. 3.9)",
         "velocity Verlet (leapfrog, one force evaluation a step)"),
        ("step-size rule",
         f"CD: {COURANT:g} × 2/ω_max, ω_max² ≤ max 2Σk_t/m over free nodes with the tangent "
         f"stiffness at the current stretch, also ≤ the no-tunnelling limit and dt_max; at rest "
         f"{COURANT * math.sqrt(2) * gersh * 1e9:.0f} ns. φ: eq. 3.9 controller (6 iterations)",
         f"cfl {cfg['cfl_factor']:.4f} × min over ALL nodes (clamped ones too) of sqrt(m/Σk), "
         f"Σk = linear spring k + the penalty k of nodes within 2h of the body "
         f"(before contact too)"
         + (" + k_pen for each neighbouring layer closer than t_ply (2 k_pen between two "
            "compressed layers)" if plies > 1 else "")
         + f": {(peer['dt_mean'] if peer else cfl_dt(cfg, kp)) * 1e9:.0f} ns"
         + (" mean" if plies > 1 else "")),
        ("contact law",
         "kinematic: a node inside the sphere is put on its surface and takes the surface "
         "velocity (impulse), no penetration; nodes only (segments off for the sphere)",
         f"penalty k_pen = 10 × mean spring k = {kp:.3g} N/m ({kp / k:.2f} k_yarn: the inert "
         "diagonals count as 0), sphere signed distance with a finite-difference normal, force "
         "scaled by the node's surviving-spring fraction"),
        ("friction",
         "Coulomb stick/slip, μ_s = 1.0, μ_d = 0.95",
         f"regularised Coulomb sliding μ·N·v_t/sqrt(v_t² + (0.01 m/s)²), μ = {cfg['mu_s']}, "
         "no stick state"),
        ("yarn law",
         f"Kirchhoff–Saint-Venant, F = U·𝔼(U²−1)/2·A0, tension only; tangent at U = 1 "
         f"{k:.4g} N/m (stiffens ≈ 1.5ε relative)",
         f"linear spring F = k(L − L0), tension only, k = E·ρ_A/ρ_f = {k:.4g} N/m "
         f"(ρ_f = {cfg['fiber_density_gcc']:.3f} g/cm³ chosen for it)"),
        ("modulus scatter",
         "per-yarn 𝔼 with cv 0.10 (seed 0" + ("; ply p from the sequence (seed, p): no two "
                                               "plies alike" if plies > 1 else "") + ")",
         "uniform"),
        ("damage",
         "Zohdi eq. 2.6: α = min(α_prev, exp(−λ(U−U_c)/U_c)), λ = 0.1, U_c = 1.03; never "
         "fully broken",
         f"linear softening from ε = {cfg['damage_onset_strain']:.3f} to failure at "
         f"{cfg['failure_strain']:.2f} (Zohdi's slope at the onset); failure-strain size "
         "regularisation inactive (h > 1 mm)"),
        ("network", f"{plies * 19800:,} yarn segments".replace(",", " ")
         + (f" ({plies} plies × 19 800)" if plies > 1 else ""),
         f"{peer['springs'] if peer else plies * 39402} springs: + 2 diagonal shear springs a "
         "cell, inert at shear_ratio 0 but looped over every step"),
        ("mass lumping",
         f"every node ρ_A·L²/(nx·ny) = {m:.4g} kg",
         f"tributary ρ_A'·h² with ρ_A' = {cfg['areal_density_kgm2']:.5f} kg/m² (so the free "
         "nodes match); edge ½, corner ¼ (they are clamped, but enter its CFL minimum)"),
        ("edges", "four edges clamped (never move)" + (", every ply" if plies > 1 else ""),
         "four edges clamped (force zeroed)" + (", every layer" if plies > 1 else "")),
        ("damping", "none", "none (its default Rayleigh β = 1e-9 s set to 0); velocity cap "
         "h/Δt, never reached here"),
        ("projectile",
         "rigid sphere, rotation by eqs. B2–B16 (iterated)",
         "rigid sphere, explicit quaternion update; the contact search covers every node "
         "within its default 'span' 0.05 m + 2h of the centre (serial loop)"),
        ("field, charges", "E = B = 0 (q = 1 C a node is inert)", "none"),
        ("threads",
         f"NUMBA_NUM_THREADS = {threads}, emfabric.run(threads={threads}) (its own default "
         f"on 100 × 100 is 1); {'serial kernel' if threads == 1 else 'row-block threaded kernel'}"
         f"; threading layer: {cd['threading_layer'] if cd else 'n/a'}",
         f"NUMBA_NUM_THREADS = {threads}, numba.set_num_threads({threads}); parallel=True "
         f"(prange) kernels at any count; threading layer "
         f"{peer['threading_layer'] if peer else 'n/a'}"),
        ("recording",
         "a history row every accepted step, in memory (no files)",
         f"all node positions + energies every {cfg['save_interval']} steps, "
         f"{cfg['chunk']}-step chunks as its worker (no files, no GUI queue)"),
        ("floating point", "no fastmath", "fastmath=True everywhere"),
    ]
    if plies > 1:
        sp, tp = cfg["ply_spacing_emfabric"], cfg["t_ply"]
        overlaps = peer.get("rest_overlaps", 0) if peer else 0
        rows += [
            ("plies, stacking",
             f"{plies} plies of the sheet, ply 1 at z = 0, the others below, {sp * 1e3:.3f} mm "
             "apart (default: touching, r + r = the contact distance)",
             f"{plies} layers of the sheet ('Mode B': n_plies = {plies}, t_ply = {tp * 1e3:.3f} "
             f"mm, cut to 40 mantissa bits, {abs(tp - sp):.1e} m off), layer 0 at z = 0, the "
             f"others above, the sphere {cfg['gap'] * 1e3:g} mm above the top one; t_ply is "
             f"the spacing and the contact distance at once (rest overlaps from rounding: "
             f"{overlaps})"),
            ("ply-to-ply contact",
             "every node against the neighbouring ply's surface (its nearest lattice patch, "
             "normal from the deformed ply), both ways, with the projectile's stick/slip "
             "impulse law (μ_s 1.0, μ_d 0.95), inelastic in the normal, the node placed at the "
             "contact distance; integer-summed (momentum-exact); no stiffness in the step rule",
             f"penalty with the body's k_pen ({kp:.3g} N/m) between node i of a layer and node "
             f"i of the next only (same index: no contact with the neighbour's surface between "
             f"nodes, so a layer sliding sideways loses its partner), along z only: "
             f"F = k_pen (t_ply − |Δz|) pushing by the sign of Δz, elastic (no damping: "
             f"layers can rebound apart); regularised Coulomb sliding "
             f"μ = {cfg['mu_s']} in x, y, no stick state; only where both nodes keep a spring"),
            ("projectile and plies",
             "the projectile meets every ply (a broken one lets it through to the next)",
             "the sphere's penalty acts on any node of any layer inside it"),
        ]
    return rows


def cfl_dt(cfg: dict, k_pen: float) -> float:
    """The peer's Δt on this sheet: a contact node of the interior limits it."""
    m, k = cfg["node_mass"], cfg["k_yarn"]
    return cfg["cfl_factor"] * min(math.sqrt(m / (4 * k + k_pen)), math.sqrt(m / 4 / (2 * k)),
                                   math.sqrt(m / 2 / (3 * k)))


def pack_words(cfg: dict) -> str:
    """'100 × 100 sheet, 1 ply' or '3 plies of 100 × 100, touching (0.370 mm apart)'."""
    n = cfg["nodes"]
    if cfg.get("plies", 1) == 1:
        return f"{n} × {n} sheet, 1 ply"
    return (f"{cfg['plies']} plies of {n} × {n}, touching ({cfg['ply_spacing_emfabric'] * 1e3:.3f} "
            "mm apart)")


def load_line() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        la = os.getloadavg()
        return f"load average: {la[0]:.2f}, {la[1]:.2f}, {la[2]:.2f}"


def table(rows: list[dict]) -> str:
    head = ["code", "threads", "steps", "evals", "Δt mean ns", "Δt min–max ns", "t_end µs",
            "wall s", "sim µs / wall s", "µs wall / step", "1st run s", "v_z end m/s",
            "defl. mm", "max ε %"]
    lines = [head]
    for r in rows:
        lines.append([
            r["label"], str(r["numba_threads_used"]), str(r["steps"]),
            str(r.get("force_evaluations", r["steps"])), f"{r['dt_mean'] * 1e9:.1f}",
            f"{r['dt_lo'] * 1e9:.1f}–{r['dt_hi'] * 1e9:.1f}", f"{r['t_end'] * 1e6:.2f}",
            f"{r['wall_s']:.3f}", f"{r['t_end'] * 1e6 / r['wall_s']:.1f}",
            f"{r['wall_s'] / r['steps'] * 1e6:.0f}", f"{r['first_run_wall_s']:.1f}",
            f"{r['projectile_vz']:.2f}", f"{r['max_deflection'] * 1e3:.2f}",
            f"{r['max_strain_yarn'] * 100:.2f}"])
    widths = [max(len(x[i]) for x in lines) for i in range(len(head))]
    out = ["  ".join(c.rjust(w) if i else c.ljust(w)
                     for i, (c, w) in enumerate(zip(x, widths, strict=True))) for x in lines]
    out.insert(1, "-" * len(out[0]))
    return "\n".join(out)


def main(argv=None) -> None:
    args = parse_args(argv)
    # before numba is imported anywhere in this process
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)
    import emfabric

    sc = emfabric.load_scenario(SCENARIO)
    cfg = problem(sc, args)
    end = cfg["end_time"]
    print(f"{SCENARIO}: {pack_words(cfg)}, end time {end * 1e6:.2f} µs (first contact at "
          f"{cfg['t_contact_nominal'] * 1e6:.2f} µs + {args.after_contact * 1e6:g} µs), "
          f"{args.threads} thread(s)", flush=True)
    before_line = load_line()
    print(f"before: {before_line}", flush=True)
    peer = None
    if not args.no_peer:
        peer = run_peer(args, cfg)
        print(f"  peer done: {peer['wall_s']:.3f} s warm", flush=True)
    emf: dict[str, dict] = {}
    if not args.no_emfabric:
        for scheme in args.schemes:
            emf[scheme] = run_emfabric(scheme, end, args)
            print(f"  emfabric {scheme} done: {emf[scheme]['wall_s']:.3f} s warm", flush=True)
    after = load_line()
    before = before_line
    rows = []
    if peer:
        rows.append(dict(peer, label="VibeDynaLITE (leapfrog)", dt_lo=peer["dt_min_chunk"],
                         dt_hi=peer["dt_max_chunk"]))
    for scheme, r in emf.items():
        rows.append(dict(r, label=f"emfabric {scheme}", dt_lo=r["dt_min"], dt_hi=r["dt_max"]))
    print()
    print(f"{SCENARIO}, {pack_words(cfg)}, {args.threads} thread(s), t_end "
          f"{end * 1e6:.2f} µs:")
    print(table(rows))
    print()
    print("wall s: the stepping loop of the best timed run (emfabric: RunResult.wall_time; the "
          "peer: its chunk loop); 1st run s: the untimed first run (compilation or cache load)")
    for r in rows:
        fc = r.get("first_contact_between")
        fc_s = f"{fc[0] * 1e6:.3f}–{fc[1] * 1e6:.3f} µs" if fc else "none"
        print(f"  {r['label']}: first contact {fc_s}; timed walls "
              f"{', '.join(f'{w:.3f}' for w in r['timed_walls_s'])} s; NUMBA_NUM_THREADS "
              f"{r['numba_num_threads']}, threads used {r['numba_threads_used']}, layer "
              f"{r['threading_layer']}, numba {r['numba_version']}"
              + (f"; deflection per ply from the top "
                 f"{' / '.join(f'{d * 1e3:.2f}' for d in r['max_deflection_per_ply'])} mm"
                 if args.plies > 1 and r.get("max_deflection_per_ply") else ""))
    if peer:
        print(f"  peer: k_yarn {peer['k_yarn']:.4g} N/m, k_penalty {peer['k_penalty']:.4g} N/m, "
              f"interior node mass {peer['node_mass_interior']:.4g} kg (emfabric "
              f"{cfg['node_mass']:.4g}), failed springs {peer['failed_springs']}"
              + (f"; {peer['plies']} layers, {peer['nodes_total']} nodes, t_ply "
                 f"{peer['t_ply']:.6g} m, rest overlaps {peer['rest_overlaps']}"
                 if peer.get("plies", 1) > 1 else ""))
    if emf:
        e0 = next(iter(emf.values()))
        print(f"  emfabric from {e0['emfabric_source']}"
              + (f"; {e0['plies']} plies, perforated {e0['plies_perforated']}"
                 if e0.get("plies", 1) > 1 else ""))
    print(f"after: {after}")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"Python {platform.python_version()}")
    print()
    print("What still differs (emfabric | VibeDynaLITE as run here):")
    for aspect, a, b in mismatches(cfg, peer, emf, args.threads):
        print(f"- {aspect}: {a} | {b}")
    if args.json:
        args.json.write_text(json.dumps({"config": cfg, "peer": peer, "emfabric": emf,
                                         "load": [before, after]}, indent=1))


if __name__ == "__main__":
    main()
