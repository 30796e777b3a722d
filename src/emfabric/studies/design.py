"""Field design: the paper's back-of-envelope field for a target tilt (eqs 5.3–5.4), and the
field found by simulation (``emfabric estimate``, ``emfabric design-field``).

Eq 5.3 balances the moment that gives a body of inertia I, at rest, the tilt Θ* after δt under
constant angular acceleration, I · 2Θ*/δt², with the moment of the friction the field's force
q v × B can mobilise on the N_c nodes in contact at the body's radius R: μ_s N_c q ‖v‖ ‖B‖ R.
The paper prints it without the charge q (its nodes carry q = 1 C); derived, it is

    ‖B‖ = 2 I Θ* / (δt² q ‖v‖ μ_s N_c R)                                     (eq 5.4)

with N_c = π R² / (Δx Δy) the nodes under the body's cross-section (Δx, Δy the node spacing),
q the charge of a node, ‖v‖ the striking speed, I the moment of inertia about the field's
direction. It is an order of magnitude: the simulation sharpens it (design_field).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from emfabric.config.scenario import Scenario


@dataclass
class Estimate:
    """Eq 5.4 and its inputs (SI units)."""

    B: float
    moment: float
    inertia: float
    charge: float
    speed: float
    static_friction: float
    nodes_in_contact: float
    radius: float
    tilt: float
    by: float

    def as_dict(self) -> dict[str, Any]:
        return {"B": self.B, "estimate_eq54": self.B, "moment_eq53": self.moment,
                "inputs": {"I": self.inertia, "q": self.charge, "speed": self.speed,
                           "mu_s": self.static_friction, "N_c": self.nodes_in_contact,
                           "R": self.radius, "target_tilt": self.tilt, "by": self.by},
                "units": {"B": "T", "estimate_eq54": "T", "moment_eq53": "N m", "I": "kg m2",
                          "q": "C", "speed": "m s-1", "R": "m", "target_tilt": "rad",
                          "by": "s"}}


def estimate(scenario: Scenario, tilt: float, by: float) -> Estimate:
    """Eq 5.4 for the scenario's projectile and fabric (see the module docstring)."""
    from emfabric.sim.builder import build_model

    if not 0.0 < tilt <= math.pi:
        # the tilt is the angle between the axis and its initial direction: at most π
        raise ValueError(f"--target-tilt {tilt}: allowed: an angle in (0, π] rad")
    if not (by > 0.0 and math.isfinite(by)):
        raise ValueError(f"--by {by}: allowed: a positive time [s]")
    model = build_model(scenario, writes=False)  # an estimate: nothing written
    if not model.has_body:
        raise ValueError("the scenario has no projectile (projectile.shape = \"none\"): there "
                         "is nothing to tilt")
    fab = scenario.fabric
    nx, ny = model.ply_grid(0)
    dx = fab.size[0] / (nx - 1)
    dy = fab.size[1] / (ny - 1)
    radius = float(model.body.radius)
    n_c = math.pi * radius**2 / (dx * dy)
    free = model.nodes.inv_mass > 0
    q = float(np.mean(np.abs(model.nodes.charge[free])))
    speed = float(np.linalg.norm(model.body_v0))
    b = np.asarray(scenario.field.B, dtype=float)
    axis = b / np.linalg.norm(b) if np.linalg.norm(b) > 0 else np.array([1.0, 0.0, 0.0])
    inertia = float(axis @ model.body.inertia @ axis)
    mu = float(scenario.contact.static_friction)
    moment = inertia * 2.0 * tilt / by**2
    denom = q * speed * mu * n_c * radius
    if not denom > 0.0:
        raise ValueError(f"eq 5.4 needs charged nodes, a moving projectile and friction (q = "
                         f"{q}, speed = {speed}, static_friction = {mu})")
    return Estimate(moment / denom, moment, inertia, q, speed, mu, n_c, radius, tilt, by)


@dataclass
class Probe:
    scale: float
    tilt: float
    status: str


def _falling_above_best(probes: dict) -> tuple[float, float] | None:
    """(the scale of the largest tilt, the largest scale) when the two largest scales of the
    complete probes both lie above the one of the largest tilt and their tilts fall with the
    scale: going further up only lowers the tilt (and in a strong field every doubling doubles
    a run's steps: docs/theory.md §4.1, the gyration limit). Else None."""
    ok = sorted(x for x, p in probes.items() if p.status == "complete"
                and math.isfinite(p.tilt))
    if len(ok) < 3:
        return None
    best = max(ok, key=lambda x: probes[x].tilt)
    a, b = ok[-2], ok[-1]
    if a > best and probes[b].tilt <= probes[a].tilt < probes[best].tilt:
        return best, b
    return None


