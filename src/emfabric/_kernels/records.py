"""The named records the kernels take whole (NamedTuples: Numba compiles their fields by name).

A Model is a composition of these records (built by emfabric.sim.builder), a State's arrays are a
``StateArrays``; a kernel reads ``fld.B`` or ``body.radius``, never a loose positional scalar.
Adding a field to a record changes the kernels' signatures, so nothing else needs to change for
the compiled code to see it. Units are SI throughout.

Layouts (the only place they are defined):
- a fabric is a pack of plies, each a regular weave (a grid of nx_p × ny_p nodes, possibly
  rotated in its plane); ply p owns the nodes ``Nodes.ply_nodes[p]`` ≤ n < ``ply_nodes[p + 1]``,
  the grid rows ``Nodes.ply_rows[p]`` ≤ j < ``ply_rows[p + 1]`` and the segments
  ``Yarns.ply_segments[p]`` ≤ s < ``ply_segments[p + 1]``; one sheet is a pack of one ply;
- node arrays are component-major, shape (3, node_count): ``x[:, n]`` is node n. Row j of the
  pack (``Nodes.rows[j]``: ROW_NODE, ROW_COUNT, ROW_WARP, ROW_FILL) holds ROW_COUNT nodes from
  ROW_NODE on; in ply p, node ply_nodes[p] + j·nx_p + i sits at column i and row j of its grid;
- within a ply, segments are numbered warp first (s = s_p + j·(nx_p−1) + i joins nodes
  n_p + j·nx_p + i and n_p + j·nx_p + i + 1), then fill (s = s_p + warp_p + j·nx_p + i joins
  n_p + j·nx_p + i and n_p + (j + 1)·nx_p + i); a row's first warp and fill segment are
  ROW_WARP and ROW_FILL (−1 on the ply's last row); ``Yarns.ends`` holds the end nodes of every
  segment as data;
- the rigid body's state is one (BODY_ROWS, 3) array, rows BODY_X … BODY_M then the rotation
  matrix (body frame → inertial frame) in rows BODY_R0 … BODY_R0 + 2.
"""

from typing import NamedTuple

import numpy as np

BODY_X, BODY_V, BODY_W, BODY_F, BODY_M, BODY_R0 = 0, 1, 2, 3, 4, 5
"""Rows of the body state: position, velocity, angular velocity (inertial frame), non-impulsive
force and moment at the state's time, rotation matrix (three rows)."""
BODY_ROWS = 8

ENERGY_TERMS = ("work_field", "work_gravity", "dissipation_friction", "dissipation_contact",
                "dissipation_projection", "dissipation_damage", "dissipation_viscous")
"""The cumulative energy terms [J] of a State (State.energy) in their order: the only place it is
spelled; the kernels index them by the constants below."""
(ENERGY_WORK_FIELD, ENERGY_WORK_GRAVITY, ENERGY_FRICTION, ENERGY_CONTACT, ENERGY_PROJECTION,
 ENERGY_DAMAGE, ENERGY_VISCOUS) = range(len(ENERGY_TERMS))

HISTORY_VARIABLES = (
    ("dt", 1), ("iterations", 1), ("error", 1), ("rejected_steps", 1), ("force_evaluations", 1),
    ("projectile_position", 3), ("projectile_velocity", 3), ("angular_velocity", 3),
    ("projectile_nose", 3), ("tilt", 1), ("contact_nodes", 1), ("max_deflection", 1),
    ("max_stretch", 1), ("fabric_momentum", 3), ("fabric_angular_momentum", 3),
    ("projectile_momentum", 3), ("projectile_angular_momentum", 3),
    ("kinetic_energy_projectile", 1), ("kinetic_energy_projectile_rotation", 1),
    ("kinetic_energy_fabric", 1), ("strain_energy", 1), ("broken_yarns", 1), ("min_damage", 1),
    *((name, 1) for name in ENERGY_TERMS),
    ("energy_balance_error", 1), ("yaw", 1), ("contact_force", 3), ("field_B", 3),
    ("field_E", 3), ("contact_segments", 1),
)
"""The history record's variables and widths (3: an xyz vector), in the order of its columns
after the time (column 0): the one layout the record kernel (diagnostics.history_row) writes and
the recorder (emfabric.io.history) reads. The last three, the applied field at the projectile
and the segments in contact, are filled after the kernel by emfabric.sim.diagnostics (the field
sources' Python side; the integrator's count of its contact list)."""


def _history_columns() -> dict[str, int]:
    out, col = {}, 1
    for name, width in HISTORY_VARIABLES:
        out[name] = col
        col += width
    return out


