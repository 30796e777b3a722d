"""The run summary: the figures a user reads first, computed once from a finished (or stopped)
run's history. ``emfabric run`` prints it (and ``--json`` emits it), ``RunResult.summary`` holds
it, and the studies take their metrics from it (emfabric.studies.sweep.metrics_of)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from emfabric.io.history import fabric_reference
from emfabric.sim.diagnostics import held_nodes, through_the_pack
from emfabric.sim.plausibility import actuation_report


def perforated(history, status: str, end_reason: str, bound: float, back: float = 0.0,
               through: bool = False) -> int:
    """1 if the run ended by perforation, or at end_time moving forward, past the pack's last
    plane (z = back; one sheet: z = 0) by more than the body's bounding radius `bound` and
    clear of the fabric — or, `through`, clear of every node an intact yarn still holds
    (sim.diagnostics.through_the_pack: it carries a plug of broken yarn); 0 if it rebounded,
    never touched or moves back; -1 undecided (still in contact and moving on at end_time,
    diverged, failed)."""
    ds = history
    if status not in ("complete", "partial"):
        return -1
    v = ds["projectile_velocity"][-1].values
    v0 = ds["projectile_velocity"][0].values
    d = v0 / max(float(np.linalg.norm(v0)), 1e-300)
    forward = float(v @ d)
    # how far the centre is past the pack's last plane, along the flight
    past = float((ds["projectile_position"][-1].values - np.array([0.0, 0.0, back])) @ d)
    clear = past > bound
    touching = int(ds["contact_nodes"][-1]) > 0
    if end_reason == "perforation":
        return 1
    if end_reason in ("rebound", "never touched") or forward <= 0.0:
        return 0
    if clear and (through or not touching):
        return 1
    if not clear and not touching and int(ds["contact_nodes"].max()) == 0:
        return 0  # has not reached the sheet yet
    return -1


def plies_perforated(model, state, history) -> int:
    """Plies the projectile has perforated: it has passed the ply — its centre beyond, along
    its flight, every node of the ply still held by an intact yarn (nodes torn loose and
    carried along do not count) by more than its bounding radius — and the ply moved (a ply it
    fell through without touching, between its yarns, is not perforated)."""
    d = model.body_v0 / max(float(np.linalg.norm(model.body_v0)), 1e-300)
    held = held_nodes(model, state.seg_alpha)
    ahead = (state.node_x - state.body_x[:, None]).T @ d
    clear = float(model.geometry.bound)
    count = 0
    for p in range(model.ply_count):
        sl = slice(int(model.nodes.ply_nodes[p]), int(model.nodes.ply_nodes[p + 1]))
        mine = ahead[sl][held[sl]]
        moved = float(history["max_deflection_per_ply"][:, p].max()) > 0.0
        if mine.size and float(mine.max()) < -clear and moved:
            count += 1
    return count


def summarize(result) -> dict[str, Any]:
    """The end-of-run figures of a RunResult (emfabric.runner.loop)."""
    ds, st, m = result.history, result.state, result.model
    steps = int(ds.sizes["time"]) - 1
    out: dict[str, Any] = {
        "status": result.status,
        "end_reason": result.end_reason,
        "time_s": float(st.t),
        "integrator": m.options.integrator,
        "steps": steps,
        "rejected_steps": int(st.rejected),
        "force_evaluations": int(st.evaluations),
        "mean_iterations": float(ds["iterations"][1:].mean()) if steps else 0.0,
        "final_dt_s": float(ds["dt"][-1]) if steps else 0.0,
        "wall_time_s": float(result.wall_time),
        "broken_yarns": int(ds["broken_yarns"][-1]),
        "min_damage": float(ds["min_damage"].min()),
        "max_stretch": float(ds["max_stretch"].max()),
        "max_deflection_m": float(ds["max_deflection"].max()),
        "energy_balance_error_J": float(ds["energy_balance_error"][-1]),
        "fabric": fabric_reference(m.scenario) if m.scenario is not None else "built in Python",
    }
    if m.has_body:
        v = ds["projectile_velocity"][-1].values
        w = ds["angular_velocity"][-1].values
        ke = ds["kinetic_energy_projectile"].values
        tilt = float(ds["tilt"].max())
        yaw = float(ds["yaw"].max())
        out.update({
            "final_velocity_m_s": [float(c) for c in v],
            "residual_speed_m_s": float(np.linalg.norm(v)),
            "final_omega_rad_s": [float(c) for c in w],
            "max_tilt_deg": float(np.degrees(tilt)),
            "max_tilt_rad": tilt,
            "max_yaw_rad": yaw,
            "energy_absorbed_J": float(ke[0] - ke[-1]),
            "perforated": perforated(ds, result.status, result.end_reason,
                                     float(m.geometry.bound),
                                     float(m.nodes.x0[2, m.nodes.ply_nodes[-2]]),
                                     through_the_pack(m, st)),
            "plies": m.ply_count,
            "plies_perforated": plies_perforated(m, st, ds),
        })
    else:
        # the fabric alone: the same keys (a script reads one schema), the projectile's figures
        # not a number (null in --json), perforation undecided
        out.update({"final_velocity_m_s": [math.nan] * 3, "residual_speed_m_s": math.nan,
                    "final_omega_rad_s": [math.nan] * 3, "max_tilt_deg": math.nan,
                    "max_tilt_rad": math.nan, "max_yaw_rad": math.nan,
                    "energy_absorbed_J": math.nan, "perforated": -1,
                    "plies": m.ply_count, "plies_perforated": -1})
    # is the actuation physical? (emfabric.sim.plausibility; docs/theory.md §3.1)
    act = actuation_report(m)
    out.update({
        "surface_charge_C_m2": act["surface_charge_C_m2"],
        "surface_field_V_m": act["max_surface_field_V_m"],
        "electrostatic_pressure_Pa": act["electrostatic_pressure_Pa"],
        # against what holds: air's dielectric strength and the yarn's tensile strength (None
        # where the scenario names no strength: no library material, no tensile_strength)
        "field_over_air_breakdown": act["field_over_air_breakdown"],
        "tensile_strength_Pa": act["tensile_strength_Pa"],
        "pressure_over_strength": act["pressure_over_strength"],
        "charge_plausible": act["charge_plausible"],
        "plausibility_warnings": act["warnings"],
    })
    return out