def design_field(scenario: Scenario, tilt: float, by: float, out, *,
                 workers: int | None = None, scheduler: str | None = None,
                 threads: int | None = None, rel_tol: float = 0.02,
                 max_rounds: int = 12, progress=None) -> dict[str, Any]:
    """The smallest field scale s whose run tilts the projectile by `tilt` before `by`, by a
    bracketed search over runs on Dask (each round runs one probe per worker, at least two):
    bracket from the eq 5.4 scale upwards and downwards by factors of 2, then shrink the bracket
    [s_lo (tilt below target), s_hi (reached)] by k-section until s_hi/s_lo − 1 ≤ rel_tol.
    Assumes the max tilt grows with the field near the answer (it is not always monotonic:
    the probes are all written to probes.json, and the figure shows them)."""
    from pathlib import Path

    from emfabric import __version__
    from emfabric.sources.scaling import field_at_centre, scale_field
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
    est = estimate(scenario, tilt, by)
    b0 = np.linalg.norm(field_at_centre(scenario, by))
    if not b0 > 0.0:
        raise StudyError("the scenario's field is zero at the sheet's centre at the target "
                         "time: nothing to scale (give it a field, e.g. --set field.B=[1,0,0])")
    base = scenario.replace(**{"solver.end_time": by})
    probes: dict[float, Probe] = {}

    def case_for(s: float) -> Case:
        sc = scale_field(base, s)
        text = sc.to_toml()
        return Case((len(probes),), {"scale": s}, sc, case_key(text), text)

    client = cluster = None
    interrupted = False
    per_case = 1
    try:
        def measure(scales: list[float]) -> None:
            nonlocal client, cluster, per_case
            cases = [case_for(s) for s in scales]
            todo = [c for c in cases if read_case(out, c) is None]
            if todo:
                if client is None:
                    client, cluster, per_case = connect(workers, scheduler, threads)
                run_cases(todo, out, client, per_case, False,
                          explicit=threads is not None)
            for s, c in zip(scales, cases, strict=True):
                rec = read_case(out, c) or {}
                status = str(rec.get("status", "failed"))
                # a run that stopped early (diverged, failed) says nothing about the tilt by
                # the target time: it brackets nothing
                probes[s] = Probe(s, float(rec.get("max_tilt", math.nan))
                                  if status == "complete" else math.nan, status)
            if progress is not None:
                progress(len(probes))

        width = 2 if workers is None else max(2, workers)
        s_est = est.B / b0
        measure([s_est * 2.0 ** (k - width // 2) for k in range(width)])
        lo = hi = None
        for _ in range(max_rounds):
            reached = sorted(x for x, p in probes.items() if p.tilt >= tilt)
            missed = sorted(x for x, p in probes.items() if p.tilt < tilt)  # NaN: neither
            if reached and (not missed or missed[0] > reached[0]) and \
                    reached[0] < 1e-6 * s_est:
                hi, lo = reached[0], 0.0  # reached with (almost) no field
                break
            if reached and any(m < reached[0] for m in missed):
                hi = reached[0]
                lo = max(m for m in missed if m < hi)
                break
            if reached:  # every probe reached the target: go down
                measure([min(probes) / 2.0 ** (k + 1) for k in range(width)])
            else:  # none did: go up, unless the runs stop completing up there
                top = max(probes)
                if probes[top].status != "complete":
                    ok = [x for x, p in probes.items() if p.status == "complete"]
                    best = max(ok, key=lambda x: probes[x].tilt, default=None)
                    raise StudyError(
                        f"the runs stop completing above {max(ok, default=0.0):.3g} × the "
                        f"scenario's field ({probes[top].status} at {top:.3g} ×) before any "
                        f"reached a tilt of {tilt} rad by {by} s"
                        + ("" if best is None else f"; the largest tilt of a complete run: "
                           f"{probes[best].tilt:.3g} rad at {best:.3g} ×")
                        + f"; the probes are in {out / 'cases'}")
                falling = _falling_above_best(probes)
                if falling is not None:
                    best, last = falling
                    raise StudyError(
                        f"no bracket for a tilt of {tilt} rad by {by} s: the largest tilt, "
                        f"{probes[best].tilt:.3g} rad at {best:.3g} × the scenario's field, "
                        f"falls as the field grows beyond it ({probes[last].tilt:.3g} rad at "
                        f"{last:.3g} ×): a stronger field does not reach the target (each "
                        f"doubling would only double the run's steps); the probes are in "
                        f"{out / 'cases'}")
                measure([top * 2.0 ** (k + 1) for k in range(width)])
        if hi is None:
            seen = [p.tilt for p in probes.values() if math.isfinite(p.tilt)]
            raise StudyError(f"no bracket for a tilt of {tilt} rad by {by} s between "
                             f"{min(probes):.3g} and {max(probes):.3g} × the scenario's field "
                             f"(largest tilt seen: {max(seen, default=math.nan):.3g} rad)")
        rounds = 0
        while hi - lo > rel_tol * hi and rounds < max_rounds:
            k = width
            scales = [lo + (hi - lo) * (i + 1) / (k + 1) for i in range(k)]
            measure(scales)
            for s in scales:
                if probes[s].tilt >= tilt:
                    hi = min(hi, s)
            lo = max([lo] + [s for s in scales if s < hi and probes[s].tilt < tilt])
            rounds += 1
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if client is not None:
            release(client, cluster, interrupted)
    b_centre = field_at_centre(scale_field(scenario, hi), by)
    return {"scale": hi, "B_centre": b_centre, "B_centre_norm": float(np.linalg.norm(b_centre)),
            "estimate_eq54": est.B, "target_tilt": tilt, "by": by, "bracket": [lo, hi],
            "probes": [{"scale": p.scale, "max_tilt": p.tilt, "status": p.status}
                       for p in sorted(probes.values(), key=lambda p: p.scale)],
            "runs": len(probes), "scenario": scenario.name,
            "base_scenario": scenario.to_toml(), "emfabric_version": __version__}
