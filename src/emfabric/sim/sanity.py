"""Is this run what the user meant? Checks on a built model before it runs (issue 25).

Two kinds, both from numbers the scenario gives:

- **Warnings** (`pre_run_warnings`): a scenario that can run but is probably a typing mistake —
  a projectile larger than the sheet, a path that misses the sheet or leads away from it, a
  sheet, projectile or mass far outside anything ballistic (mm or g typed as m or kg), a
  projectile that falls between the nodes, a solver key the chosen integrator does not read.
  Each says what was found and the likely fix. They
  are warnings, not errors: a 1000 kg body standing in for a constant-speed driver, or a shot
  fired away on purpose, are legitimate experiments.
- **The output volume** (`output_volume`, `check_output_volume`): snapshots × (nodes and
  segments), plus the ParaView files; a run that would write more than `output.size_limit`
  bytes is refused before it starts (raise the limit to ask for it).

`build_model` logs the warnings and applies the volume check, so `emfabric validate`, `run` and
every study case see them; the volume check only where the run writes its files
(`build_model(..., writes=False)` for a run kept in memory: `emfabric.run(scenario)` with no
folder, a study case that keeps no files).
"""

from __future__ import annotations

import math

import numpy as np

BALLISTIC_MASS = (1e-4, 10.0)
"""Projectile masses [kg] we do not warn about: a 0.1 g fragment to a 10 kg body."""
BALLISTIC_SIZE = (2e-4, 0.5)
"""Projectile radii [m] we do not warn about."""
PROJECTILE_DENSITY = (10.0, 23000.0)
"""A projectile's mean density [kg/m³] we do not warn about: a rigid foam to osmium (22 590),
denser than any penetrator (tungsten alloys ~18 000)."""
SHEET_SIZE = (1e-3, 5.0)
"""Sheet sides [m] we do not warn about."""
BALLISTIC_SPEED = (1.0, 5000.0)
"""Striking speeds [m/s] we do not warn about."""
FABRIC_AREAL_DENSITY = (1e-3, 100.0)
"""Areal densities of one ply [kg/m²] we do not warn about (the paper's sheet 0.128, a KM2
weave 0.18)."""
YARN_WAVE_SPEED = (10.0, 1e5)
"""Longitudinal wave speeds of the yarn network [m/s] we do not warn about (7.7 km/s on the
paper's sheet; aramid and UHMWPE fibres 8–12 km/s)."""

YARN_MASS_SHARE = (0.95, 1.5)
"""Areal density over the mass of the straight yarns alone (linear density × thread count) we do
not warn about: crimp adds a few to 25 % (the library's styles); lighter than its own yarns, or
half again heavier, is a unit slip (denier as tex, ends per inch as per cm)."""
FAILURE_STRAIN_MAX = 0.3
"""Brittle failure strains [-] above this are warned about: fibres break at 0.5–10 % (a
percentage typed as a fraction: 3.5 for 3.5 %)."""
TENSILE_STRENGTH = (1e7, 1e11)
"""Yarn tensile strengths [Pa] we do not warn about (aramid and UHMWPE 2.5–4 GPa)."""

SNAPSHOT_BYTES_PER_NODE = 6 * 8
"""snapshots.nc per node and snapshot: position and velocity (6 doubles) [B]."""
SNAPSHOT_BYTES_PER_SEGMENT = 8
"""snapshots.nc per yarn segment and snapshot: its damage [B]."""
VTU_BYTES_PER_NODE = 112
"""A fabric .vtu per node and snapshot (measured: a 100 × 100 sheet writes 1.1 MB per
snapshot; points, velocity, displacement, ply, index and two line cells per node) [B]."""


def _unit_hint(value: float, unit: str, small: str, factor: float) -> str:
    """"did you type mm as m? (26.35 mm = 0.02635 m)"."""
    return (f"did you type {small} as {unit}? ({value:g} {small} = {value * factor:g} {unit})")


