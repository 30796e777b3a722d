"""Model (everything a step only reads) and State (everything a step writes).

Arrays are float64. Node arrays are component-major, shape (3, node_count), so that the kernels'
inner loops run over contiguous memory; ``node_x[:, n]`` is node n's position. Node n sits at grid
column i = n % nx and row j = n // nx. Segments are numbered warp first (x-neighbours,
s = j·(nx−1) + i), then fill (y-neighbours, s = warp_count + j·nx + i).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from emfabric.scenario import Scenario

# rows of the packed rigid-body state, shape (BODY_ROWS, 3)
BODY_X, BODY_V, BODY_W, BODY_F, BODY_M, BODY_R0 = 0, 1, 2, 3, 4, 5
BODY_ROWS = 8  # rows 5..7: rotation matrix (body frame -> inertial frame)

MATERIAL_KSV, MATERIAL_FUNG = 0, 1
REGION_UNIFORM, REGION_HALF_SPACE = 0, 1


@dataclass(frozen=True, eq=False)
class Model:
    """Everything a step only reads: geometry, material, field, body, solver options."""

    scenario: Scenario
    nx: int
    ny: int
    node_x0: np.ndarray
    """Reference (initial) node positions [m], shape (3, node_count)."""
    node_mass: np.ndarray
    """Lumped node mass [kg], shape (node_count,)."""
    node_inv_mass: np.ndarray
    """1/mass [1/kg], 0 for fixed (clamped) nodes, shape (node_count,)."""
    node_charge: np.ndarray
    """Node charge [C], shape (node_count,)."""
    seg_nodes: np.ndarray
    """End nodes of each yarn segment, shape (seg_count, 2), int64."""
    seg_rest_length: np.ndarray
    """Yarn rest length L0 [m], shape (seg_count,)."""
    seg_modulus: np.ndarray
    """Young's modulus 𝔼_I (KSV) or Fung c_I of each yarn [Pa], shape (seg_count,)."""
    yarn_area: float
    """Undeformed cross-section A0 [m²]."""
    material_kind: int
    fung_H: float
    critical_stretch: float
    damage_rate: float
    broken_below: float
    field_E: np.ndarray
    """[V/m], shape (3,)."""
    field_B: np.ndarray
    """[T], shape (3,)."""
    field_region: int
    field_z0: float
    gravity: np.ndarray
    """[m/s²], shape (3,)."""
    has_body: bool
    body_radius: float
    body_mass: float
    body_inertia: np.ndarray
    """Inertia tensor about the centre of mass in the body frame [kg m²], shape (3, 3)."""
    body_charge_pos: np.ndarray
    """Charged points relative to the centre of mass, body frame [m], shape (charge_count, 3)."""
    body_charge: np.ndarray
    """[C], shape (charge_count,)."""
    body_nose: np.ndarray
    """Tilt marker relative to the centre of mass, body frame [m], shape (3,)."""
    body_x0: np.ndarray = field(repr=False)
    body_v0: np.ndarray = field(repr=False)
    body_w0: np.ndarray = field(repr=False)
    node_v0: np.ndarray = field(repr=False)

    @property
    def node_count(self) -> int:
        return self.nx * self.ny

    @property
    def warp_count(self) -> int:
        return self.ny * (self.nx - 1)

    @property
    def seg_count(self) -> int:
        return self.warp_count + (self.ny - 1) * self.nx

    def state(self) -> State:
        """A fresh State at t = 0 (the only way States are made)."""
        from emfabric.integrator import initial_forces

        n, s = self.node_count, self.seg_count
        st = State(
            t=0.0,
            dt=self.scenario.solver.dt_initial or self.scenario.solver.dt_max,
            node_x=self.node_x0.copy(),
            node_v=self.node_v0.copy(),
            node_f=np.zeros((3, n)),
            seg_alpha=np.ones(s),
            body=np.zeros((BODY_ROWS, 3)),
        )
        st.body[BODY_X] = self.body_x0
        st.body[BODY_V] = self.body_v0
        st.body[BODY_W] = self.body_w0
        st.body[BODY_R0:BODY_R0 + 3] = np.eye(3)
        initial_forces(self, st)
        return st


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
    """Next step size to try [s]."""
    node_x: np.ndarray
    """Node positions [m], shape (3, node_count)."""
    node_v: np.ndarray
    """Node velocities [m/s], shape (3, node_count)."""
    node_f: np.ndarray
    """Non-impulsive force on each node at time t (ψ(t) of the φ-scheme) [N], (3, node_count)."""
    seg_alpha: np.ndarray
    """Committed yarn damage α (1 intact, 0 broken), shape (seg_count,)."""
    body: np.ndarray
    """Rigid body, shape (8, 3): rows x [m], v [m/s], ω [rad/s], F [N], M [N m] (non-impulsive
    force and moment at t), then the rotation matrix (body -> inertial)."""
    steps: int = 0
    rejected: int = 0
    evaluations: int = 0
    iterations: int = 0
    error: float = 0.0
    contact_count: int = 0
    energy: np.ndarray = field(default_factory=lambda: np.zeros(len(ENERGY_TERMS)))
    """Cumulative energy terms [J], see ENERGY_TERMS."""

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
        return State(
            t=self.t, dt=self.dt, node_x=self.node_x.copy(), node_v=self.node_v.copy(),
            node_f=self.node_f.copy(), seg_alpha=self.seg_alpha.copy(), body=self.body.copy(),
            steps=self.steps, rejected=self.rejected, evaluations=self.evaluations,
            iterations=self.iterations, error=self.error, contact_count=self.contact_count,
            energy=self.energy.copy(),
        )
