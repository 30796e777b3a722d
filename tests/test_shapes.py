"""Projectile shapes (issue 12): geometry against closed forms and independent sampling, the
closest point against brute force, and impacts of an ogive: momentum, symmetry, the mirror in
B, torque-free rotation, and segment contact catching a nose that node contact lets through."""

import math

import numpy as np
import pytest
from numba import njit

from emfabric._kernels.records import SHAPE_CYLINDER, SHAPE_FSP, SHAPE_OGIVE, Body
from emfabric._kernels.shapes import closest_surface_point
from emfabric.config.scenario import ScenarioError, load_scenario
from emfabric.integrators import Integrator
from emfabric.runner.loop import run
from emfabric.sim.builder import build_model
from emfabric.sim.geometry import ShapeGeometry, shape_frame
from emfabric.sim.state import initial_state

from conftest import make

R = 0.005
OGIVE = ShapeGeometry("ogive", R, 0.03, nose_length=0.018)
CYLINDER = ShapeGeometry("cylinder", R, 0.02)
FSP = ShapeGeometry("fsp", R, 2.32 * R, flat_half_width=0.16 * R, bevel=math.radians(35.0))
CODES = {"ogive": SHAPE_OGIVE, "cylinder": SHAPE_CYLINDER, "fsp": SHAPE_FSP}


def _inside_local(geo, q):
    """Independent inside test in the shape frame (s from the base), for points (N, 3)."""
    s = q[:, 2] + geo.base
    rr = np.hypot(q[:, 0], q[:, 1])
    ok = (s > 0) & (s < geo.length)
    if geo.kind == "ogive":
        lb = geo.length - geo.nose_length
        rho = (geo.radius**2 + geo.nose_length**2) / (2 * geo.radius)
        prof = np.where(s <= lb, geo.radius,
                        np.sqrt(np.maximum(rho**2 - (s - lb) ** 2, 0)) + geo.radius - rho)
        return ok & (rr < prof)
    ok &= rr < geo.radius
    if geo.kind == "fsp":
        ok &= np.abs(q[:, 1]) < geo.flat_half_width + (geo.length - s) * math.tan(geo.bevel)
    return ok