def _fabric_warnings(model, from_scenario: bool) -> list[str]:
    """Each ply's areal density and its yarns' longitudinal wave speed L0·√(k/m) (its lightest
    free node), outside anything woven: a mass or a stiffness typed in the wrong unit, or far
    enough out of range that the stable step is nil. Per ply, so one mistyped ply of a pack is
    not averaged away."""
    from emfabric.sim.diagnostics import wave_speed

    out: list[str] = []
    nodes, yarns = model.nodes, model.yarns
    if not from_scenario:
        return out
    plies = model.ply_count
    lo_d, hi_d = FABRIC_AREAL_DENSITY
    lo_c, hi_c = YARN_WAVE_SPEED
    for p in range(plies):
        a, b = int(nodes.ply_nodes[p]), int(nodes.ply_nodes[p + 1])
        s0, s1 = int(yarns.ply_segments[p]), int(yarns.ply_segments[p + 1])
        mass = nodes.mass[a:b]
        live = mass > 0
        free = nodes.inv_mass[a:b] > 0
        if not live.any() or not free.any() or s1 <= s0:
            continue
        x0 = nodes.x0[:2, a:b][:, live]
        area = float(np.prod(x0.max(axis=1) - x0.min(axis=1)))
        which = f"ply {p + 1}'s" if plies > 1 else "the fabric's"
        key = f"fabric.ply[{p}].areal_density or fabric.areal_density" if plies > 1 else \
            "fabric.areal_density"
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            density = float(mass.sum()) / area if area > 0.0 else math.inf
        wave = wave_speed(yarns.rest_length[s0:s1], yarns.stiffness[s0:s1],
                          float(mass[free].min()))
        if area > 0.0 and not lo_d <= density <= hi_d:
            out.append(f"{which} areal density is {density:.4g} kg/m², far outside woven "
                       f"fabrics ({lo_d:g}–{hi_d:g} kg/m² a ply): check {key} (or the yarns' "
                       f"linear density, thread count and fibre density)")
        if not lo_c <= wave <= hi_c:
            out.append(f"{which} yarns' longitudinal wave speed is {wave:.4g} m/s, far outside "
                       f"fibres ({lo_c:g}–{hi_c:g} m/s; aramid and UHMWPE 8–12 km/s): check "
                       f"the material's modulus and the fabric's mass ({key}); the explicit "
                       f"step shrinks as 1/speed")
    return out


def _datasheet_warnings(sc) -> list[str]:
    """Each ply's areal density against the mass of its straight yarns (tex × ends and picks),
    its brittle failure strain and its yarn strength, where a unit slip is likely
    (YARN_MASS_SHARE, FAILURE_STRAIN_MAX, TENSILE_STRENGTH)."""
    from emfabric.config.scenario import straight_yarn_mass

    out: list[str] = []
    fab = sc.fabric
    plies = fab.plies
    # without per-ply tables every ply is the fabric: one warning, not one per ply
    for p in range(plies if fab.ply else 1):
        ply = fab.ply_fabric(p) if fab.ply else fab
        at = f"fabric.ply[{p}]." if fab.ply else "fabric."
        which = (f"ply {p + 1}" if fab.ply and plies > 1 else
                 "each ply" if plies > 1 else "the fabric")
        tex, count = ply.yarn_linear_density, ply.thread_count
        if tex is not None and count is not None:
            yarns = straight_yarn_mass(tex, count)
            share = ply.areal_density / yarns
            lo, hi = YARN_MASS_SHARE
            if not lo <= share <= hi:
                out.append(
                    f"{which}'s areal density {ply.areal_density:.4g} kg/m² is {share:.3g} × the "
                    f"mass of its straight yarns ({tex:.4g} tex × {count[0]:.4g} + {count[1]:.4g} "
                    f"per cm = {yarns:.4g} kg/m²; crimp adds a few to 25 %): check "
                    f"{at}areal_density, yarn_linear_density (tex = denier/9) and thread_count "
                    "(per cm, not per inch)")
        eps = ply.failure_strain()
        if eps is not None and eps > FAILURE_STRAIN_MAX:
            out.append(f"{which}'s failure strain is {eps:g} ({100 * eps:g} %): fibres break at "
                       f"0.5–10 %; strains are fractions (3.5 % is 0.035): check "
                       f"{at}damage.failure_strain or {at}material.failure_strain")
        sigma = ply.material.tensile_strength
        lo_s, hi_s = TENSILE_STRENGTH
        if sigma is not None and not lo_s <= sigma <= hi_s:
            hint = "; did you type GPa as Pa? (3.88 GPa = 3.88e9 Pa)" if sigma < lo_s else ""
            out.append(f"{at}material.tensile_strength = {sigma:g} Pa is far outside yarns "
                       f"({lo_s:g}–{hi_s:g} Pa; aramid and UHMWPE 2.5–4 GPa){hint}")
    return out