HISTORY_COLUMN = _history_columns()
"""First column of each history variable."""
HISTORY_COLUMNS = 1 + sum(width for _name, width in HISTORY_VARIABLES)
"""Columns of a history record (time first)."""
COL_TIME = 0
COL_DT = HISTORY_COLUMN["dt"]
COL_ITERATIONS = HISTORY_COLUMN["iterations"]
COL_ERROR = HISTORY_COLUMN["error"]
COL_REJECTED = HISTORY_COLUMN["rejected_steps"]
COL_EVALUATIONS = HISTORY_COLUMN["force_evaluations"]
COL_POSITION = HISTORY_COLUMN["projectile_position"]
COL_VELOCITY = HISTORY_COLUMN["projectile_velocity"]
COL_OMEGA = HISTORY_COLUMN["angular_velocity"]
COL_NOSE = HISTORY_COLUMN["projectile_nose"]
COL_TILT = HISTORY_COLUMN["tilt"]
COL_CONTACTS = HISTORY_COLUMN["contact_nodes"]
COL_DEFLECTION = HISTORY_COLUMN["max_deflection"]
COL_STRETCH = HISTORY_COLUMN["max_stretch"]
COL_FABRIC_MOMENTUM = HISTORY_COLUMN["fabric_momentum"]
COL_FABRIC_ANGULAR = HISTORY_COLUMN["fabric_angular_momentum"]
COL_BODY_MOMENTUM = HISTORY_COLUMN["projectile_momentum"]
COL_BODY_ANGULAR = HISTORY_COLUMN["projectile_angular_momentum"]
COL_KE_BODY = HISTORY_COLUMN["kinetic_energy_projectile"]
COL_KE_BODY_ROTATION = HISTORY_COLUMN["kinetic_energy_projectile_rotation"]
COL_KE_FABRIC = HISTORY_COLUMN["kinetic_energy_fabric"]
COL_STRAIN = HISTORY_COLUMN["strain_energy"]
COL_BROKEN = HISTORY_COLUMN["broken_yarns"]
COL_MIN_DAMAGE = HISTORY_COLUMN["min_damage"]
COL_ENERGY_TERMS = HISTORY_COLUMN[ENERGY_TERMS[0]]
COL_BALANCE = HISTORY_COLUMN["energy_balance_error"]
COL_YAW = HISTORY_COLUMN["yaw"]
COL_CONTACT_FORCE = HISTORY_COLUMN["contact_force"]
COL_FIELD_B = HISTORY_COLUMN["field_B"]
COL_FIELD_E = HISTORY_COLUMN["field_E"]
COL_CONTACT_SEGMENTS = HISTORY_COLUMN["contact_segments"]

MATERIAL_KSV, MATERIAL_FUNG = 0, 1
DAMAGE_ZOHDI, DAMAGE_BRITTLE = 0, 1
REGION_UNIFORM, REGION_HALF_SPACE = 0, 1
SHAPE_SPHERE, SHAPE_OGIVE, SHAPE_CYLINDER, SHAPE_FSP = 0, 1, 2, 3


ROW_NODE, ROW_COUNT, ROW_WARP, ROW_FILL = 0, 1, 2, 3
"""Columns of Nodes.rows: a row's first node, its node count, its first warp segment, and its
first fill segment to the next row of its ply (−1 on a ply's last row)."""


