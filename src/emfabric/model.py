"""Model (everything a step only reads) and State (everything a step writes).

A Model is the scenario plus a composition of named records (emfabric._kernels.records): nodes,
yarns, material, field, body, contact. The kernels take the ``physics`` record whole. A State is
made by emfabric.state.initial_state; a checkpoint is a State (emfabric.io.checkpoint).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from emfabric._kernels.records import (
    BODY_R0,
    BODY_V,
    BODY_W,
    BODY_X,
    Body,
    Contact,
    Field,
    Material,
    Nodes,
    Physics,
    StateArrays,
    Yarns,
)
from emfabric.geometry import ShapeGeometry
from emfabric.scenario import Scenario


@dataclass(frozen=True, eq=False)
class Model:
    """Everything a step only reads, as named records, and the scenario it was built from."""

    scenario: Scenario
    physics: Physics
    """The records the kernels take (nodes, yarns, material, field, body, contact)."""
    geometry: ShapeGeometry = field(repr=False)
    """The projectile's shape and dimensions (volume, inertia, surface mesh)."""
    flight_direction: np.ndarray = field(repr=False)
    """Unit vector of the projectile's initial velocity (−z if it starts at rest)."""
    body_x0: np.ndarray = field(repr=False)
    """Initial centre of mass [m]."""
    body_v0: np.ndarray = field(repr=False)
    body_w0: np.ndarray = field(repr=False)
    node_v0: np.ndarray = field(repr=False)

    @property
    def nodes(self) -> Nodes:
        return self.physics.nodes

    @property
    def yarns(self) -> Yarns:
        return self.physics.yarns

    @property
    def material(self) -> Material:
        return self.physics.material

    @property
    def field(self) -> Field:
        return self.physics.field

    @property
    def body(self) -> Body:
        return self.physics.body

    @property
    def contact(self) -> Contact:
        return self.physics.contact

    @property
    def nx(self) -> int:
        return self.nodes.nx

    @property
    def ny(self) -> int:
        return self.nodes.ny

    @property
    def node_count(self) -> int:
        return self.nodes.nx * self.nodes.ny

    @property
    def warp_count(self) -> int:
        return self.ny * (self.nx - 1)

    @property
    def seg_count(self) -> int:
        return self.yarns.ends.shape[0]

    @property
    def has_body(self) -> bool:
        return bool(self.body.active)



# cumulative energy terms [J], in the order of State.energy
ENERGY_TERMS = (
    "work_field",
    "work_gravity",
    "dissipation_friction",
    "dissipation_contact",
    "dissipation_projection",
    "dissipation_damage",
)


@dataclass(eq=False)
class State:
    """Everything a step writes; a checkpoint is just a State."""

    t: float
    """Time [s]."""
    dt: float
    """Next step size to try (the controller's state) [s]."""
    node_x: np.ndarray
    """Node positions [m], shape (3, node_count)."""
    node_v: np.ndarray
    """Node velocities [m/s], shape (3, node_count)."""
    node_f: np.ndarray
    """Non-impulsive force on each node at time t (ψ(t) of the φ-scheme) [N], (3, node_count)."""
    node_e: np.ndarray
    """The electric field [V/m] in each node's ψ(t), (3, node_count): the energy bookkeeping's
    field work uses the field the φ-update used (emfabric._kernels.energy)."""
    seg_alpha: np.ndarray
    """Committed yarn damage α (1 intact, 0 broken), shape (seg_count,)."""
    body: np.ndarray
    """Rigid body, shape (BODY_ROWS, 3): the rows of emfabric._kernels.records (x [m], v [m/s],
    ω [rad/s], F [N], M [N m] (non-impulsive force and moment at t), rotation matrix)."""
    steps: int = 0
    """Accepted steps so far."""
    rejected: int = 0
    """Rejected attempts so far."""
    evaluations: int = 0
    """Force evaluations so far."""
    iterations: int = 0
    """Fixed-point iterations of the last accepted step."""
    error: float = 0.0
    """ϖ_K of the last accepted step."""
    last_dt: float = 0.0
    """The last accepted step [s]."""
    contact_count: int = 0
    """Nodes in contact after the last step."""
    contact_steps: int = 0
    """Accepted steps that ended with a node in contact (0: the projectile never touched)."""
    energy: np.ndarray = field(default_factory=lambda: np.zeros(len(ENERGY_TERMS)))
    """Cumulative energy terms [J], see ENERGY_TERMS."""
    contact_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Total contact + friction force on the body over the last step, ΣJ/Δt [N]."""
    energy_initial: float = math.nan
    """Total energy of the initial state [J] (reference of the energy balance)."""

    @property
    def arrays(self) -> StateArrays:
        """The arrays a step kernel reads or writes, as a named record."""
        return StateArrays(self.node_x, self.node_v, self.node_f, self.seg_alpha, self.body,
                           self.node_e)

    @property
    def body_x(self) -> np.ndarray:
        return self.body[BODY_X]

    @property
    def body_v(self) -> np.ndarray:
        return self.body[BODY_V]

    @property
    def body_omega(self) -> np.ndarray:
        return self.body[BODY_W]

    @property
    def body_rotation(self) -> np.ndarray:
        return self.body[BODY_R0:BODY_R0 + 3]

    def copy(self) -> State:
        return State(**{f.name: (v.copy() if isinstance(v, np.ndarray) else v)
                        for f in fields(self) for v in [getattr(self, f.name)]})