def _surface_samples(geo, n=400_000, seed=3):
    """Points spread over the surface (shape frame, relative to the centre of mass), drawn
    independently of the code: faces, side and nose parametrised directly."""
    rng = np.random.default_rng(seed)
    big_r, big_l = geo.radius, geo.length
    parts = []
    # base and end discs (r uniform in area)
    for s0 in (0.0, big_l):
        r = big_r * np.sqrt(rng.uniform(0, 1, n // 4))
        t = rng.uniform(0, 2 * np.pi, n // 4)
        parts.append(np.stack([r * np.cos(t), r * np.sin(t), np.full(r.size, s0)], 1))
    s = rng.uniform(0, big_l, n)
    t = rng.uniform(0, 2 * np.pi, n)
    if geo.kind == "ogive":
        parts.pop()  # no end disc: the nose closes to a point
        lb = big_l - geo.nose_length
        rho = (big_r**2 + geo.nose_length**2) / (2 * big_r)
        r = np.where(s <= lb, big_r, np.sqrt(np.maximum(rho**2 - (s - lb) ** 2, 0)) + big_r - rho)
        parts.append(np.stack([r * np.cos(t), r * np.sin(t), s], 1))
    else:
        parts.append(np.stack([big_r * np.cos(t), big_r * np.sin(t), s], 1))
    pts = np.concatenate(parts)
    if geo.kind == "fsp":
        tb = math.tan(geo.bevel)
        # chisel faces: y = ±(w/2 + (L − s) tan β), x within the disc
        x = rng.uniform(-big_r, big_r, 2 * n)
        ss = rng.uniform(0, big_l, 2 * n)
        y = (geo.flat_half_width + (big_l - ss) * tb) * np.where(rng.uniform(0, 1, 2 * n) < .5,
                                                                 1, -1)
        face = np.stack([x, y, ss], 1)
        face = face[x**2 + y**2 <= big_r**2]
        h = geo.flat_half_width + (big_l - pts[:, 2]) * tb
        pts = np.concatenate([pts[np.abs(pts[:, 1]) <= h + 1e-15], face])
    pts[:, 2] -= geo.base
    return pts


def _body(geo, frame):
    return Body(True, CODES[geo.kind], geo.radius, 1.0, np.eye(3), np.zeros((0, 3)),
                np.zeros(0), np.zeros(3), length=geo.length, nose_length=geo.nose_length,
                base=geo.base, arc_radius=geo.arc_radius, flat_half_width=geo.flat_half_width,
                bevel_cos=math.cos(geo.bevel), bevel_sin=math.sin(geo.bevel), frame=frame,
                bound=geo.bound)


@njit
def _closest_all(body, rot, d):
    n = d.shape[0]
    inside = np.zeros(n, np.bool_)
    r = np.zeros((n, 3))
    nrm = np.zeros((n, 3))
    for i in range(n):
        a, rr, nh = closest_surface_point(body, rot, (d[i, 0], d[i, 1], d[i, 2]))
        inside[i] = a
        for c in range(3):
            r[i, c] = rr[c]
            nrm[i, c] = nh[c]
    return inside, r, nrm


def test_cylinder_mass_properties_closed_form():
    m = 0.01
    assert CYLINDER.volume == pytest.approx(math.pi * R**2 * 0.02, rel=1e-13)
    assert CYLINDER.base == pytest.approx(0.01, rel=1e-13)
    i = CYLINDER.principal_inertia(m)
    np.testing.assert_allclose(i, [m * (3 * R**2 + 0.02**2) / 12] * 2 + [m * R**2 / 2],
                               rtol=1e-13)


def test_ogive_volume_closed_form():
    """Tangent ogive of arc radius ϱ: V_nose = π[ϱ²L_n − L_n³/3 − (ϱ − R)ϱ² asin(L_n/ϱ)]."""
    ln = OGIVE.nose_length
    rho = OGIVE.arc_radius
    assert rho == pytest.approx((R**2 + ln**2) / (2 * R), rel=1e-15)
    nose = math.pi * (rho**2 * ln - ln**3 / 3 - (rho - R) * rho**2 * math.asin(ln / rho))
    assert OGIVE.volume == pytest.approx(nose + math.pi * R**2 * (0.03 - ln), rel=1e-12)


@pytest.mark.parametrize("geo", [OGIVE, FSP], ids=["ogive", "fsp"])
def test_centre_of_mass_and_inertia_against_sampling(geo):
    """Monte Carlo over the bounding box with the independent inside test: volume, centre of
    mass and the three principal moments agree to the sampling error (~0.3 %)."""
    rng = np.random.default_rng(11)
    n = 3_000_000
    lo = np.array([-R, -R, -geo.base])
    hi = np.array([R, R, geo.length - geo.base])
    q = rng.uniform(lo, hi, (n, 3))
    inside = _inside_local(geo, q)
    box = float(np.prod(hi - lo))
    assert inside.mean() * box == pytest.approx(geo.volume, rel=5e-3)
    p = q[inside]
    assert abs(p[:, 2].mean()) < 2e-3 * geo.length  # the centre of mass is the origin
    m = 0.02
    mc = m * np.array([np.mean(p[:, 1] ** 2 + p[:, 2] ** 2), np.mean(p[:, 0] ** 2 + p[:, 2] ** 2),
                       np.mean(p[:, 0] ** 2 + p[:, 1] ** 2)])
    np.testing.assert_allclose(geo.principal_inertia(m), mc, rtol=6e-3)
    if geo.kind == "fsp":  # the chisel makes the two transverse moments differ
        i = geo.principal_inertia(m)
        assert i[1] > i[0] * 1.02


@pytest.mark.parametrize("geo", [OGIVE, CYLINDER, FSP], ids=["ogive", "cylinder", "fsp"])
def test_closest_point_against_brute_force(geo):
    """Random points around a yawed, rotated body: the inside test matches the independent one,
    the closest surface point lies on the surface at the brute-force distance, and the normal
    is a unit vector pointing out (a step along it leaves the body)."""
    axis = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    frame = shape_frame(axis)
    th = 0.7
    rot = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0], [-math.sin(th), 0, math.cos(th)]])
    body = _body(geo, frame)
    rng = np.random.default_rng(5)
    to_local = frame @ rot.T
    # points in the body's bounding box enlarged by 10 %, in the world frame
    lo = np.array([-R, -R, -geo.base]) * 1.1
    hi = np.array([R, R, geo.length - geo.base]) * 1.1
    q = rng.uniform(lo, hi, (3000, 3))
    d = q @ to_local
    inside, r, nrm = _closest_all(body, rot, d)
    np.testing.assert_array_equal(inside, _inside_local(geo, q))
    assert inside.sum() > 300
    surf = _surface_samples(geo, n=120_000) @ to_local  # world frame: rows · (frame R^T)
    spacing = 3e-4  # the samples' spacing on the surface is ~1e-4 m
    for k in np.flatnonzero(inside)[:150]:
        brute = np.sqrt(((surf - d[k]) ** 2).sum(1)).min()
        dist = np.linalg.norm(r[k] - d[k])
        assert dist <= brute + 1e-12
        assert dist > brute - spacing
        # on the surface: the closest sample to r is within the sampling spacing
        assert np.sqrt(((surf - r[k]) ** 2).sum(1)).min() < spacing
    n = nrm[inside]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-14)
    out = (r[inside] + 1e-6 * n) @ to_local.T
    back = (r[inside] - 1e-6 * n) @ to_local.T
    assert not _inside_local(geo, out).any()
    assert _inside_local(geo, back).mean() > 0.99  # inward step is inside (edges excepted)


