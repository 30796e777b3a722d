"""The named records the kernels take whole (NamedTuples: Numba compiles their fields by name).

A Model is a composition of these records (built by emfabric.builder), a State's arrays are a
``StateArrays``; a kernel reads ``fld.B`` or ``body.radius``, never a loose positional scalar.
Adding a field to a record changes the kernels' signatures, so nothing else needs to change for
the compiled code to see it. Units are SI throughout.

Layouts (the only place they are defined):
- node arrays are component-major, shape (3, node_count): ``x[:, n]`` is node n; node n sits at
  grid column i = n % nx and row j = n // nx;
- segments are numbered warp first (s = j·(nx−1) + i joins nodes j·nx + i and j·nx + i + 1), then
  fill (s = warp_count + j·nx + i joins j·nx + i and (j + 1)·nx + i); ``Yarns.ends`` holds the
  end nodes of every segment as data;
- the rigid body's state is one (BODY_ROWS, 3) array, rows BODY_X … BODY_M then the rotation
  matrix (body frame → inertial frame) in rows BODY_R0 … BODY_R0 + 2.
"""

from typing import NamedTuple

import numpy as np

BODY_X, BODY_V, BODY_W, BODY_F, BODY_M, BODY_R0 = 0, 1, 2, 3, 4, 5
"""Rows of the body state: position, velocity, angular velocity (inertial frame), non-impulsive
force and moment at the state's time, rotation matrix (three rows)."""
BODY_ROWS = 8

MATERIAL_KSV, MATERIAL_FUNG = 0, 1
REGION_UNIFORM, REGION_HALF_SPACE = 0, 1
SHAPE_SPHERE = 0


class Nodes(NamedTuple):
    """The fabric's lumped masses on an nx × ny grid."""

    nx: int
    ny: int
    x0: np.ndarray
    """Reference positions [m], (3, node_count)."""
    mass: np.ndarray
    """Lumped mass [kg], (node_count,)."""
    inv_mass: np.ndarray
    """1/mass [1/kg], 0 for clamped nodes."""
    charge: np.ndarray
    """[C], (node_count,)."""


class Yarns(NamedTuple):
    """Yarn segments as data: end nodes, rest lengths and axial stiffness."""

    ends: np.ndarray
    """End nodes (a, b) of each segment, (seg_count, 2) int64."""
    rest_length: np.ndarray
    """L0 [m], (seg_count,)."""
    inv_rest2: np.ndarray
    """1/L0² [1/m²]: the stretch² of a segment d = x_b − x_a is |d|²/L0² (stretch_sq)."""
    stiffness: np.ndarray
    """𝔼·A0/L0 (KSV) or c·A0/L0 (Fung) [N/m]: the tension vector is stiffness·α·S/𝔼·d."""
    modulus: np.ndarray
    """𝔼 (KSV) or c (Fung) of each segment [Pa]."""
    area: float
    """Undeformed cross-section A0 [m²]."""


class Material(NamedTuple):
    """Yarn constitutive and damage law (emfabric._kernels.materials)."""

    kind: int
    """MATERIAL_KSV or MATERIAL_FUNG."""
    fung_h: float
    critical_stretch: float
    damage_rate: float
    broken_below: float
    """α below which a yarn counts as broken (diagnostics only)."""


class Field(NamedTuple):
    """Applied fields (emfabric._kernels.fields.field_at) and gravity."""

    E: np.ndarray
    """[V/m], (3,)."""
    B: np.ndarray
    """[T], (3,)."""
    region: int
    """REGION_UNIFORM or REGION_HALF_SPACE (z < z0)."""
    z0: float
    gravity: np.ndarray
    """[m/s²], (3,)."""


class Body(NamedTuple):
    """The rigid projectile: shape (emfabric._kernels.shapes), inertia, charges."""

    active: bool
    """False when the scenario has no projectile."""
    shape: int
    """SHAPE_SPHERE."""
    radius: float
    """Shape size [m] (sphere radius)."""
    mass: float
    inertia: np.ndarray
    """Inertia about the centre of mass in the body frame [kg m²], (3, 3)."""
    charge_pos: np.ndarray
    """Charged points relative to the centre of mass, body frame [m], (charge_count, 3)."""
    charge: np.ndarray
    """[C], (charge_count,)."""
    nose: np.ndarray
    """Tilt marker relative to the centre of mass, body frame [m], (3,)."""


class Contact(NamedTuple):
    """Stick/slip contact law (emfabric._kernels.contact.contact_impulse)."""

    static_friction: float
    dynamic_friction: float


class Solver(NamedTuple):
    """What one attempted step needs of the solver settings."""

    phi: float
    """φ of the φ-scheme."""
    tolerance: float
    iteration_limit: int
    """Fixed-point iterations per attempt."""


class Physics(NamedTuple):
    """Everything a kernel reads about the model, by name."""

    nodes: Nodes
    yarns: Yarns
    material: Material
    field: Field
    body: Body
    contact: Contact


class StateArrays(NamedTuple):
    """The arrays of a State that a step reads (start) or writes (end)."""

    x: np.ndarray
    """Node positions [m], (3, node_count)."""
    v: np.ndarray
    """Node velocities [m/s]."""
    f: np.ndarray
    """Non-impulsive node forces at the state's time [N]."""
    alpha: np.ndarray
    """Yarn damage α, (seg_count,)."""
    body: np.ndarray
    """Body state, (BODY_ROWS, 3)."""


class Work(NamedTuple):
    """Scratch arrays of one attempted step."""

    xbuf: np.ndarray
    """Second iterate buffer, (3, node_count)."""
    err_rows: np.ndarray
    """Per-row error sums, (2, ny)."""
    err_num: np.ndarray
    err_den: np.ndarray
    cand: np.ndarray
    """Contact candidates (node indices)."""
    flag: np.ndarray
    """1 for contact candidates (uint8)."""
    c_node: np.ndarray
    c_imp: np.ndarray
    """Contact impulse on the node [N s], (3, node_count)."""
    c_arm: np.ndarray
    """Contact point relative to the body centre [m]."""
    c_proj: np.ndarray
    """Projection displacement [m]."""
    sum_buf: np.ndarray
    reaction: np.ndarray
    """Total contact + friction impulse on the body [N s] and its moment about the centre of
    mass [N m s] of the last iterate, (2, 3)."""


def make_work(nx: int, ny: int) -> Work:
    n = nx * ny
    return Work(np.empty((3, n)), np.empty((2, ny)), np.empty(n), np.empty(n),
                np.empty(n, dtype=np.int64), np.zeros(n, dtype=np.uint8),
                np.empty(n, dtype=np.int64), np.empty((3, n)), np.empty((3, n)),
                np.empty((3, n)), np.empty(n), np.zeros((2, 3)))