def _solver_warnings(sc) -> list[str]:
    """Solver keys given values the chosen integrator does not read (a φ-scheme key with
    central differences, courant with the φ-scheme). Compared with the
    defaults, not with the keys a file writes: a run's own scenario (a checkpoint's, a study
    case's) writes every key."""
    from emfabric.config.scenario import PHI_KEYS, SolverSpec

    solver, default = sc.solver, SolverSpec()
    if solver.integrator == "central-difference":
        unread, reader = PHI_KEYS, 'the φ-scheme (solver.integrator = "phi")'
    else:
        # (a bulk viscosity other than 0 is an error of the scenario with the φ-scheme)
        unread, reader = ("courant",), "central differences"
    changed = [f"solver.{k} = {getattr(solver, k)!r}" for k in unread
               if getattr(solver, k) != getattr(default, k)]
    if not changed:
        return []
    return [f"{', '.join(changed)}: read only by {reader}; solver.integrator = "
            f"{solver.integrator!r} runs without {'it' if len(changed) == 1 else 'them'}"]


def pre_run_warnings(model) -> list[str]:
    """What in this model is probably not what the user meant (see the module docstring)."""
    sc = model.scenario
    out: list[str] = []
    if sc is not None:
        out += _solver_warnings(sc)
    x0 = model.nodes.x0
    live = model.nodes.mass > 0
    lo = x0[:2, live].min(axis=1) if live.any() else np.zeros(2)
    hi = x0[:2, live].max(axis=1) if live.any() else np.zeros(2)
    side = float(min(hi - lo)) if live.any() else 0.0
    if sc is not None:
        for length in sc.fabric.size:
            if not SHEET_SIZE[0] <= length <= SHEET_SIZE[1]:
                hint = _unit_hint(length, "m", "mm", 1e-3) if length > SHEET_SIZE[1] else ""
                out.append(f"fabric.size = {list(sc.fabric.size)} m: a sheet side of {length:g} m "
                           f"is far outside armour panels ({SHEET_SIZE[0]:g}–{SHEET_SIZE[1]:g} m)"
                           + (f"; {hint}" if hint else ""))
                break
    out += _fabric_warnings(model, sc is not None)
    if sc is not None:
        out += _datasheet_warnings(sc)
    if not model.has_body:
        return out
    pr = sc.projectile if sc is not None else None
    geo = model.geometry
    radius = float(model.body.radius)
    mass = float(model.body.mass)
    if pr is not None and not BALLISTIC_SIZE[0] <= radius <= BALLISTIC_SIZE[1]:
        hint = _unit_hint(radius, "m", "mm", 1e-3) if radius > BALLISTIC_SIZE[1] else ""
        out.append(f"projectile.radius = {radius:g} m is far outside ballistic projectiles "
                   f"({BALLISTIC_SIZE[0]:g}–{BALLISTIC_SIZE[1]:g} m)" + (f"; {hint}" if hint
                                                                          else ""))
    if pr is not None and not BALLISTIC_MASS[0] <= mass <= BALLISTIC_MASS[1]:
        hint = _unit_hint(mass, "kg", "g", 1e-3) if mass > BALLISTIC_MASS[1] else ""
        out.append(f"projectile.mass = {mass:g} kg is far outside ballistic projectiles "
                   f"({BALLISTIC_MASS[0]:g}–{BALLISTIC_MASS[1]:g} kg)"
                   + (f"; {hint}" if hint else "; fine for a driver of constant speed"))
    if pr is not None and BALLISTIC_MASS[0] <= mass <= BALLISTIC_MASS[1]:
        # within the range of projectiles, but not of this one's size: the mean density a
        # solid of its shape would need (a .22 FSP of 1.1 g typed as 1.1 kg: 7e6 kg/m³)
        volume = float(geo.volume)
        density = mass / volume if volume > 0.0 else 0.0
        if density > PROJECTILE_DENSITY[1] or 0.0 < density < PROJECTILE_DENSITY[0]:
            hint = (_unit_hint(mass, "kg", "g", 1e-3) if density > PROJECTILE_DENSITY[1]
                    else "")
            out.append(f"projectile.mass = {mass:g} kg in a {pr.shape} of {volume:.3g} m³ "
                       f"is a mean density of {density:.3g} kg/m³, outside any solid's "
                       f"({PROJECTILE_DENSITY[0]:g}–{PROJECTILE_DENSITY[1]:g} kg/m³)"
                       + (f"; {hint}" if hint else ""))
    across = 2.0 * float(geo.bound)
    if side > 0.0 and across > side:
        out.append(f"the projectile ({across:.4g} m across) is larger than the sheet "
                   f"({side:.4g} m): it strikes the frame, not the fabric"
                   + (f"; check projectile.radius = {radius:g} m (mm as m?)" if radius > 0.1
                      else ""))
    if pr is not None and pr.position is not None and pr.gap != type(pr)().gap:
        out.append(f"projectile.gap = {pr.gap:g} m is not used: projectile.position = "
                   f"{list(pr.position)} m places the centre (gap is the clearance below the "
                   f"projectile, over the sheet's centre, when position is not given)")
    if pr is not None:
        # a point charge the projectile carries sits on or inside it (the paper's four sit on
        # its surface, section 6); one beyond its reach is a unit or frame mistake
        for k, ch in enumerate(pr.charges):
            dist = float(np.linalg.norm(np.asarray(ch.position, dtype=float)))
            if dist > float(geo.bound) * (1.0 + 1e-9):
                out.append(f"projectile.charges[{k}].position = {list(ch.position)} m lies "
                           f"{dist:.4g} m from the centre of mass, outside the projectile "
                           f"(it reaches {float(geo.bound):.4g} m): a charge the projectile "
                           f"carries sits on or inside it (positions are relative to the "
                           f"centre, in m)")
    v = np.asarray(model.body_v0, dtype=float)
    speed = float(np.linalg.norm(v))
    if pr is not None and speed > 0.0 and not BALLISTIC_SPEED[0] <= speed <= BALLISTIC_SPEED[1]:
        out.append(f"projectile.velocity: a speed of {speed:g} m/s is far outside ballistic "
                   f"impacts ({BALLISTIC_SPEED[0]:g}–{BALLISTIC_SPEED[1]:g} m/s)")
    c = np.asarray(model.body_x0, dtype=float)
    z_top = float(x0[2].max())
    z_bottom = float(x0[2].min())
    if speed > 0.0:
        # where the centre's straight path crosses the sheet's plane (the top ply's)
        plane = z_top if c[2] > z_top else z_bottom if c[2] < z_bottom else None
        if plane is not None and (plane - c[2]) * v[2] <= 0.0:
            out.append(f"projectile.velocity = {list(map(float, v))} m/s leads away from the "
                       f"sheet: the projectile will never touch it (fine if on purpose)")
        elif plane is not None:
            t = (plane - c[2]) / v[2]
            hit = c[:2] + t * v[:2]
            reach = float(geo.bound)
            if (hit < lo - reach).any() or (hit > hi + reach).any():
                out.append(f"the projectile's path crosses the sheet's plane at x, y = "
                           f"({hit[0]:.4g}, {hit[1]:.4g}) m, off the sheet ({lo[0]:.4g} … "
                           f"{hi[0]:.4g}, {lo[1]:.4g} … {hi[1]:.4g} m): it will miss the "
                           f"fabric (check projectile.position and velocity)")
            elif sc is not None:
                between = _between_yarns(model, sc, hit, v, 0 if c[2] > z_top else -1)
                if between is not None:
                    out.append(between)
                if sc.fabric.edges == "clamped":
                    edge = _at_the_frame(model, hit, v, lo, hi)
                    if edge is not None:
                        out.append(edge)
    elif pr is not None:
        out.append("projectile.velocity = [0, 0, 0]: the projectile is at rest and touches "
                   "the sheet only if the field or gravity drives it there")
    # a sphere smaller than the node spacing falls between the nodes (node contact only)
    if sc is not None and model.ply_count >= 1:
        nx, ny = model.ply_grid(0)
        lx, ly = sc.fabric.size
        h = max(lx / (nx - 1), ly / (ny - 1))
        segments = bool(model.contact.segments)
        if not segments and across < h * math.sqrt(2.0) and not any(
                "between the yarns" in w for w in out):
            out.append(f"the projectile ({across:.4g} m across) is smaller than the diagonal "
                       f"of a cell of the network ({h:.4g} m spacing) and only nodes meet it "
                       f"(contact.segments = false): it can fall between the nodes; use more "
                       f"fabric.nodes or contact.segments = true")
    return out


