"""Model: everything a step only reads.

A Model is a composition of named records (emfabric._kernels.records: nodes, yarns, material,
field, body, contact; the kernels take the ``physics`` record whole) and one resolved
``Options`` record (the numerical settings the integrator and the run loop read). The scenario
it was built from rides along for the output files' provenance and for resuming; no numerical
code reads it. Models come from emfabric.sim.builder.build_model; States (emfabric.sim.state)
from initial_state or a checkpoint.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from emfabric._kernels.records import (
    Body,
    Contact,
    Field,
    Material,
    Nodes,
    Physics,
    Yarns,
)
from emfabric.config.scenario import Scenario
from emfabric.sim.geometry import ShapeGeometry


@dataclass(frozen=True)
class Options:
    """The numerical settings of a run, resolved from the scenario's [solver] and [output]."""

    phi: float = 0.5
    """φ of the φ-scheme."""
    tolerance: float = 1e-6
    """Fixed-point tolerance on ϖ (eq. 3.10)."""
    target_iterations: int = 6
    """K_d of eq. 3.9."""
    max_iterations: int = 200
    """Iteration limit per step at fixed Δt (adaptive = False)."""
    adaptive: bool = True
    exponent: float = 2.0
    """p of eq. 3.9."""
    safety: float = 0.9
    """Factor on Φ_K of eq. 3.9."""
    dt_max: float = 1e-6
    """[s]"""
    dt_min: float = 1e-13
    """[s]"""
    dt_initial: float = 1e-6
    """First Δt tried [s]."""
    scheme: str = "fixed-point"
    """"fixed-point" or "anderson"."""
    anderson_depth: int = 5
    predictor: str = "start"
    """"start" or "explicit"."""
    end_time: float = 1.5e-3
    """[s]"""
    snapshot_interval: float = 10e-6
    """[s]"""
    checkpoint_seconds: float = 5.0
    """Wall time between checkpoints [s]."""
    integrator: str = "central-difference"
    """"central-difference" (the default, as a scenario's) or "phi"."""
    courant: float = 0.25
    """central-difference: fraction of the stable step taken (the scenario's default)."""
    bulk_viscosity: float = 0.0
    """central-difference: the yarns' bulk viscosity q (Scenario.bulk_viscosity; the kernels
    read Yarns.damping)."""

    @classmethod
    def of(cls, scenario: Scenario) -> Options:
        """The options of a validated scenario."""
        s, o = scenario.solver, scenario.output
        return cls(float(s.phi), float(s.tolerance), int(s.target_iterations),
                   int(s.max_iterations), bool(s.adaptive), float(s.exponent), float(s.safety),
                   float(s.dt_max), float(s.dt_min), float(s.dt_initial or s.dt_max), s.scheme,
                   int(s.anderson_depth), s.predictor, float(s.end_time),
                   float(o.snapshot_interval), float(o.checkpoint_seconds), s.integrator,
                   float(s.courant), scenario.bulk_viscosity)


@dataclass(frozen=True, eq=False)
class Model:
    """Everything a step only reads: the kernels' records, the numerical options, the
    projectile's initial pose, and the scenario it was built from (provenance only)."""

    physics: Physics
    """The records the kernels take (nodes, yarns, material, field, body, contact)."""
    options: Options
    """The numerical settings (integrator, end time, output intervals)."""
    geometry: ShapeGeometry = dataclasses.field(repr=False)
    """The projectile's shape and dimensions (volume, inertia, surface mesh)."""
    flight_direction: np.ndarray = dataclasses.field(repr=False)
    """Unit vector of the projectile's initial velocity (−z if it starts at rest)."""
    body_x0: np.ndarray = dataclasses.field(repr=False)
    """Initial centre of mass [m]."""
    body_v0: np.ndarray = dataclasses.field(repr=False)
    body_w0: np.ndarray = dataclasses.field(repr=False)
    node_v0: np.ndarray = dataclasses.field(repr=False)
    """Initial node velocities [m/s], (3, node_count)."""
    projectile_shape: str = "sphere"
    """The scenario's projectile.shape ("none" without a body)."""
    scenario: Scenario | None = dataclasses.field(default=None, repr=False)
    """The scenario it was built from (history and checkpoint attributes, resume); None for a
    Model put together in Python."""

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
        """The longest grid row's node count (the row buffers' width)."""
        return self.nodes.nx

    @property
    def ny(self) -> int:
        """Grid rows of the whole pack."""
        return self.nodes.ny

    @property
    def node_count(self) -> int:
        return int(self.nodes.x0.shape[1])

    @property
    def ply_count(self) -> int:
        return int(self.nodes.ply_nodes.shape[0] - 1)

    def ply_grid(self, ply: int) -> tuple[int, int]:
        """(nx, ny) of ply `ply`'s grid."""
        j0, j1 = int(self.nodes.ply_rows[ply]), int(self.nodes.ply_rows[ply + 1])
        return int(self.nodes.rows[j0, 1]), j1 - j0

    def node_ply(self) -> np.ndarray:
        """The ply of each node, (node_count,) int32."""
        return np.repeat(np.arange(self.ply_count, dtype=np.int32),
                         np.diff(self.nodes.ply_nodes))

    def segment_ply(self) -> np.ndarray:
        """The ply of each yarn segment, (seg_count,) int32."""
        return np.repeat(np.arange(self.ply_count, dtype=np.int32),
                         np.diff(self.yarns.ply_segments))

    @property
    def seg_count(self) -> int:
        return self.yarns.ends.shape[0]

    @property
    def has_body(self) -> bool:
        return bool(self.body.active)