class Nodes(NamedTuple):
    """The fabric's lumped masses: a pack of plies, each a grid of rows (the layout above)."""

    nx: int
    """The longest row's node count (the row buffers' width)."""
    ny: int
    """Rows of the whole pack (Σ ny_p)."""
    x0: np.ndarray
    """Reference positions [m], (3, node_count)."""
    mass: np.ndarray
    """Lumped mass [kg], (node_count,)."""
    inv_mass: np.ndarray
    """1/mass [1/kg], 0 for clamped nodes."""
    charge: np.ndarray
    """[C], (node_count,)."""
    rows: np.ndarray
    """(ny, 4) int64: ROW_NODE, ROW_COUNT, ROW_WARP, ROW_FILL of each row."""
    ply_nodes: np.ndarray
    """(plies + 1,) int64: ply p's nodes are ply_nodes[p] ≤ n < ply_nodes[p + 1]."""
    ply_rows: np.ndarray
    """(plies + 1,) int64: ply p's rows."""


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
    """Undeformed cross-section A0 [m²] of the first ply's first segment, a warp (each
    segment's is stiffness·L0/𝔼: fabric.rescale scales each family's with its own spacing)."""
    ply_segments: np.ndarray
    """(plies + 1,) int64: ply p's segments are ply_segments[p] ≤ s < ply_segments[p + 1]."""
    failure_stretch2: np.ndarray = np.zeros(0)
    """Material.damage_law = DAMAGE_BRITTLE: each segment's stretch² at break, (1 + ε_f)²,
    (seg_count,); unused (may be empty) with DAMAGE_ZOHDI."""
    damping: np.ndarray = np.zeros(0)
    """The axial (bulk) viscosity of each segment, η = q·√(stiffness·m̄) with q
    solver.bulk_viscosity and m̄ the mean mass of its end nodes [N s/m]: a taut segment carries
    the tension η·α·L̇ besides its elastic one (central differences; docs/theory.md §2.1).
    Empty: no viscosity (the kernels then leave it out)."""
    averaging_rate: np.ndarray = np.zeros(0)
    """Brittle yarns with fabric.damage.strain_averaging = n > 0: each segment's 1/τ with τ =
    n·√(m̄/stiffness) [1/s]; a segment breaks when its averaged stretch² ū², dū²/dt =
    (max(U², 1) − ū²)/τ (StateArrays.strain), passes failure_stretch2. Empty: the
    instantaneous U²."""


class Material(NamedTuple):
    """Yarn constitutive and damage law (emfabric._kernels.materials)."""

    kind: int
    """MATERIAL_KSV or MATERIAL_FUNG."""
    fung_h: float
    critical_stretch: float
    damage_rate: float
    broken_below: float
    """α below which a yarn counts as broken (diagnostics only)."""
    damage_law: int = DAMAGE_ZOHDI
    """DAMAGE_ZOHDI (eq. 2.6 with critical_stretch and damage_rate) or DAMAGE_BRITTLE (α = 0
    past Yarns.failure_stretch2)."""


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
    loops: np.ndarray | None = None
    """Current loops (coils are sums of loops), (loop_count, 8): centre [m], unit normal (the
    current circulates right-handed about it), radius [m], wire radius [m]; None without loops
    (then Numba compiles the loop sum away)."""
    currents: np.ndarray = np.zeros((0, 6))
    """Each loop's current waveform, (loop_count, 6): kind (coils.WAVE_*), amplitude = current ×
    turns [A], start_time, rise_time [s], frequency [Hz], decay_time [s]."""
    tables: np.ndarray = np.zeros((0, 1, 2))
    """Waveform tables (t [s], I [A]) per loop, padded, (loop_count, points, 2)."""
    table_len: np.ndarray = np.zeros(0, dtype=np.int64)
    """Points used in each loop's table."""
    map_axes: np.ndarray | None = None
    """A field map's grid: x, y, z coordinates [m], padded, (3, points); None without a map
    (then Numba compiles the map lookup away)."""
    map_size: np.ndarray = np.zeros(3, dtype=np.int64)
    """Points of the map along x, y, z."""
    map_step: np.ndarray = np.zeros(3)
    """The spacing of each evenly spaced map axis [m], 0 for an uneven one."""
    map_values: np.ndarray = np.zeros((1, 1, 1, 6))
    """The map's E [V/m] and B [T] at the grid points, (nx, ny, nz, 6): Ex Ey Ez Bx By Bz."""
    map_has_e: bool = False
    """Whether the map holds a non-zero E anywhere."""
    grid_values: np.ndarray | None = None
    """The source grid (emfabric.sources.grid): per group of sources with one waveform, the
    field per unit of the waveform at the grid points, (groups, nz + 1, ny + 1, nx + 1, 6):
    b [T] and the vector potential a [T m] (the induced E is −(dw/dt) a); None without a grid
    (then Numba compiles the lookup away)."""
    grid_origin: np.ndarray = np.zeros(3)
    """The grid's first point [m]."""
    grid_step: np.ndarray = np.ones(3)
    """The grid's spacing along x, y, z [m]."""
    grid_cells: np.ndarray = np.zeros(3, dtype=np.int64)
    """Cells along x, y, z."""
    grid_exact: np.ndarray = np.zeros((1, 1, 1), dtype=np.uint8)
    """1 for a cell where interpolating the loops misses the tolerance (near a wire): the
    loops are evaluated exactly there, (nz, ny, nx)."""
    grid_wave: np.ndarray = np.zeros(0, dtype=np.int64)
    """Per group: the loop whose waveform (currents, tables) the group follows; −1 for the
    permanent magnets (constant, no induced E)."""
    grid_loops: bool = False
    """Whether the loops are in the grid (else evaluated exactly everywhere)."""
    magnets: np.ndarray = np.zeros((0, 13))
    """Permanent magnets, (count, 13): shape (0 cuboid, 1 cylinder), polarization [T] (3),
    dimension [m] (3: a b c, or d h 0), position [m] (3), rotation vector [rad] (3). Their
    field reaches the kernels through the source grid only (magpylib computes it there)."""