def test_shape_keys_are_checked():
    with pytest.raises(ScenarioError, match="needs length"):
        make(**{"projectile.shape": "cylinder"})
    with pytest.raises(ScenarioError, match="nose_length"):
        make(**{"projectile.shape": "ogive", "projectile.length": 0.03})
    with pytest.raises(ScenarioError, match=r"\[radius, length\]"):
        make(**{"projectile.shape": "ogive", "projectile.length": 0.03,
                "projectile.nose_length": 0.002})
    with pytest.raises(ScenarioError, match="only for shape"):
        make(**{"projectile.shape": "cylinder", "projectile.length": 0.03,
                "projectile.nose_length": 0.01})


def _ogive(**kw):
    return make(**{"projectile.shape": "ogive", "projectile.radius": 0.006,
                   "projectile.length": 0.03, "projectile.nose_length": 0.018,
                   "projectile.mass": 0.01, **kw})


def test_default_start_puts_the_nose_gap_above_the_sheet():
    """A yawed ogive by default starts with its lowest point `gap` above the sheet centre."""
    axis = np.array([math.sin(0.3), 0.0, -math.cos(0.3)])
    model = build_model(_ogive(**{"projectile.axis": list(axis)}))
    geo = model.geometry
    pts, _ = geo.mesh(n_az=2000, n_axial=400)
    world = pts @ model.body.frame + model.body_x0
    assert world[:, 2].min() == pytest.approx(1e-4, abs=2e-8)
    # the nose marker points along the axis, from the centre of mass to the tip
    np.testing.assert_allclose(model.body.nose, (geo.length - geo.base) * axis, rtol=1e-14)