def _silhouette(model, hit, v, e) -> tuple[float, float]:
    """The projectile's extent along the in-plane unit vector e (world, (3,)) seen along its
    velocity v, where its centre's path crosses the sheet's plane at `hit` (x, y): the body
    projected along v onto the plane, as (least, largest) e·x [m]. Its extent along e is the
    body's support function in d = e − (e·v / v_z) ẑ (the projection's adjoint applied to e)."""
    geo, frame = model.geometry, model.body.frame
    d = e - (e @ v / v[2]) * np.array([0.0, 0.0, 1.0])
    centre = float(e[:2] @ hit)
    return centre - geo.extent(frame @ -d), centre + geo.extent(frame @ d)


def _at_the_frame(model, hit, v, lo, hi) -> str | None:
    """The warning for a projectile whose silhouette (_silhouette) reaches the clamped edge of
    the sheet (lo, hi: its x, y extent), else None: clamped nodes are fixed points, not an
    obstacle, and a body that meets them passes through the frame while the yarns they hold
    stretch without bound (the energy balance then fails: a run aimed 2.5 cm off the edge of
    demo-small ended with clamped nodes deep inside the sphere and −7.6 J of balance error)."""
    for k, axis in enumerate("xy"):
        e = np.zeros(3)
        e[k] = 1.0
        least, largest = _silhouette(model, hit, v, e)
        edge = lo[k] if least <= lo[k] else hi[k] if largest >= hi[k] else None
        if edge is not None:
            room = 0.5 * (largest - least)
            return (f"the projectile reaches the clamped edge {axis} = {edge:.4g} m: it crosses "
                    f"the sheet at x, y = ({hit[0]:.4g}, {hit[1]:.4g}) m and is "
                    f"{largest - least:.4g} m across {axis} there; the frame is not an "
                    f"obstacle in this model (its clamped nodes are fixed points the projectile "
                    f"passes through, stretching the yarns they hold without bound): aim it at "
                    f"least {room:.4g} m from the edges, or use fabric.edges = \"free\"")
    return None


