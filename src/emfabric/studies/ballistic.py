"""Ballistic limit: V_BL of the model by bisection on the striking speed, the Lambert–Jonas fit
of the residual speeds above it, and V50 with its spread from seeded shots
(``emfabric ballistic-limit``).

A shot perforates when its run ends by perforation (the projectile past every node, moving
away), or reaches `end_time` moving forward past the sheet's plane and clear of the fabric
(emfabric.runner.summary.perforated); a shot still in contact at end_time has not perforated
*within end_time*: V_BL is the lowest speed that perforates within the scenario's end_time
(the shipped ``rupture`` scenario runs 3 ms, long enough for a stopped sphere to rebound).

Lambert–Jonas: v_r = a (v_s^p − V_BL^p)^{1/p} for v_s > V_BL, 0 below (SciPy least squares).
V50: the logistic P(perforation | v) = 1 / (1 + exp(−(v − V50)/s)) fitted by maximum
likelihood to the seeded shots (each seed draws the yarn moduli and jitters the impact point
within one node spacing), with a bootstrap confidence interval over the shots.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from emfabric.config.scenario import Scenario

SPEEDS_ABOVE = (1.05, 1.1, 1.2, 1.35, 1.5, 1.75, 2.0)
"""Striking speeds above V_BL run for the Lambert–Jonas fit, as multiples of V_BL."""
SEED_SPEEDS = tuple(np.linspace(0.8, 1.2, 9))
"""Striking speeds of each seed's shots, as multiples of V_BL."""
SEED_WIDEN = 1.5
"""Where every seeded shot so far perforated (or every one was stopped), the seeds fire again
at the speeds of the last band divided (multiplied) by this factor: the next band of speeds,
adjoining the last (0.8 × 1.5 = 1.2)."""
SEED_WIDENINGS = 3
"""The most bands fired beyond the first (down to 0.24 × V_BL, up to 4.05 × V_BL)."""


def lambert_jonas(vs: np.ndarray, a: float, p: float, vbl: float) -> np.ndarray:
    """v_r = a (v_s^p − V_BL^p)^{1/p} above V_BL, 0 below."""
    vs = np.asarray(vs, dtype=float)
    inner = np.clip(vs**p - vbl**p, 0.0, None)
    return a * inner ** (1.0 / p)


def fit_lambert_jonas(vs, vr, vbl_guess: float) -> dict[str, float]:
    """Least-squares (a, p, V_BL) of the Lambert–Jonas curve through perforating shots
    (v_s, v_r): 0 < a ≤ 1 and p ≥ 1 (so that v_r ≤ v_s), V_BL below every v_s given."""
    from scipy.optimize import curve_fit

    vs = np.asarray(vs, dtype=float)
    vr = np.asarray(vr, dtype=float)
    if vs.size < 3:
        raise ValueError(f"the Lambert–Jonas fit needs 3 perforating shots, got {vs.size}")
    top = float(vs.min()) * (1 - 1e-9)
    guess = (0.9, 2.0, min(vbl_guess, 0.99 * top))  # inside the bounds
    params, _cov = curve_fit(lambert_jonas, vs, vr, p0=guess,
                             bounds=([1e-6, 1.0, 0.0], [1.0, 20.0, top]), maxfev=20000)
    a, p, vbl = (float(x) for x in params)
    rms = float(np.sqrt(np.mean((lambert_jonas(vs, a, p, vbl) - vr) ** 2)))
    return {"a": a, "p": p, "v_bl": vbl, "rms_residual": rms}