def test_torque_free_ogive_conserves_momentum_and_energy():
    """An ogive (two equal transverse moments, a smaller axial one) spinning about an oblique
    axis, nothing touching it: angular momentum exact, kinetic energy to the scheme's error;
    the axis precesses (the spin is not about a principal axis)."""
    sc = _ogive(**{"fabric.nodes": [2, 2], "fabric.size": [0.01, 0.01], "field.B": [0, 0, 0],
                   "projectile.position": [0.0, 0.0, 1.0], "projectile.velocity": [0, 0, 0],
                   "projectile.axis": [0.0, 0.0, -1.0],
                   "projectile.angular_velocity": [300.0, 0.0, 2000.0],
                   "solver.adaptive": False, "solver.dt_max": 2e-5, "solver.tolerance": 1e-13,
                   "solver.max_iterations": 50})
    model = build_model(sc)
    integ = Integrator(model)
    s, s2 = initial_state(model), initial_state(model)
    inertia = model.body.inertia
    h0 = inertia @ model.body_w0
    e0 = 0.5 * model.body_w0 @ inertia @ model.body_w0
    worst_h = worst_e = 0.0
    for _ in range(1500):
        integ.step(s, s2)
        s, s2 = s2, s
        rot = s.body_rotation
        w = s.body_omega
        world_i = rot @ inertia @ rot.T
        worst_h = max(worst_h, np.linalg.norm(world_i @ w - h0) / np.linalg.norm(h0))
        worst_e = max(worst_e, abs(0.5 * w @ world_i @ w - e0) / e0)
    assert worst_h < 1e-10
    assert worst_e < 1e-4
    # precession: the nose axis has left −z
    nose = s.body_rotation @ model.body.nose
    assert abs(nose[0]) + abs(nose[1]) > 1e-3 * np.linalg.norm(nose)


def _oblique_ogive(dt):
    return _ogive(**{
        "fabric.nodes": [15, 15], "fabric.size": [0.1, 0.1], "fabric.edges": "free",
        "field.B": [0, 0, 0], "projectile.position": [0.003, -0.002, 0.02],
        "projectile.velocity": [30.0, -20.0, -200.0], "projectile.axis": [0.1, 0.05, -1.0],
        "projectile.angular_velocity": [100.0, -300.0, 2000.0], "solver.end_time": 200e-6,
        "solver.adaptive": False, "solver.dt_max": dt, "solver.tolerance": 1e-10,
        "solver.max_iterations": 200})


def test_ogive_momentum_conserved_with_yaw_obliquity_offset():
    """Free edges, no field: a yawed ogive hitting obliquely off-centre, node and segment
    contact both active. Linear momentum of fabric + projectile is conserved to round-off.
    Angular momentum: the contact impulses exchange exactly opposite moments, but the
    trapezoidal rule and the momentum-free position projection (m δ × v per projected node,
    MODEL §4) do not conserve it exactly: the drift stays below 10⁻⁴ of |L| here."""
    ds = run(_oblique_ogive(1e-7)).history
    p = ds.fabric_momentum.values + ds.projectile_momentum.values
    a = ds.fabric_angular_momentum.values + ds.projectile_angular_momentum.values
    assert int(ds.contact_nodes.max()) >= 5
    assert np.abs(p - p[0]).max() < 1e-14 * np.abs(p[0]).max() * 10
    assert np.abs(a - a[0]).max() / np.abs(a[0]).max() < 1e-4


H = 0.254 / 99


def _head_on(n, **kw):
    return _ogive(**{"fabric.nodes": [n, n], "fabric.size": [(n - 1) * H, (n - 1) * H],
                     "fabric.rescale": False, "projectile.gap": 0.0,
                     "fabric.material.modulus_cv": 0.0, **kw})


