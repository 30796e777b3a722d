"""Diagnostics as pure functions of (Model, State): tilt, energies, momenta, damage statistics."""

from __future__ import annotations

import math

import numpy as np

from emfabric._kernels import diagnostics as _k
from emfabric.model import Model, State


def flight_direction(model: Model) -> np.ndarray:
    """Unit vector of the projectile's initial velocity (−z if it starts at rest)."""
    v = model.body_v0
    speed = float(np.linalg.norm(v))
    return v / speed if speed > 0 else np.array([0.0, 0.0, -1.0])


def tilt(model: Model, state: State) -> float:
    """Tilt angle Θ of eq. 5.2 [rad]: angle between the nose marker now and at t = 0."""
    now = state.body_rotation @ model.body_nose
    ref = model.body_nose
    # atan2 form of arccos(a·b/|a||b|): accurate at small angles
    return math.atan2(float(np.linalg.norm(np.cross(now, ref))), float(np.dot(now, ref)))


def body_inertia_world(model: Model, state: State) -> np.ndarray:
    """Inertia tensor about the centre of mass in the inertial frame [kg m²] (B15)."""
    rot = state.body_rotation
    return rot @ model.body_inertia @ rot.T


def projectile_energy(model: Model, state: State) -> tuple[float, float]:
    """Translational and rotational kinetic energy of the body [J]."""
    if not model.has_body:
        return 0.0, 0.0
    v, w = state.body_v, state.body_omega
    rot = 0.5 * float(w @ body_inertia_world(model, state) @ w)
    return 0.5 * model.body_mass * float(v @ v), rot


def projectile_momenta(model: Model, state: State) -> tuple[np.ndarray, np.ndarray]:
    """Linear momentum and angular momentum about the origin of the body."""
    if not model.has_body:
        return np.zeros(3), np.zeros(3)
    p = model.body_mass * state.body_v
    h = body_inertia_world(model, state) @ state.body_omega
    return p, np.cross(state.body_x, p) + h


def fabric_diagnostics(model: Model, state: State, coef: np.ndarray) -> np.ndarray:
    """Packed fabric diagnostics (see emfabric._kernels.diagnostics for the layout)."""
    out = np.empty(_k.COUNT)
    centre = state.body_x if model.has_body else np.zeros(3)
    _k.fabric_diagnostics(state.node_x, state.node_v, model.node_x0, model.node_mass, model.nx,
                          model.ny, state.seg_alpha, coef, model.seg_rest_length,
                          model.material_kind, model.fung_H, model.broken_below, centre,
                          flight_direction(model), out)
    return out