def fit_v50(speeds, perforated, bootstrap: int = 500, seed: int = 0) -> dict[str, float]:
    """Maximum-likelihood logistic fit of P(perforation | v): V50, the scale s (spread σ =
    sπ/√3) and a bootstrap 95 % interval of V50 (resampling the shots); "separated" False.

    Shots that separate completely (every stopped shot at most as fast as every perforating
    one) have no maximum-likelihood fit: the likelihood grows without bound as s → 0, for any
    V50 in the gap. Then V50 is the middle of the gap between the fastest stopped and the
    slowest perforating shot, the interval is the gap itself, s = σ = 0 (no spread resolved:
    it is smaller than the gap) and "separated" is True — not the arbitrary V50 and vanishing
    interval a minimiser stops at."""
    from scipy.optimize import minimize

    v = np.asarray(speeds, dtype=float)
    y = np.asarray(perforated, dtype=float)
    if not (0 < y.sum() < y.size):
        raise ValueError("V50 needs shots that perforate and shots that do not")
    stopped_max, perforated_min = float(v[y == 0].max()), float(v[y == 1].min())
    if stopped_max <= perforated_min:
        return {"v50": 0.5 * (stopped_max + perforated_min), "scale": 0.0, "sigma": 0.0,
                "ci95": [stopped_max, perforated_min], "shots": int(v.size), "separated": True}

    def nll(theta, v, y):
        v50, log_s = theta
        z = (v - v50) / math.exp(log_s)
        # log(1 + e^{-z}) and log(1 + e^{z}), stable
        return float(np.sum(y * np.logaddexp(0.0, -z) + (1 - y) * np.logaddexp(0.0, z)))

    def fit(v, y):
        start = (float(np.median(v)), math.log(max(float(np.std(v)), 1e-6 * float(v.mean()))))
        res = minimize(nll, start, args=(v, y), method="Nelder-Mead",
                       options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
        return float(res.x[0]), math.exp(float(res.x[1]))

    v50, s = fit(v, y)
    rng = np.random.default_rng(seed)
    boot = []
    for _ in range(bootstrap):
        idx = rng.integers(0, v.size, v.size)
        if 0 < y[idx].sum() < v.size:
            boot.append(fit(v[idx], y[idx])[0])
    lo, hi = (np.percentile(boot, [2.5, 97.5]) if boot else (math.nan, math.nan))
    return {"v50": v50, "scale": s, "sigma": s * math.pi / math.sqrt(3.0),
            "ci95": [float(lo), float(hi)], "shots": int(v.size), "separated": False}


def shot(scenario: Scenario, speed: float, seed: int | None = None,
         jitter: tuple[float, float] = (0.0, 0.0)) -> Scenario:
    """The scenario at the striking speed (along its velocity), with a modulus seed and the
    impact point moved by `jitter` in the sheet's plane."""
    from emfabric.sim.geometry import initial_pose

    v = np.asarray(scenario.projectile.velocity, dtype=float)
    over: dict[str, Any] = {"projectile.velocity": list(speed * v / np.linalg.norm(v))}
    if seed is not None:
        over["fabric.material.seed"] = int(seed)
    if jitter != (0.0, 0.0):
        x0 = initial_pose(scenario.projectile).position
        over["projectile.position"] = [float(x0[0] + jitter[0]), float(x0[1] + jitter[1]),
                                       float(x0[2])]
    return scenario.replace(**over)


def ballistic_limit(scenario: Scenario, out, *, seeds: int = 0, tolerance: float = 2.0,
                    workers: int | None = None, scheduler: str | None = None,
                    threads: int | None = None, max_rounds: int = 12,
                    progress=None) -> dict[str, Any]:
    """V_BL (bracket and bisect to `tolerance` m/s), the Lambert–Jonas fit above it, and with
    `seeds`, V50. Every shot is a stored case in out/cases (a rerun reuses them)."""
    from emfabric.studies.sweep import (
        Case,
        StudyError,
        case_key,
        connect,
        read_case,
        release,
        run_cases,
    )

    out = Path(out)
    v = np.asarray(scenario.projectile.velocity, dtype=float)
    v0 = float(np.linalg.norm(v))
    if scenario.projectile.shape == "none" or not v0 > 0.0:
        raise StudyError("the ballistic limit needs a projectile with a striking velocity")
    if not tolerance > 0.0:
        raise StudyError(f"--tolerance {tolerance}: allowed: a positive speed [m/s]")
    shots: list[dict[str, Any]] = []
    client = cluster = None
    interrupted = False
    per_case = 1

    def fire(scenarios: list[tuple[float, int | None, Scenario]]) -> list[dict[str, Any]]:
        nonlocal client, cluster, per_case
        cases = []
        for k, (_speed, _seed, sc) in enumerate(scenarios):
            text = sc.to_toml()
            cases.append(Case((k,), {}, sc, case_key(text), text))
        todo = [c for c in cases if read_case(out, c) is None]
        if todo:
            if client is None:
                client, cluster, per_case = connect(workers, scheduler, threads)
            run_cases(todo, out, client, per_case, False,
                      explicit=threads is not None)
        got = []
        for (speed, seed, _sc), case in zip(scenarios, cases, strict=True):
            rec = read_case(out, case) or {"status": "failed", "perforated": -1}
            perforated = int(rec.get("perforated", -1))
            if perforated == -1 and rec.get("status") in ("complete", "partial"):
                perforated = 0  # still in contact at end_time: not through within it
            row = {"speed": speed, "seed": seed, "perforated": perforated,
                   "residual_speed": float(rec.get("residual_speed", math.nan)),
                   "status": rec.get("status", "failed"), "key": case.key}
            got.append(row)
            if all(r["key"] != case.key for r in shots):
                shots.append(row)
        if progress is not None:
            progress(len(shots))
        return got

    width = 2 if workers is None else max(2, workers)
    try:
        # bracket: perforating and stopped shots of the deterministic model
        fire([(s, None, shot(scenario, s)) for s in
              (v0 * 2.0 ** (k - width // 2) for k in range(width))])
        lo = hi = None
        for _ in range(max_rounds):
            perf = sorted(r["speed"] for r in shots if r["seed"] is None and r["perforated"] == 1)
            held = sorted(r["speed"] for r in shots if r["seed"] is None and r["perforated"] == 0)
            if perf and any(h < perf[0] for h in held):
                hi = perf[0]
                lo = max(h for h in held if h < hi)
                break
            if perf:  # below every speed tried (undecided shots decide nothing)
                low = min(r["speed"] for r in shots if r["seed"] is None)
                new = [low / 2.0 ** (k + 1) for k in range(width)]
            elif held:
                new = [max(held) * 2.0 ** (k + 1) for k in range(width)]
            else:
                raise StudyError("no shot was decided (perforated or stopped): " + "; ".join(
                    f"{r['speed']:.4g} m/s {r['status']}" for r in shots)
                    + "; a longer solver.end_time lets a run end by perforation or rebound")
            fire([(s, None, shot(scenario, s)) for s in new])
        if hi is None:
            undecided = sum(1 for r in shots if r["perforated"] == -1)
            raise StudyError(f"no bracket of the ballistic limit between "
                             f"{min(r['speed'] for r in shots):.4g} and "
                             f"{max(r['speed'] for r in shots):.4g} m/s"
                             + (f" ({undecided} shots were still in contact at end_time or "
                                f"did not complete: a longer solver.end_time decides them)"
                                if undecided else ""))

        def narrow(lo: float, hi: float) -> tuple[float, float]:
            """k-section of the bracket to the tolerance, or until a round decides nothing
            (its shots failed or were still in contact at end_time)."""
            rounds = 0
            while hi - lo > tolerance and rounds < 4 * max_rounds:
                new = [lo + (hi - lo) * (i + 1) / (width + 1) for i in range(width)]
                before = (lo, hi)
                fire([(s, None, shot(scenario, s)) for s in new])
                lo, hi = bracket(lo, hi)
                rounds += 1
                if (lo, hi) == before:
                    break
            return lo, hi

        def bracket(lo: float, hi: float) -> tuple[float, float]:
            """The bracket every decided shot so far bounds: the slowest perforating one, and
            the fastest stopped one below it."""
            hi = min([hi] + [r["speed"] for r in shots if r["seed"] is None
                             and r["perforated"] == 1])
            lo = max([lo] + [r["speed"] for r in shots if r["seed"] is None
                             and r["perforated"] == 0 and r["speed"] < hi])
            return lo, hi

        lo, hi = narrow(lo, hi)
        v_bl = 0.5 * (lo + hi)
        fire([(f * v_bl, None, shot(scenario, f * v_bl)) for f in SPEEDS_ABOVE])
        # a bisection that stopped early (failed shots inside its bracket) left the bracket
        # wide enough for the shots above V_BL to fall inside it: what they decided narrows it,
        # and the k-section goes on from there
        if bracket(lo, hi) != (lo, hi):
            lo, hi = narrow(*bracket(lo, hi))
        v_bl = 0.5 * (lo + hi)
        pts = [(r["speed"], r["residual_speed"]) for r in shots
               if r["seed"] is None and r["perforated"] == 1 and r["speed"] >= hi
               and math.isfinite(r["residual_speed"])]
        lj = fit_lambert_jonas([p[0] for p in pts], [p[1] for p in pts], v_bl)
        result: dict[str, Any] = {"v_bl": v_bl, "v_bl_bracket": [lo, hi],
                                  "tolerance": tolerance, "lambert_jonas": lj}
        # a bisection stopped early (the shots inside the bracket decided nothing): those
        # shots, which unresolved_bracket reports; empty where the bracket is within tolerance
        result["unresolved"] = [] if hi - lo <= tolerance else [
            {"speed": r["speed"], "status": r["status"]} for r in
            sorted(shots, key=lambda r: r["speed"])
            if r["seed"] is None and r["perforated"] == -1 and lo < r["speed"] < hi]
        if seeds > 0:
            result["seeds"] = seeds
            try:
                rows, bands = seeded_shots(fire, scenario, v_bl, seeds)
            except StudyError as err:  # V_BL and its shots are still worth writing
                result["v50_error"] = str(err)
            else:
                result["v50"] = fit_v50([r["speed"] for r in rows],
                                        [r["perforated"] for r in rows])
                result["v50"]["bands"] = bands
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if client is not None:
            release(client, cluster, interrupted)
    result["shots"] = shots
    result["runs"] = len(shots)
    result["scenario"] = scenario.name
    # what the limit is of: the whole scenario the shots were varied from (its --set overrides
    # applied), and the package that fired them
    result["base_scenario"] = scenario.to_toml()
    from emfabric import __version__

    result["emfabric_version"] = __version__
    result["non_monotone"] = non_monotone(shots, result["v_bl"])
    return result


def seeded_shots(fire, scenario: Scenario, v_bl: float,
                 seeds: int) -> tuple[list[dict[str, Any]], int]:
    """The decided shots of seeds 1..`seeds` (each its modulus draw and its impact point moved
    by up to half a node spacing) at the speeds SEED_SPEEDS × V_BL, and the number of bands
    fired. Where every one of them perforated (or every one was stopped), the seeds fire again
    a band lower (higher) by SEED_WIDEN, up to SEED_WIDENINGS times, until both outcomes are
    in: a ballistic limit whose seeded spread is wider than ±20 % of the deterministic V_BL
    still gets its V50. `fire` runs a batch of (speed, seed, Scenario) and returns one row
    ({"speed", "perforated", ...}) per shot. Raises StudyError when no band brings both."""
    from emfabric.studies.sweep import StudyError

    spacing = _node_spacing(scenario)
    jitter = {}
    for sd in range(1, seeds + 1):
        rng = np.random.default_rng(sd)
        jitter[sd] = tuple(float(x) for x in rng.uniform(-0.5, 0.5, 2) * spacing)
    rows: list[dict[str, Any]] = []
    scale = 1.0
    factors = SEED_SPEEDS
    for band in range(1, SEED_WIDENINGS + 2):
        batch = [(f * scale * v_bl, sd, shot(scenario, f * scale * v_bl, sd, jitter[sd]))
                 for sd in range(1, seeds + 1) for f in factors]
        rows += [r for r in fire(batch) if r["perforated"] in (0, 1)]
        through = sum(r["perforated"] for r in rows)
        if 0 < through < len(rows):
            return rows, band
        if not rows:
            break
        # the next band adjoins this one: its speed at the shared end is not fired again
        if through == len(rows):
            scale, factors = scale / SEED_WIDEN, SEED_SPEEDS[:-1]
        else:
            scale, factors = scale * SEED_WIDEN, SEED_SPEEDS[1:]
    speeds = [r["speed"] for r in rows]
    what = ("no seeded shot was decided (perforated or stopped): a longer solver.end_time "
            "decides them" if not rows else
            f"every one of the {len(rows)} decided seeded shots from {min(speeds):.4g} to "
            f"{max(speeds):.4g} m/s {'perforated' if through else 'was stopped'}")
    raise StudyError(f"V50: {what}, the deterministic V_BL being {v_bl:.4g} m/s; "
                     "a V50 needs shots of both outcomes")


def unresolved_bracket(res: dict[str, Any]) -> str | None:
    """What to tell a user whose bisection stopped before its bracket was narrower than the
    tolerance, else None: the shots inside decided nothing (runs that diverged or failed, or
    were still in contact at end_time), so V_BL is known only to the bracket."""
    lo, hi = res["v_bl_bracket"]
    tolerance = res.get("tolerance", math.inf)
    if not hi - lo > tolerance:
        return None
    inside = res.get("unresolved") or []
    counts = Counter(r["status"] for r in inside)
    what = ", ".join(f"{n} {st}" for st, n in sorted(counts.items()))
    return (f"V_BL = {res['v_bl']:.4g} m/s is known only to its bracket {lo:.4g} – {hi:.4g} "
            f"m/s, wider than --tolerance {tolerance:g} m/s: "
            + (f"the {len(inside)} shots inside it decided nothing ({what}: "
               + ", ".join(f"{r['speed']:.4g}" for r in inside) + " m/s)"
               if inside else "the shots inside it decided nothing")
            + "; see each shot's run in the cases (a longer solver.end_time decides shots "
            "still in contact; a diverged one names its cause)")


def v_bl_outside_v50(res: dict[str, Any]) -> str | None:
    """What to tell a user whose deterministic V_BL lies outside the 95 % interval of the seeded
    V50 (or outside the gap where the seeded shots separate), else None: there the bisection's
    single number is one draw of what the scatter of the yarns and the impact point decide, and
    V50 is the limit to quote (docs/studies.md, "The step and the ballistic limit")."""
    fit = res.get("v50")
    if not fit:
        return None
    lo, hi = fit["ci95"]
    v_bl = res["v_bl"]
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= v_bl <= hi:
        return None
    return (f"V_BL by bisection ({v_bl:.4g} m/s) lies outside the seeded V50's 95 % interval "
            f"[{lo:.4g}, {hi:.4g}] m/s: the deterministic shots are one draw of the yarns' "
            f"scatter and the impact point; quote V50 = {fit['v50']:.4g} m/s with its spread")


def non_monotone(shots: list[dict[str, Any]], v_bl: float) -> list[dict[str, Any]]:
    """The outcomes of the scenario as given (seeded shots scatter by design: left out) that a
    sharp ballistic limit cannot explain: each stopped shot faster than a perforating one, as
    {"stopped": its speed, "perforated": the fastest perforating speed below it}, and a
    stopped shot above `v_bl` with no perforating shot below it, with "perforated": None;
    by the stopped speed [m/s]."""
    det = [s for s in shots if s["seed"] is None]
    perf = sorted(float(s["speed"]) for s in det if s["perforated"] == 1)
    out: list[dict[str, Any]] = []
    for v in sorted(float(s["speed"]) for s in det if s["perforated"] == 0):
        below = [p for p in perf if p < v]
        if below:
            out.append({"stopped": v, "perforated": below[-1]})
        elif v > v_bl:
            out.append({"stopped": v, "perforated": None})
    return out


def _node_spacing(scenario: Scenario) -> np.ndarray:
    fab = scenario.fabric
    return np.array([fab.size[0] / (fab.nodes[0] - 1), fab.size[1] / (fab.nodes[1] - 1)])


def write_outputs(res: dict[str, Any], out: Path) -> list[Path]:
    """ballistic.json, ballistic.nc (the shots) and ballistic.png."""
    import xarray as xr

    from emfabric import __version__
    from emfabric.io import jsontext
    from emfabric.io.atomic import write_atomic
    from emfabric.io.netcdf import write_netcdf

    out.mkdir(parents=True, exist_ok=True)
    text = jsontext.dumps(res, indent=1)
    write_atomic(out / "ballistic.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
    shots = res["shots"]
    ds = xr.Dataset({
        "striking_speed": ("shot", np.array([s["speed"] for s in shots]), {"units": "m s-1"}),
        "residual_speed": ("shot", np.array([s["residual_speed"] for s in shots]),
                           {"units": "m s-1"}),
        "perforated": ("shot", np.array([s["perforated"] for s in shots], dtype=np.int8),
                       {"long_name": "1 perforated, 0 stopped, -1 failed", "units": "1"}),
        "seed": ("shot", np.array([-1 if s["seed"] is None else s["seed"] for s in shots]),
                 {"long_name": "modulus seed and impact jitter (-1: the scenario as given)",
                  "units": "1"}),
        "status": ("shot", np.array([str(s["status"]) for s in shots])),
    }, attrs={"title": "emfabric ballistic limit", "emfabric_version": __version__,
              "v_bl": res["v_bl"], "lambert_jonas": jsontext.dumps(res["lambert_jonas"]),
              "v50": jsontext.dumps(res.get("v50")),
              **({"base_scenario": res["base_scenario"]} if "base_scenario" in res else {})})
    write_netcdf(ds, out / "ballistic.nc")
    from emfabric.viz.study_plots import ballistic_figure

    figure = ballistic_figure(res, out / "ballistic.png", lambert_jonas)
    return [out / "ballistic.json", out / "ballistic.nc", figure]