@pytest.mark.parametrize("n", [30, 31])
def test_head_on_ogive_does_not_spin(n):
    """No field, no modulus scatter, an axisymmetric ogive head-on: ω stays exactly zero with
    node and segment contact (mirror-symmetric contact and exactly rounded sums). The odd grid
    has a node on the axis: it rides on the tip."""
    ds = run(_head_on(n, **{"field.B": [0, 0, 0], "solver.end_time": 60e-6})).history
    assert int(ds.contact_nodes.max()) >= 4
    assert float(np.abs(ds.angular_velocity).max()) == 0.0
    assert float(np.abs(ds.projectile_position[:, :2]).max()) == 0.0
    assert float(ds.yaw.max()) == 0.0


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_reversing_B_mirrors_yaw_and_spin(integrator):
    """A yawed ogive (axis in the x–z plane, velocity oblique in that plane) in B = ±B e_x: the
    scene is mirror-symmetric in y, so reversing B mirrors the run exactly: ω_x and ω_z change
    sign, ω_y and the yaw do not. Both schemes; under the φ-scheme's adaptive steps the error
    measure that chooses them is mirror-exact too."""
    def go(bx):
        return run(_head_on(30, **{"field.B": [bx, 0, 0], "solver.end_time": 40e-6,
                                   "solver.integrator": integrator,
                                   "projectile.axis": [0.1, 0.0, -1.0],
                                   "projectile.velocity": [20.0, 0.0, -250.0]})).history
    a, b, c = go(0.05), go(-0.05), go(0.0)
    wa, wb = a.angular_velocity.values, b.angular_velocity.values
    assert np.abs(wa[:, 0]).max() > 1.0
    np.testing.assert_array_equal(wb[:, 0], -wa[:, 0])
    np.testing.assert_array_equal(wb[:, 1], wa[:, 1])
    np.testing.assert_array_equal(wb[:, 2], -wa[:, 2])
    np.testing.assert_array_equal(a.yaw.values, b.yaw.values)
    # the field spins the ogive about x, which the fabric alone does not
    assert abs(wa[-1, 0] - c.angular_velocity.values[-1, 0]) > 1.0


def _sharp(segments):
    """An ogive narrower than a cell's diagonal (R = 0.6 h < h/√2) aimed at a cell centre of an
    11 × 11 clamped sheet without damage, at 50 m/s: no node is ever inside it."""
    h = 0.01
    return _ogive(**{"fabric.nodes": [11, 11], "fabric.size": [0.1, 0.1], "field.B": [0, 0, 0],
                     "fabric.damage.rate": 0.0, "fabric.material.modulus_cv": 0.0,
                     "contact.segments": segments, "projectile.radius": 0.6 * h,
                     "projectile.length": 3 * h, "projectile.nose_length": 1.8 * h,
                     "projectile.mass": 0.005, "projectile.position": [h / 2, h / 2, 0.021],
                     "projectile.velocity": [0, 0, -50.0], "solver.end_time": 3e-3})


def test_segment_contact_catches_a_nose_that_passes_between_nodes():
    """With segment contact the yarns around the cell catch the ogive and throw it back; with
    node contact alone it passes through the cell untouched. How fast it comes back is set by
    the friction of the four segments sliding along the nose and by the cell's release: the
    rebound converges with the step, to 18.0 m/s (18.04 and 18.02 at courant 1/32 and 1/64;
    21.2, 20.6 and 19.2 at 0.25, 0.125 and 0.0625: `python scripts/sharp_ogive.py`). Before
    the passes' impulses were cut to the Coulomb cone as a whole (docs/theory.md §5.2) the
    friction fell 0.2–0.4 % short of μ_d while sliding and the rebound read 18.6 m/s at every
    step: the same at each step, and the limit of another law."""
    rebound = []
    for courant in (0.25, 0.03125, 0.015625):
        caught = run(_sharp(True).replace(**{"solver.courant": courant})).history
        assert caught.attrs["end_reason"] == "rebound"
        rebound.append(float(caught.projectile_velocity[-1, 2]))
    assert rebound[0] > 0.0
    assert rebound[1] == pytest.approx(rebound[2], rel=0.01)
    passed = run(_sharp(False)).history
    assert passed.attrs["end_reason"] == "never touched"
    assert float(passed.projectile_velocity[-1, 2]) == -50.0