class Body(NamedTuple):
    """The rigid projectile: shape (emfabric._kernels.shapes), inertia, charges."""

    active: bool
    """False when the scenario has no projectile."""
    shape: int
    """SHAPE_SPHERE, SHAPE_OGIVE, SHAPE_CYLINDER or SHAPE_FSP."""
    radius: float
    """Sphere radius, or the body radius (calibre/2) of the other shapes [m]."""
    mass: float
    inertia: np.ndarray
    """Inertia about the centre of mass in the body frame [kg m²], (3, 3)."""
    charge_pos: np.ndarray
    """Charged points relative to the centre of mass, body frame [m], (charge_count, 3)."""
    charge: np.ndarray
    """[C], (charge_count,)."""
    nose: np.ndarray
    """Tilt and yaw marker relative to the centre of mass, body frame [m], (3,)."""
    length: float = 0.0
    """Overall length L [m] (not the sphere)."""
    nose_length: float = 0.0
    """Ogive nose length L_n [m]."""
    base: float = 0.0
    """Height of the centre of mass above the base face along the axis [m]."""
    arc_radius: float = 0.0
    """Ogive arc radius ϱ = (R² + L_n²)/(2R) [m]."""
    flat_half_width: float = 0.0
    """FSP: half the width of the flat between the chisel faces [m]."""
    bevel_cos: float = 1.0
    """FSP: cos β, β the angle between a chisel face and the axis."""
    bevel_sin: float = 0.0
    frame: np.ndarray = np.eye(3)
    """Rows e1, e2, e3 (e3: the nose axis) of the shape's frame in the body frame, (3, 3)."""
    bound: float = 0.0
    """Bounding radius about the centre of mass [m] (not the sphere)."""


class Contact(NamedTuple):
    """Stick/slip contact law (emfabric._kernels.contact.contact_impulse)."""

    static_friction: float
    dynamic_friction: float
    segments: bool = False
    """Also resolve contact of the yarn segments (not only the nodes) against the body."""
    follow: bool = True
    """Put a node in contact where the φ-update with its velocity after contact takes it (else
    at the closest point of its position before contact, the paper as printed)."""
    ply_gap: np.ndarray = np.zeros(0)
    """Ply-to-ply contact (emfabric._kernels.plies): the distance [m] below which the mid-planes
    of plies p and p + 1 are in contact (the sum of their yarn radii), (plies − 1,)."""
    ply_reach: np.ndarray = np.zeros(0)
    """The in-plane radius ρ [m] of a node's share of its ply's surface, (plies,)."""
    ply_box: np.ndarray = np.zeros((0, 2), dtype=np.int64)
    """The half-widths (columns, rows) of the box of a ply's grid around its node nearest to a
    node of the other ply that holds every node within ply_reach, (plies, 2) int64."""
    ply_guess: np.ndarray = np.zeros((2, 0), dtype=np.int64)
    """For each node, its nearest node in the reference state of the ply above (row 0) and of
    the ply below (row 1), −1 where there is none, (2, node_count) int64: where the walk to the
    nearest node starts (a state-free start: a restarted run walks the same way)."""
    ply_quantum: np.ndarray = np.ones(3)
    """The units [N s], [kg m] and [N] in which ply contact sums impulses, mass-weighted
    placements and (the φ-scheme's) forces exactly (integers: the sum does not depend on the
    order), (3,)."""
    ply_stiffness: np.ndarray = np.zeros(0)
    """The φ-scheme's ply contact (plies.ply_forces): the normal stiffness [N/m] of a node's
    whole share against the neighbouring ply, per pair of plies p, p + 1, (plies − 1,)."""


class Solver(NamedTuple):
    """What one attempted step needs of the solver settings."""

    phi: float
    """φ of the φ-scheme."""
    tolerance: float
    iteration_limit: int
    """Fixed-point iterations per attempt."""
    predict: bool
    """Start the iteration from the explicit prediction x0 + Δt v0 + φΔt² ψ(t)/m (else from x0,
    the paper's initial iterate)."""


