"""Is the actuation physical? The charge a model puts on its fabric and the field it applies,
against what matter and magnets can do (issue 24; docs/theory.md §3.1).

``actuation_report(model)`` takes a built Model (emfabric.sim.builder) and returns plain numbers
and warnings; ``emfabric validate`` prints them and the run summary (emfabric.runner.summary)
carries the headline figures. Nothing here changes a run.

Decisions (docs/theory.md §3.1):
- the surface charge density is a ply's (or the pack's) total charge over the sheet's projected
  area Lx·Ly (``fabric.size``), both faces counted as one sheet: σ = Q/(Lx·Ly);
- the surface field is that of an isolated, uniformly charged thin sheet, E_s = |σ|/(2 ε0) on
  either side (a conductor carrying σ/2 on each face has σ/(2 ε0) at each face: the same);
- the electrostatic pressure is p = σ²/(2 ε0), the Maxwell stress ε0 E²/2 of the field σ/ε0
  that the whole charge on one face would have: an upper bound of the pull the charge exerts
  (the field energy density at E_s, σ²/(8 ε0), is four times smaller); it is compared with the
  yarn's tensile strength as an order of magnitude, not as a failure criterion;
- E_MAX, "beyond what any material holds", is the field that evaporates the surface atoms of
  tungsten, the most field-resistant metal: ≈ 6 V/Å = 6e10 V/m;
- the applied field is taken at the fabric's nodes at rest (Nodes.x0) at t = 0 and, when a
  source's current varies in time, also at 33 times evenly over [0, solver.end_time] (a pulse
  is zero at t = 0); the fabric's own charge field is not part of the applied field.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from emfabric._kernels.coils import WAVE_CONSTANT
from emfabric.sources.evaluate import fields_at

EPS0 = 8.8541878128e-12
"""Vacuum permittivity ε0 [F/m] (CODATA 2018)."""
E_BREAKDOWN_AIR = 3e6
"""Dielectric strength of dry air at sea-level pressure [V/m] (about 3 MV/m; AMS Glossary of
Meteorology, "dielectric strength"; lower in humid air and at lower pressure)."""
E_MAX_SURFACE = 6e10
"""The largest surface field any material holds [V/m]: field evaporation of tungsten, ≈ 6 V/Å
(Ono et al., arXiv cond-mat/0410034, in agreement with the measured values; molybdenum ≈ 5 V/Å;
a negatively charged surface loses electrons by field emission already from ~1e9 V/m, the
commonly quoted value)."""
B_PERMANENT = 1.4
"""Remanence of the strongest sintered NdFeB grades [T] (N52: 1.42–1.48 T in manufacturers'
tables; the field next to a magnet's pole is below its remanence)."""
B_PULSED_MAX = 100.0
"""The strongest non-destructive pulsed magnets [T] (NHMFL Pulsed Field Facility, Los Alamos:
past 100 T on 22 March 2012; Physics Today 65(5), 30 (2012))."""
FIELD_SAMPLES = 33
"""Times over [0, end_time] at which a time-varying applied field is sampled."""


def _area(model) -> float:
    """The sheet's projected area [m²]: fabric.size, or the nodes' extent for a Model put
    together in Python."""
    sc = model.scenario
    if sc is not None:
        lx, ly = sc.fabric.size
        return float(lx) * float(ly)
    x0 = np.asarray(model.nodes.x0)
    return float(np.ptp(x0[0]) * np.ptp(x0[1]))


def _strengths(model) -> list[float | None]:
    """Each ply's yarn tensile strength [Pa], None where the scenario gives none."""
    sc = model.scenario
    if sc is None:
        return [None] * model.ply_count
    out: list[float | None] = []
    for p in range(model.ply_count):
        try:
            material = sc.fabric.ply_fabric(p).material
        except (AttributeError, IndexError, TypeError, ValueError):
            material = sc.fabric.material
        value = getattr(material, "tensile_strength", None)
        out.append(float(value) if value is not None else None)
    return out


def _time_varying(fld) -> bool:
    cur = np.asarray(getattr(fld, "currents", np.zeros((0, 6))))
    return bool(cur.size) and bool(np.any(cur[:, 0] != WAVE_CONSTANT))


def _magnitudes(v: np.ndarray) -> np.ndarray:
    """|v| of each row of v (N, 3), without the overflow of squaring a component near the
    largest double (a field of 1e300 V/m is 1e300, not inf)."""
    return np.hypot(np.hypot(v[:, 0], v[:, 1]), v[:, 2])


def _peak_fields(model) -> tuple[float, float, float, float, float]:
    """Largest |B| [T] and |E| [V/m] at the nodes at t = 0, and the largest over the run's
    sampled times with the time [s] of the largest |B|."""
    pts = np.ascontiguousarray(np.asarray(model.nodes.x0, dtype=float).T)
    fld = model.field
    e, b = fields_at(fld, pts, 0.0)
    with np.errstate(over="ignore"):  # a field evaluated as inf is reported as inf, not warned
        b0 = float(_magnitudes(b).max()) if pts.size else 0.0
        e0 = float(_magnitudes(e).max()) if pts.size else 0.0
        b_peak, e_peak, t_peak = b0, e0, 0.0
        end = float(model.options.end_time)
        if pts.size and _time_varying(fld) and end > 0.0:
            for t in np.linspace(0.0, end, FIELD_SAMPLES)[1:]:
                e, b = fields_at(fld, pts, float(t))
                bt = float(_magnitudes(b).max())
                e_peak = max(e_peak, float(_magnitudes(e).max()))
                if bt > b_peak:
                    b_peak, t_peak = bt, float(t)
    return b0, e0, b_peak, e_peak, t_peak


def surface_numbers(charge: float, area: float) -> tuple[float, float, float]:
    """σ = Q/A [C/m²], E_s = |σ|/(2 ε0) [V/m] and p = σ²/(2 ε0) [Pa] of a sheet of area A [m²]
    carrying Q [C]."""
    sigma = charge / area
    return sigma, abs(sigma) / (2.0 * EPS0), sigma * sigma / (2.0 * EPS0)


def actuation_report(model) -> dict[str, Any]:
    """The charge and applied field of a built Model against physical limits: plain numbers
    (floats, ints, strings, lists of them; None where the scenario gives no yarn strength) and
    report["warnings"], a list of strings (empty when everything is attainable)."""
    charge = np.asarray(model.nodes.charge, dtype=float)
    bounds = np.asarray(model.nodes.ply_nodes, dtype=np.int64)
    plies = int(model.ply_count)
    area = _area(model)
    ply_q = (np.add.reduceat(charge, bounds[:-1]) if charge.size
             else np.zeros(plies)).astype(float)
    per_ply = [surface_numbers(float(q), area) for q in ply_q]
    total = float(charge.sum())
    sigma, e_s, p = surface_numbers(total, area)
    # the field that decides: the pack's, or one ply's where the plies' charges differ in sign
    e_top = max([e_s] + [n[1] for n in per_ply])

    strengths = _strengths(model)
    known = [s for s in strengths if s is not None]
    ratios = [n[2] / s for n, s in zip(per_ply, strengths, strict=True) if s is not None]
    if known:
        ratios.append(p / min(known))
    p_ratio = max(ratios) if ratios else None

    b0, e0, b_peak, e_peak, t_peak = _peak_fields(model)

    warnings: list[str] = []
    where = "" if plies == 1 else ", the pack's or its most charged ply's"
    if e_top > E_MAX_SURFACE:
        warnings.append(
            f"surface field of the fabric's charge E_s = {e_top:.3g} V/m (σ = "
            f"{sigma:.3g} C/m²{where}) is beyond what any material holds "
            f"({E_MAX_SURFACE:.0e} V/m, field evaporation of tungsten; "
            f"{e_top / E_MAX_SURFACE:.2g} times that): no "
            f"material keeps this charge, and at {e_top / E_BREAKDOWN_AIR:.2g} times air's "
            f"breakdown field the sheet would discharge into air")
    elif e_top > E_BREAKDOWN_AIR:
        warnings.append(
            f"surface field of the fabric's charge E_s = {e_top:.3g} V/m (σ = "
            f"{sigma:.3g} C/m²{where}) exceeds air's breakdown field {E_BREAKDOWN_AIR:.0e} V/m "
            f"({e_top / E_BREAKDOWN_AIR:.2g} times): the sheet would discharge into air "
            "(it could hold the charge only in vacuum)")
    if p_ratio is not None and p_ratio > 1.0:
        p_top = max([p] + [n[2] for n in per_ply])
        warnings.append(
            f"electrostatic pressure of the charge p = σ²/(2ε0) = {p_top:.3g} Pa "
            f"exceeds the yarn's tensile strength {min(known):.3g} Pa ({p_ratio:.2g} times)")
    if b_peak > B_PULSED_MAX:
        at = "" if t_peak == 0.0 else f" (at t = {t_peak:.3g} s)"
        warnings.append(
            f"applied |B| at the fabric reaches {b_peak:.3g} T{at}: beyond the strongest "
            f"non-destructive pulsed magnets (≈ {B_PULSED_MAX:.0f} T)")
    if e_peak > E_BREAKDOWN_AIR:
        warnings.append(
            f"applied |E| at the fabric reaches {e_peak:.3g} V/m: beyond air's breakdown field "
            f"{E_BREAKDOWN_AIR:.0e} V/m")

    return {
        "plies": plies,
        "area_m2": area,
        "charge_C": total,
        "surface_charge_C_m2": sigma,
        "surface_field_V_m": e_s,
        "electrostatic_pressure_Pa": p,
        "max_surface_field_V_m": e_top,
        "ply_charge_C": [float(q) for q in ply_q],
        "ply_surface_charge_C_m2": [n[0] for n in per_ply],
        "ply_surface_field_V_m": [n[1] for n in per_ply],
        "ply_pressure_Pa": [n[2] for n in per_ply],
        "field_over_air_breakdown": e_top / E_BREAKDOWN_AIR,
        "field_over_material_limit": e_top / E_MAX_SURFACE,
        "air_breakdown_V_m": E_BREAKDOWN_AIR,
        "material_limit_V_m": E_MAX_SURFACE,
        "tensile_strength_Pa": min(known) if known else None,
        "pressure_over_strength": p_ratio,
        "charge_plausible": bool(e_top <= E_BREAKDOWN_AIR),
        "peak_B_t0_T": b0,
        "peak_E_t0_V_m": e0,
        "peak_B_T": b_peak,
        "peak_B_time_s": t_peak,
        "peak_E_V_m": e_peak,
        "B_over_permanent_magnet": b_peak / B_PERMANENT,
        "B_over_pulsed_record": b_peak / B_PULSED_MAX,
        "warnings": warnings,
    }


def log_warnings(model, logger) -> list[str]:
    """Log each of actuation_report(model)'s warnings once on `logger` (a run's start); return
    them."""
    found = actuation_report(model)["warnings"]
    for w in found:
        logger.warning("%s", w)
    return found