@pytest.mark.parametrize("lag", [0.0, 1e-7])
@pytest.mark.parametrize("depth_radius", [0.0052, 0.0058])
def test_shared_segment_contacts_are_resolved_together(depth_radius, lag):
    """The sharp nose pushed through the middle of a cell at 300 m/s, the sheet at rest: the
    cell's four segments press on it and share its four corner nodes. Resolved together, the
    contact law's conditions hold at every contact point at once: the point is on the surface
    (not inside) and, the law being perfectly inelastic along the normal, it moves with the
    surface along the normal, v_P·n = v_s·n, while its impulse pushes (J·n ≥ 0). Each pass
    of the shared correction gives each segment only its share at a node: with the passes
    capped at 8 (before) the points were left 0.5–2.8 µm inside, moving into the nose at
    0.025–0.06 m/s; now they are within 1e-11 m of the surface and 1e-7 m/s of its normal
    velocity.

    Under central differences (lag = Δt > 0) Coulomb's law holds at every point at once too:
    the points slide along the nose (at ~180 and ~230 m/s), so each impulse's tangential part
    is μ_d times its normal part, against the slip. The passes' impulses are added up and cut
    to the cone as a whole; cut pass by pass (the φ-scheme's, lag = 0: a pass whose own normal
    impulse is small could not stop the slip its neighbours gave the point), they gave
    0.948 and 0.946, friction short by 0.2–0.4 %. With lag > 0 the end nodes then move by
    lag × the tangential velocity change (the redone drift), so the position is checked for
    lag = 0 and the velocities, which that move leaves alone, for both."""
    from emfabric._kernels.contact import find_segment_candidates, segment_contact
    from emfabric._kernels.records import BODY_R0, BODY_V, BODY_W, BODY_X
    from emfabric._kernels.shapes import surface_point
    from emfabric.integrators import CentralDifference

    model = build_model(_sharp(True))
    geo = model.geometry
    # the sheet's plane (z = 0) cuts the nose where its radius is depth_radius, beyond the
    # segments' midpoints at h/2 = 5 mm from the axis
    s = np.linspace(0.0, geo.length, 200001)
    plane = s[np.argmin(np.abs(geo.profile_radius(s) - depth_radius))]
    integ = CentralDifference(model, threads=False)
    a = initial_state(model).arrays
    phys, work = integ.physics, integ.work
    body = a.body
    tip = body[BODY_X] + model.body.nose
    body[BODY_X, 2] += -(geo.length - plane) - tip[2]
    body[BODY_V] = (0.0, 0.0, -300.0)
    body[BODY_W] = 0.0
    x, v = a.x.copy(), np.zeros_like(a.v)
    _ncand, nseg = find_segment_candidates(phys.yarns, a.alpha, phys.material.broken_below, x,
                                           phys.nodes.inv_mass, body[BODY_X], 0.03, work, 0)
    nc = segment_contact(phys, body, nseg, 0, x, v, work, lag, a.seg_contact,
                         np.zeros_like(a.seg_contact))
    assert nc == 4
    rot = body[BODY_R0:BODY_R0 + 3]
    mu_d = phys.contact.dynamic_friction
    for kc in range(nc):
        na, nb = work.c_node[kc], work.c_node2[kc]
        wa, wb = work.c_w[:, kc]
        p = wa * x[:, na] + wb * x[:, nb]
        vp = wa * v[:, na] + wb * v[:, nb]
        if lag == 0.0:
            g, _r, n = surface_point(phys.body, rot, tuple(float(c) for c in p - body[BODY_X]))
            assert g > -1e-9 * model.body.bound and g < 1e-12
            np.testing.assert_allclose(n, work.c_nrm[:, kc], rtol=0, atol=1e-9)
        n = work.c_nrm[:, kc]
        jv = work.c_imp[:, kc]
        jn = float(jv @ n)
        assert jn > 0.0
        # the surface's velocity is the body's (no spin): −300 e_z
        rel = vp - body[BODY_V]
        assert float(rel @ n) == pytest.approx(0.0, abs=1e-6)
        if lag > 0.0:
            slip = rel - (rel @ n) * n
            jt = jv - jn * n
            assert np.linalg.norm(slip) > 100.0
            assert np.linalg.norm(jt) == pytest.approx(mu_d * jn, rel=1e-9)
            np.testing.assert_allclose(jt / np.linalg.norm(jt), -slip / np.linalg.norm(slip),
                                       rtol=0, atol=1e-9)


def test_auto_contact_mode_follows_the_shape():
    assert not build_model(make()).contact.segments
    assert build_model(_ogive()).contact.segments
    assert not build_model(_ogive(**{"contact.segments": False})).contact.segments
    assert build_model(make(**{"contact.segments": True})).contact.segments