class StepStats(NamedTuple):
    """What a history record says about the step that led to a state."""

    t: float
    """Time [s]."""
    dt: float
    """The step just taken [s]."""
    iterations: int
    error: float
    """ϖ at acceptance."""
    rejected: int
    """Rejected attempts so far."""
    evaluations: int
    """Force evaluations so far."""
    contacts: int
    """Contacts after the step."""


class RowRecords(NamedTuple):
    """What the row kernels of emfabric._kernels.nodes read (Physics's first four records):
    built inside compiled code, one type for the serial and the threaded kernels (a parallel
    loop cannot take the nested Physics record as an argument)."""

    nodes: Nodes
    yarns: Yarns
    material: Material
    field: Field


def row_records(phys) -> RowRecords:
    """The RowRecords of a Physics record, built in Python with the types compiled code gives
    it (for a row-block kernel called from Python or compiled ahead: sim.state.update_forces,
    the integrators' precompile_targets)."""
    return RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)


class RowArrays(NamedTuple):
    """The arrays the per-row force (nodes._row_force) reads, built once per row block: a
    function bound to a record references and releases every array in it (atomic operations),
    so the per-row code gets these and not Physics's records (nodes._rotate_row)."""

    rows: np.ndarray
    """Nodes.rows."""
    mass: np.ndarray
    charge: np.ndarray
    inv_rest2: np.ndarray
    """Yarns.inv_rest2."""
    rest_length: np.ndarray
    """Yarns.rest_length."""
    stiffness: np.ndarray
    alpha: np.ndarray
    """The committed α (the step's start state)."""
    alpha_trial: np.ndarray
    """The trial α written by the evaluation."""
    damage_thr: np.ndarray
    """Work.damage_thr."""
    node_field: np.ndarray
    """Work.node_field."""
    damping: np.ndarray
    """Yarns.damping (empty: no viscosity)."""
    base: np.ndarray
    """The node positions at the step's start (the viscous tension's rate, (x − base)/Δt)."""
    strain: np.ndarray
    """The committed averaged stretch² (StateArrays.strain; empty: not averaged)."""
    strain_trial: np.ndarray
    """The trial averaged stretch² written by the evaluation."""
    averaging_rate: np.ndarray
    """Yarns.averaging_rate."""
    dt: float
    """The step Δt [s] (the averaged stretch's update; 0: none)."""


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
    e: np.ndarray = np.zeros((3, 0))
    """The electric field in each node's force f [V/m], (3, node_count)."""
    contact: np.ndarray = np.zeros((4, 0))
    """Each node's contact at the state's time (central differences), (4, node_count): rows
    0–2 the body-frame point it sticks to [m], row 3 its mode (0 none, contact.STICK,
    contact.SLIDE)."""
    fv: np.ndarray = np.zeros((3, 0))
    """The viscous part of f (central differences with bulk viscosity: Yarns.damping), (3,
    node_count), for the energy bookkeeping of the next half kick; (3, 0) without viscosity."""
    strain: np.ndarray = np.zeros(0)
    """Each segment's averaged stretch² ū² (Yarns.averaging_rate), (seg_count,); (0,) where
    brittle yarns break on the instantaneous stretch or the law is eq. 2.6."""
    seg_contact: np.ndarray = np.zeros(0)
    """Each segment's contact mode with the body at the state's time (central differences
    with segment contact: 0 none, contact.STICK, contact.SLIDE), (seg_count,); (0,) for the
    φ-scheme or without segment contact."""


# the fabric diagnostics of a state (diagnostics.fabric_diagnostics), in this order: kinetic
# energy, momentum, angular momentum about the origin, max |Δz|, max stretch, strain energy,
# broken yarns, min α, the nodes' extent along the flight direction from the body centre, the
# fastest node speeds against and along it
(DIAG_KE, DIAG_PX, DIAG_PY, DIAG_PZ, DIAG_LX, DIAG_LY, DIAG_LZ, DIAG_DEFLECTION, DIAG_STRETCH,
 DIAG_STRAIN, DIAG_BROKEN, DIAG_MIN_ALPHA, DIAG_AHEAD_MIN, DIAG_AHEAD_MAX, DIAG_APPROACH_MAX,
 DIAG_RECEDE_MAX) = range(16)
DIAG_COUNT = 16