def _between_yarns(model, sc, hit, v, ply: int) -> str | None:
    """The warning for a projectile whose silhouette, seen along its velocity v, fits between
    the yarns of the ply it meets first (ply 0 from above, the last from below) where its
    centre's path crosses that ply's plane at `hit` (x, y): the lumped network has yarns only
    along its grid lines, so such a body passes through the sheet without touching one (a
    fragment narrower than the cell of a coarse grid; the grid's parity decides it when the
    body is aimed at the middle). None when it meets a yarn line."""
    p = ply % model.ply_count
    a, b = int(model.nodes.ply_nodes[p]), int(model.nodes.ply_nodes[p + 1])
    x0 = model.nodes.x0[:, a:b][:, model.nodes.mass[a:b] > 0]
    if x0.shape[1] == 0 or v[2] == 0.0:
        return None
    angles = sc.fabric.ply_angles
    theta = math.radians(angles[p]) if angles else 0.0
    nx, ny = model.ply_grid(p)
    spacing = (sc.fabric.size[0] / (nx - 1), sc.fabric.size[1] / (ny - 1))
    covered = []
    for e in ((math.cos(theta), math.sin(theta), 0.0), (-math.sin(theta), math.cos(theta), 0.0)):
        e = np.array(e)
        span = _silhouette(model, hit, v, e)
        lines = np.unique(np.round(e[:2] @ x0[:2], 9))
        if np.any((lines >= span[0]) & (lines <= span[1])):
            return None  # it meets the yarns along this family's lines
        covered.append(span[1] - span[0])
    need = [int(math.ceil(size / width)) + 1 for size, width in zip(sc.fabric.size, covered,
                                                                      strict=True)]
    return (f"the projectile fits between the yarns of the network: seen along its velocity it "
            f"is {covered[0]:.4g} × {covered[1]:.4g} m where it crosses the "
            f"{'top' if ply == 0 else 'bottom'} ply at x, y = ({hit[0]:.4g}, {hit[1]:.4g}) m, "
            f"inside one cell of {spacing[0]:.4g} × {spacing[1]:.4g} m, so it passes through that "
            f"ply without touching a yarn (the lumped network has yarns only along its grid "
            f"lines); use fabric.nodes ≥ [{need[0]}, {need[1]}] or aim it at a yarn")