@pytest.mark.parametrize("name", ["ogive-field", "ogive-no-field", "ogive-yawed", "fsp"])
def test_builtin_shape_scenarios_build(name):
    model = build_model(load_scenario(name))
    assert model.has_body and model.scenario.projectile.shape in ("ogive", "fsp")


def test_outputs_show_the_real_shape(tmp_path):
    """ParaView and snapshots.nc carry the ogive's surface (points on its surface, moved with
    the body's pose); the impact sequence draws that surface, not a sphere."""
    import meshio
    import xarray as xr
    from matplotlib.collections import PolyCollection
    from mpl_toolkits.mplot3d import Axes3D

    from emfabric.viz import plots

    out = tmp_path / "run"
    axis = [math.sin(0.2), 0.0, -math.cos(0.2)]
    run(_ogive(**{"fabric.nodes": [13, 13], "solver.end_time": 20e-6,
                  "output.snapshot_interval": 10e-6, "projectile.axis": axis,
                  "projectile.angular_velocity": [0.0, 3000.0, 0.0]}), out)
    model = build_model(_ogive(**{"projectile.axis": axis}))
    geo = model.geometry
    with xr.open_dataset(out / "snapshots.nc") as s:
        assert s.attrs["projectile_shape"] == "ogive"
        pts = s["projectile_surface"].values
        k = s.sizes["snapshot"] - 1
        rot = s["projectile_rotation"].values[k]
        centre = s["projectile_position"].values[k]
        v_cm = s["projectile_velocity"].values[k]
        omega = s["angular_velocity"].values[k]
    # the stored points lie on the ogive: in the shape frame, on its profile
    q = pts @ model.body.frame.T
    s_ = q[:, 2] + geo.base
    rr = np.hypot(q[:, 0], q[:, 1])
    on_side = rr > 0
    np.testing.assert_allclose(rr[on_side & (s_ > 1e-9)], geo.profile_radius(
        s_[on_side & (s_ > 1e-9)]), atol=1e-12)
    vtu = meshio.read(out / "vtk" / f"projectile_{k:05d}.vtu")
    np.testing.assert_allclose(vtu.points, pts @ rot.T + centre, atol=1e-12)
    assert not np.allclose(rot, np.eye(3))  # it turned, and the mesh with it
    # each surface point's velocity is the rigid body's there, v + ω × r (not v alone)
    r = vtu.points - centre
    np.testing.assert_allclose(vtu.point_data["velocity"], v_cm + np.cross(omega, r),
                               rtol=0, atol=1e-9 * np.abs(v_cm).max())
    assert np.ptp(vtu.point_data["velocity"][:, 0]) > 1.0  # the spin shows
    with plots.open_snapshots(out) as s:
        fig = plots.sequence_figure(s, count=2)
    ax = [a for a in fig.axes if isinstance(a, Axes3D)][-1]
    skins = [c for c in ax.collections if isinstance(c, PolyCollection)]
    fig.canvas.draw()  # 3-D polygons are projected to paths when drawn
    assert len(skins) == 1 and len(skins[0].get_paths()) == len(vtu.cells_dict["triangle"])


def test_ogive_energy_budget_closes_with_the_scheme():
    """Segment and node contact on a yawed oblique ogive: every dissipation is booked (≥ 0 for
    contact and friction), the balance error is a small discretisation error (< 0.1 % of the
    energy exchanged) and shrinks as Δt does."""
    def err(dt):
        ds = run(_oblique_ogive(dt).replace(**{"solver.end_time": 300e-6})).history
        exchanged = float(ds.kinetic_energy_projectile[0] - ds.kinetic_energy_projectile[-1])
        assert exchanged > 10.0
        for term in ("dissipation_friction", "dissipation_contact"):
            assert float(ds[term][-1]) > 0.0, term
        return abs(float(ds.energy_balance_error[-1])) / exchanged

    coarse, fine = err(2e-7), err(5e-8)
    assert coarse < 1e-3
    assert fine < coarse / 3