# rows of Work.row_sums, one value per grid row, summed in a fixed order by the step kernels
SUM_ERROR_NUM = 0
"""φ-scheme: Σ |x_K − x_{K−1}| of the row's nodes out of contact (eq. 3.10)."""
SUM_ERROR_DEN = 1
"""φ-scheme: Σ |x_K − x_n|."""
SUM_WORK_FIELD = 2
"""Central differences: the electric field's work of a half kick [J]."""
SUM_WORK_GRAVITY = 3
"""Central differences: gravity's work of a half kick [J]."""
SUM_PROJECTION = 4
"""Central differences: the force's work over the contact placement [J]."""
SUM_SPEED = 5
"""Central differences: Σ |v|² [m²/s²] (finite unless the step blew up)."""
SUM_STIFFNESS = 6
"""Central differences: the largest ω² of the row's nodes [s⁻²] that the step must resolve:
2 Σ k_t/m (Gershgorin) or (2 ω_c/GYRATION_TURN)², ω_c = |q B|/m its cyclotron frequency."""
GYRATION_TURN = 0.1
"""[rad] Central differences turn a charged node about B by at most courant × this a step:
Δt ≤ courant · GYRATION_TURN/ω_c (as courant · 2/ω with ω = 2 ω_c/GYRATION_TURN). The spin
error that the field adds to contact is first order, about 0.4 ω_cΔt of the peak spin (a
charged sheet in 1 and 5 T, docs/theory.md §4.1): at the default courant 0.25, 0.025 rad a step
keeps it near 1 %."""
SUM_DIAG = 7
"""Central differences: the row's share of the fabric diagnostics of the step's end state,
DIAG_COUNT rows in the order of diagnostics.fabric_diagnostics's results (sums, or the
largest or smallest value; the stretch row holds U²: its row of the warp segments and of the
fill segments to the next row), reduced by diagnostics.fabric_from_rows."""
SUM_MOTION = SUM_DIAG + DIAG_COUNT
"""Central differences: the row's largest |v|², then the smallest and the largest of each
velocity component (7 rows; the no-tunnelling limit's, contact.travel_limit)."""
MOTION_COUNT = 7
SUM_WORK_VISCOUS = SUM_MOTION + MOTION_COUNT
"""Central differences with bulk viscosity: the work of the viscous yarn forces in the row's
half kick (h/2 f_v·v̄)."""
SUM_ROWS = SUM_WORK_VISCOUS + 1