def _snapshots(sc) -> float:
    """Snapshots of a run to end_time: t = 0, interval, 2·interval, … (a float: inf where the
    ratio overflows)."""
    ratio = sc.solver.end_time / sc.output.snapshot_interval * (1.0 + 1e-12)
    return float(math.floor(ratio) + 1) if math.isfinite(ratio) else math.inf


def _snapshot_bytes(model) -> int:
    """Bytes of one snapshot: snapshots.nc's record and, with output.paraview, its .vtu file."""
    per = (SNAPSHOT_BYTES_PER_NODE * model.node_count
           + SNAPSHOT_BYTES_PER_SEGMENT * model.seg_count)
    if model.scenario.output.paraview:
        per += VTU_BYTES_PER_NODE * model.node_count
    return per


def output_volume(model) -> float:
    """Bytes a run of this model writes (estimate): every snapshot in snapshots.nc and, with
    output.paraview, its .vtu files; the history and checkpoint are small beside them."""
    if model.scenario is None:
        return 0.0
    return _snapshots(model.scenario) * _snapshot_bytes(model)


def check_output_volume(model) -> None:
    """Refuse a run that would write more than output.size_limit bytes, naming the keys that
    set the volume."""
    from emfabric.config.scenario import ScenarioError

    sc = model.scenario
    if sc is None:
        return
    need = output_volume(model)
    limit = sc.output.size_limit
    if need > limit:
        snapshots = _snapshots(sc)
        count = f"{snapshots:.0f}" if snapshots < 1e15 else f"{snapshots:.3g}"
        size = f"{need / 1e9:.3g}" if math.isfinite(need) else "more than 1e300"
        raise ScenarioError(
            f"output.snapshot_interval = {sc.output.snapshot_interval:g} s: {count} "
            f"snapshots of {model.node_count} nodes up to solver.end_time = "
            f"{sc.solver.end_time:g} s would write about {size} GB, above "
            f"output.size_limit = {limit / 1e9:.3g} GB; allowed: a longer snapshot_interval "
            f"(≥ {sc.solver.end_time * _snapshot_bytes(model) / limit:.3g} s), "
            f"output.paraview = false, or a larger output.size_limit to ask for it")