class Work(NamedTuple):
    """Scratch arrays of one attempted step."""

    xbuf: np.ndarray
    """Second iterate buffer, (3, node_count)."""
    row_sums: np.ndarray
    """Per-row sums of the node kernels, (SUM_ROWS, ny): rows SUM_* (the φ-scheme's error terms,
    central differences' work, projection, speed and stiffness bound)."""
    err_num: np.ndarray
    err_den: np.ndarray
    cand: np.ndarray
    """Contact candidates (node indices); their count in counts[0]."""
    flag: np.ndarray
    """Per node (uint8): 0 not a contact candidate, 1 a candidate not in contact, contact.STICK
    or contact.SLIDE for one in contact at the latest iterate. The node kernel leaves every
    non-zero node out of the fabric's error measure (candidates are measured after contact)."""
    seg_cand: np.ndarray
    """Candidate segments for segment contact; their count in counts[1]."""
    seg_active: np.ndarray
    """1 for a candidate segment in contact earlier in this step (int8, by candidate index)."""
    seg_slot: np.ndarray
    """The contact record of each candidate segment in the current iterate, −1 for none."""
    seg_tmp: np.ndarray
    """One segment-contact pass: impulse, move to the surface and weight, (7, seg_count)."""
    seg_list: np.ndarray
    """The candidate indices of the segments in contact in segment_contact's first pass, in
    candidate order (the later passes revisit only these)."""
    counts: np.ndarray
    """[candidate nodes, candidate segments] of the current attempt (int64)."""
    v_pre: np.ndarray
    """Candidates' velocity before contact [m/s], (3, node_count)."""
    share: np.ndarray
    """Penetration depths of the segment contacts at each node by yarn family, (2, node_count)."""
    acc: np.ndarray
    """Per-node corrections of segment contact by yarn family (warp, fill): position [m] and
    velocity [m/s], (2, 2, 3, node_count)."""
    c_node: np.ndarray
    """Per contact: its node, or the first end of its segment."""
    c_node2: np.ndarray
    """Per contact: the second end of its segment, −1 for a node contact."""
    c_w: np.ndarray
    """Per contact: the weights of its (one or two) nodes in the contact point, (2, contacts)."""
    c_imp: np.ndarray
    """Contact impulse on the fabric [N s], (3, contacts)."""
    c_arm: np.ndarray
    """Contact point relative to the body centre [m]."""
    c_nrm: np.ndarray
    """Outward surface normal at the contact point."""
    node_field: np.ndarray
    """The field of the sources at each node for the attempt (fields.fill_node_fields), (6, N):
    Ex Ey Ez Bx By Bz."""
    sum_buf: np.ndarray
    reaction: np.ndarray
    """Total contact + friction impulse on the body [N s] and its moment about the centre of
    mass [N m s] of the last iterate, (2, 3)."""
    damage_thr: np.ndarray
    """Per yarn segment, the stretch² U² above which the damage law can lower its committed α
    (materials.damage_thresholds, brought up to date at the start of each attempt); 0: evaluate
    it always."""
    damage_alpha: np.ndarray
    """The α each damage_thr was computed for (NaN: not yet)."""
    body_scratch: np.ndarray
    """The body update's workspace, (7, 3): rows 0–2 the rotation increment, rows 3–6 the
    inertia solve (vec3.solve3)."""
    ply_acc: np.ndarray
    """Ply contact's exact sums per node (int64, in Contact.ply_quantum units): the impulse
    and the mass-weighted placement, (2, 3, node_count)."""
    ply_force: np.ndarray
    """The φ-scheme's ply contact force on each node at the current iterate [N], (3,
    node_count); (3, 1) for one ply."""
    ply_force0: np.ndarray
    """The same at the start of the step (the energy bookkeeping's), (3, node_count)."""
    ply_normals: np.ndarray
    """Every ply's surface normal at its nodes (plies._normals), (3, node_count)."""
    ply_near: np.ndarray
    """Central differences' ply contact: each node's nearest node of the ply above (row 0) and
    below (row 1), as Contact.ply_guess's rows, as the step's first sweep found it
    (plies._pass), (2, node_count) int64; (2, 1) for one ply."""
    frame: np.ndarray
    """The fabric diagnostics' frame, (2, 3): the body centre at the end of the step (zeros
    without a body) and the flight direction (set by the integrator)."""
    diag: np.ndarray
    """Central differences: the fabric diagnostics of the last attempt's end state,
    (DIAG_COUNT,) in diagnostics.fabric_diagnostics's order."""
    ply_memo: np.ndarray
    """Central differences' ply contact, for the sweeps of impulses alone (whose positions do
    not change): each node's shares w and gaps g of the master nodes around it, their total and
    whether one acts, as plies._pass found them, against the ply above (0) and below (1),
    (2, node_count, 2·box + 2) for the largest box of master nodes; (2, 1, 1) for one ply.
    Kept for every node: under pack-field's sphere those sweeps meet all of them within the
    first 100 µs (all the rows of its 4 plies' nodes in one step)."""
    ply_stamp: np.ndarray
    """The ply_contact call (ply_epoch) whose sweeps of impulses alone wrote each node's
    ply_memo, −1 for none, (2, node_count) int64."""
    ply_epoch: np.ndarray
    """ply_contact's call count, (1,) int64."""
    ply_sum: np.ndarray
    """Central differences' ply contact: the impulse each pair of a node and a master node
    has had so far in the step's sweeps, by the master node's position in the node's box
    (3 components each), against the ply above (0) and below (1), (2, node_count, 3·box) for
    the largest box; (2, 1, 1) for one ply. The sweeps cut this sum to the Coulomb cone
    (plies._pass)."""
    ply_sum_at: np.ndarray
    """The master node each node's ply_sum box is centred on (its nearest when the sum was
    last written), (2, node_count) int64."""
    ply_sum_stamp: np.ndarray
    """The ply_contact call (ply_epoch) whose sweeps wrote each node's ply_sum, −1 for none,
    (2, node_count) int64."""
    ply_start: np.ndarray
    """Where the step put each node before ply contact (plies.ply_contact), against which it
    bounds the node's placements (plies.PLY_PLACEMENT_LIMIT), (3, node_count) ((3, 1) for one
    ply)."""
    visc_base: np.ndarray
    """Central differences with the yarns' bulk viscosity: the positions the viscous rate of
    the kick is taken from, (3, node_count) ((3, 1) without viscosity): the step's start x_n,
    and for a node that contact placed, x_{n+1} − Δt v⁺ with v⁺ its velocity after the
    contact impulses (explicit.central_step): a placement is not a motion of the yarn, and
    taken as one over a step it made a rate of δ/Δt (docs/theory.md §2.1)."""


def ply_box_size(ply_box: np.ndarray) -> int:
    """The most master nodes a node meets in ply contact: the largest (2 i + 1)(2 j + 1) of
    Contact.ply_box's rows (1 without plies)."""
    if ply_box.shape[0] == 0:
        return 1
    return int(((2 * ply_box[:, 0] + 1) * (2 * ply_box[:, 1] + 1)).max())


def pack_tables(grids) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The layout tables of a pack of plies whose grids are `grids` [(nx_p, ny_p), ...] in
    order: (Nodes.rows, Nodes.ply_nodes, Nodes.ply_rows, Yarns.ply_segments)."""
    rows = []
    ply_nodes, ply_rows, ply_segments = [0], [0], [0]
    for nx, ny in grids:
        n0, s0 = ply_nodes[-1], ply_segments[-1]
        warp = ny * (nx - 1)
        for j in range(ny):
            rows.append((n0 + j * nx, nx, s0 + j * (nx - 1),
                         s0 + warp + j * nx if j < ny - 1 else -1))
        ply_nodes.append(n0 + nx * ny)
        ply_rows.append(ply_rows[-1] + ny)
        ply_segments.append(s0 + warp + nx * (ny - 1))
    return (np.array(rows, dtype=np.int64).reshape(-1, 4), np.array(ply_nodes, dtype=np.int64),
            np.array(ply_rows, dtype=np.int64), np.array(ply_segments, dtype=np.int64))


def grid_nodes(nx: int, ny: int, x0, mass, inv_mass, charge) -> Nodes:
    """The Nodes record of one nx × ny sheet (a pack of one ply)."""
    rows, ply_nodes, ply_rows, _ = pack_tables([(nx, ny)])
    return Nodes(nx, ny, x0, mass, inv_mass, charge, rows, ply_nodes, ply_rows)


def make_work(node_count: int, row_count: int, seg_total: int, seg_count: int = 0,
              plies: int = 1, ply_box: int = 1, viscous: bool = False) -> Work:
    """The workspace of a step: node_count nodes in row_count grid rows, seg_total yarn
    segments; seg_count: the segments segment contact may touch (0 without segment contact:
    its arrays are then one element long); plies: 1 leaves ply contact's arrays one node long;
    ply_box: the most master nodes a node meets in ply contact (Contact.ply_box's largest
    (2 i + 1)(2 j + 1), ply_box_size), which sizes ply_memo and ply_sum: central
    differences' (the φ-scheme's passes keep neither, and leave it at 1); viscous: the yarns
    have a bulk viscosity (Work.visc_base is then one column per node)."""
    n = node_count
    ny = row_count
    nmax = n + seg_count
    ns = n if seg_count else 1
    return Work(np.empty((3, n)), np.empty((SUM_ROWS, ny)), np.empty(n), np.empty(n),
                np.empty(n, dtype=np.int64), np.zeros(n, dtype=np.uint8),
                np.empty(max(seg_count, 1), dtype=np.int64),
                np.zeros(max(seg_count, 1), dtype=np.int8),
                np.empty(max(seg_count, 1), dtype=np.int64), np.zeros((7, max(seg_count, 1))),
                np.empty(max(seg_count, 1), dtype=np.int64),
                np.zeros(2, dtype=np.int64),
                np.empty((3, n)), np.zeros((2, ns)), np.zeros((2, 2, 3, ns)),
                np.empty(nmax, dtype=np.int64), np.empty(nmax, dtype=np.int64),
                np.empty((2, nmax)), np.empty((3, nmax)), np.empty((3, nmax)),
                np.empty((3, nmax)), np.zeros((6, n)), np.empty(nmax), np.zeros((2, 3)),
                np.zeros(seg_total), np.full(seg_total, np.nan), np.zeros((7, 3)),
                np.zeros((2, 3, n if plies > 1 else 1), dtype=np.int64),
                np.zeros((3, n if plies > 1 else 1)), np.zeros((3, n if plies > 1 else 1)),
                np.zeros((3, n if plies > 1 else 1)),
                np.full((2, n if plies > 1 else 1), -1, dtype=np.int64), np.zeros((2, 3)),
                np.zeros(DIAG_COUNT),
                np.zeros((2, n if plies > 1 else 1, 2 * ply_box + 2 if plies > 1 else 1)),
                np.full((2, n if plies > 1 else 1), -1, dtype=np.int64),
                np.zeros(1, dtype=np.int64),
                np.zeros((2, n if plies > 1 else 1, 3 * ply_box if plies > 1 else 1)),
                np.full((2, n if plies > 1 else 1), -1, dtype=np.int64),
                np.full((2, n if plies > 1 else 1), -1, dtype=np.int64),
                np.zeros((3, n if plies > 1 else 1)), np.zeros((3, n if viscous else 1)))
