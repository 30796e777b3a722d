"""Central differences (solver.integrator = "central-difference"): closed forms and invariants."""

import math

import numpy as np
import pytest

from emfabric.config.scenario import load_scenario
from emfabric.integrators import CentralDifference, make_integrator
from emfabric.runner.loop import resume, run
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state

from conftest import fabric_only, interrupted_demo, make

CD = {"solver.integrator": "central-difference"}


def _free_sheet(n=2, **kw):
    """A rigid free sheet (every node the same velocity: no yarn stretches); soft yarns, so the
    step is dt_max."""
    return fabric_only(**{
        "fabric.nodes": [n, n], "fabric.size": [0.1, 0.1], "fabric.edges": "free",
        "fabric.areal_density": 0.04, "fabric.material.youngs_modulus": 1.0, **CD, **kw})


def _march(sc, steps):
    model = build_model(sc)
    integ = make_integrator(model)
    assert isinstance(integ, CentralDifference)
    s, s2 = initial_state(model), initial_state(model)
    for _ in range(steps):
        integ.step(s, s2)
        s, s2 = s2, s
    return model, s


def _march_at(sc, steps, dt):
    """_march with every step forced to dt (the step a state carries, State.dt), past the
    gyration limit that a run keeps to (records.GYRATION_TURN): what the scheme itself does at
    any ω_c Δt."""
    model = build_model(sc)
    integ = make_integrator(model)
    assert isinstance(integ, CentralDifference)
    s, s2 = initial_state(model), initial_state(model)
    s.steps = 1  # a state past its first step: its own dt is the step taken
    for _ in range(steps):
        s.dt = dt
        integ.step(s, s2)
        assert s2.t - s.t == pytest.approx(dt, rel=1e-12)
        s, s2 = s2, s
    return model, s


@pytest.mark.parametrize("dt", [2e-3, 1e-2])
def test_cyclotron_frequency_is_exact(dt):
    """A charged node in uniform B turns at exactly ω_c = qB/m, whatever ω_c Δt (0.2 and 1
    here): the magnetic rotation is exact in angle and magnitude."""
    sc = _free_sheet(**{"fabric.velocity": [3.0, 0.0, 0.0], "field.B": [0.0, 0.0, 0.01],
                        "fabric.charge_per_node": 1.0, "solver.dt_max": dt})
    steps = round(0.2 / dt)
    model, s = _march_at(sc, steps, dt)
    wc = 1.0 * 0.01 / model.nodes.mass[0]  # 100 rad/s
    theta = wc * steps * dt
    v = s.node_v[:, 0]
    assert np.allclose(v, [3 * math.cos(theta), -3 * math.sin(theta), 0.0], rtol=0, atol=1e-12)


def test_e_cross_b_motion_is_second_order():
    """A charged node in E ⟂ B: the exact orbit is the E × B drift plus gyration; the
    position error at a fixed time falls 4× per halving of Δt (second order)."""
    q, e0, b0, v0 = 1.0, 0.02, 0.01, 3.0

    def error(dt):
        sc = _free_sheet(**{"fabric.velocity": [v0, 0.0, 0.0], "field.B": [0.0, 0.0, b0],
                            "field.E": [0.0, e0, 0.0], "fabric.charge_per_node": q,
                            "solver.dt_max": dt})
        steps = round(0.05 / dt)
        model, s = _march_at(sc, steps, dt)
        m = model.nodes.mass[0]
        wc, t = q * b0 / m, steps * dt
        drift = e0 / b0  # E × B / B² = (e0 / b0) x̂
        # v(t) = drift x̂ + (v0 − drift)(cos ωt, −sin ωt): its integral
        u = v0 - drift
        dx = drift * t + u * math.sin(wc * t) / wc
        dy = u * (math.cos(wc * t) - 1.0) / wc
        return np.hypot(s.node_x[0, 0] - model.nodes.x0[0, 0] - dx,
                        s.node_x[1, 0] - model.nodes.x0[1, 0] - dy)

    e1, e2, e3 = error(2e-3), error(1e-3), error(5e-4)
    assert e1 / e2 > 3.6 and e2 / e3 > 3.6


def test_the_step_resolves_the_gyration():
    """A charged node turns about B by at most courant × GYRATION_TURN a step (0.025 rad at
    the default courant): on the free sheet above, ω_c = 100 rad/s and yarns so soft that
    dt_max would allow 0.01 s, the step is courant · 0.1/ω_c = 2.5e-4 s, from the initial state
    (CentralDifference.stable_dt) and from every step after (the kick's rotation,
    nodes._kick_block), and half that in twice the field."""
    from emfabric._kernels.records import GYRATION_TURN

    for b0, courant in ((0.01, 0.25), (0.02, 0.25), (0.01, 0.5)):
        sc = _free_sheet(**{"fabric.velocity": [3.0, 0.0, 0.0], "field.B": [0.0, 0.0, b0],
                            "fabric.charge_per_node": 1.0, "solver.dt_max": 1e-2,
                            "solver.courant": courant})
        model, s = _march(sc, 3)
        wc = b0 / model.nodes.mass[0]
        assert GYRATION_TURN == 0.1
        assert s.last_dt == pytest.approx(courant * 0.1 / wc, rel=1e-12)
        assert s.dt == pytest.approx(courant * 0.1 / wc, rel=1e-12)
        assert s.t == pytest.approx(3 * courant * 0.1 / wc, rel=1e-12)


def test_a_spin_induced_in_a_strong_field_is_converged_at_the_default_step():
    """In 5 T the charged sheet's nodes gyrate at ω_c = 6e6 rad/s, about 3 rad in the step the
    yarns alone allow on this 14 × 14 sheet: without the gyration limit the sphere's induced
    ω_x was 84 % of its peak off the run at a quarter of the step (the error is first order in
    ω_c Δt, docs/theory.md §4.1). With it the default run is within 2 % of the run at a
    quarter of its step over the whole contact."""
    base = {"fabric.nodes": [14, 14], "field.B": [5.0, 0.0, 0.0], "solver.end_time": 3e-5}
    a = run(load_scenario("demo-small", base)).history
    b = run(load_scenario("demo-small", {**base, "solver.courant": 0.0625})).history
    wa, wb = a.angular_velocity.values[:, 0], b.angular_velocity.values[:, 0]
    peak = np.abs(wb).max()
    assert peak > 1000.0 and int(a.contact_nodes.max()) > 0
    err = np.abs(wa - np.interp(a.time.values, b.time.values, wb)).max()
    assert err < 0.02 * peak


def _struck(**kw):
    """A free 15 × 15 sheet struck obliquely by a spinning sphere, no field."""
    return make(**{"fabric.nodes": [15, 15], "fabric.edges": "free", "field.B": [0, 0, 0],
                   "projectile.velocity": [40.0, -25.0, -250.0],
                   "projectile.angular_velocity": [300.0, -200.0, 1000.0],
                   "projectile.gap": 0.0, "solver.end_time": 40e-6, **CD, **kw})


def test_free_fabric_struck_conserves_momentum():
    """Free sheet + spinning sphere struck obliquely, no field: linear momentum of the pair is
    conserved to round-off (the body receives exactly −J); angular momentum to a first-order
    error in Δt (the placement on the surface moves a node without momentum, as in the
    φ-scheme: test_impact.py), halving with the step. Putting a sliding or newly sticking
    node where the velocity after its impulse drifts it (docs/theory.md §5.2) is such a move:
    it raised the error at courant 0.5 from 2.4e-5 to 1.6e-4 of the initial angular momentum
    (7.8e-5, 3.9e-5, 2.0e-5 at 0.25, 0.125, 0.0625), while it brought paper-spin's ω 30× closer
    to the converged run at that step."""
    errors = []
    for courant in (0.5, 0.25, 0.125):
        ds = run(_struck(**{"solver.courant": courant, "solver.end_time": 60e-6})).history
        assert int(ds.contact_nodes.max()) >= 3
        p = ds.fabric_momentum.values + ds.projectile_momentum.values
        assert np.abs(p - p[0]).max() < 1e-14 * np.abs(p[0]).max()
        ang = ds.fabric_angular_momentum.values + ds.projectile_angular_momentum.values
        errors.append(np.linalg.norm(ang - ang[0], axis=1).max() / np.linalg.norm(ang[0]))
    assert errors[0] < 2e-4
    assert (errors[0] / errors[-1]) ** 0.5 >= 1.8, errors


def test_head_on_impact_spins_nothing_to_the_bit():
    """No field, no modulus scatter, head-on on a clamped sheet: ω stays exactly zero and the
    sphere moves exactly along −z (the mirror symmetries are kept to the bit)."""
    sc = make(**{"fabric.nodes": [16, 16], "fabric.material.modulus_cv": 0.0,
                 "field.B": [0, 0, 0], "projectile.gap": 0.0, "solver.end_time": 40e-6, **CD})
    ds = run(sc).history
    assert int(ds.contact_nodes.max()) >= 4
    assert np.all(ds.angular_velocity.values == 0.0)
    assert np.all(ds.projectile_velocity.values[:, :2] == 0.0)


def test_field_mirror_runs_mirror_to_the_bit():
    """B → −B (along x) mirrors the run in y: ω_x changes sign to the bit."""
    base = {"fabric.nodes": [14, 14], "fabric.material.modulus_cv": 0.0, "projectile.gap": 0.0,
            "solver.end_time": 30e-6, **CD}
    a = run(make(**base, **{"field.B": [0.05, 0, 0]})).history
    b = run(make(**base, **{"field.B": [-0.05, 0, 0]})).history
    assert float(np.abs(a.angular_velocity.values[:, 0]).max()) > 0.0
    np.testing.assert_array_equal(a.angular_velocity.values[:, 0],
                                  -b.angular_velocity.values[:, 0])
    np.testing.assert_array_equal(a.projectile_velocity.values[:, 2],
                                  b.projectile_velocity.values[:, 2])


def test_stable_step_of_a_sheet_at_rest():
    """At rest every interior node has four yarns of stiffness k = 𝔼A0/L0: the Gershgorin bound
    ω_max² = 2·4k/m gives the stable step 2/√(8k/m); courant takes that fraction."""
    sc = fabric_only(**{"fabric.nodes": [9, 9], **CD, "solver.courant": 0.5})
    model = build_model(sc)
    integ = CentralDifference(model)
    k = float(model.yarns.stiffness.max())
    m = float(model.nodes.mass[0])
    assert integ.stable_dt(initial_state(model)) == pytest.approx(
        min(0.5 * 2.0 / math.sqrt(8.0 * k / m), sc.solver.dt_max), rel=1e-12)


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_thin_fast_wire_does_not_tunnel(integrator):
    """A 0.1 mm wire at 1500 m/s lying across the yarns meets the fabric (the step keeps the
    body from moving more than a quarter of its radius per step, in both schemes) instead of
    passing between two steps."""
    sc = make(**{"fabric.nodes": [21, 21], "field.B": [0, 0, 0],
                 "projectile.shape": "cylinder", "projectile.radius": 5e-5,
                 "projectile.length": 0.02, "projectile.mass": 1e-3,
                 "projectile.axis": [1.0, 0.0, 0.0], "projectile.gap": 1e-4,
                 "projectile.velocity": [0.0, 0.0, -1500.0], "solver.end_time": 2e-6,
                 "solver.integrator": integrator})
    res = run(sc)
    assert int(res.history.contact_nodes.max()) > 0
    assert res.end_reason != "never touched"


@pytest.mark.parametrize("plies, integrator", [(1, "central-difference"),
                                               (2, "central-difference"), (1, "phi")])
def test_contact_counts_nodes_once_and_segments_apart(plies, integrator):
    """A wire lying along x, half a cell off a node row and three cells long with its ends in
    mid-cell, pressed flat onto the sheet (12.7 mm cells): it crosses exactly three of the
    y-yarns' segments and touches no node, so the history counts 3 segments and their 6 end
    nodes, all on the top ply, at every record where it touches (the step that meets them
    sends the six nodes ahead of the wire). The φ-scheme meets the three at once with a
    contraction no step size improves (the 1 g wire against their struck mass): it must
    complete with its patient steps (phi.Integrator.step), not stop at dt_min."""
    cell = 0.254 / 20
    sc = make(**{"fabric.nodes": [21, 21], "fabric.plies": plies, "field.B": [0, 0, 0],
                 "fabric.material.modulus_cv": 0.0, "projectile.shape": "cylinder",
                 "projectile.radius": 5e-5, "projectile.length": 3 * cell,
                 "projectile.mass": 1e-3, "projectile.axis": [1.0, 0.0, 0.0],
                 "projectile.position": [0.0, cell / 2, 1.5e-4],
                 "projectile.velocity": [0.0, 0.0, -300.0], "solver.end_time": 4e-6, **CD,
                 "solver.integrator": integrator})
    res = run(sc)
    assert res.status == "complete"
    h = res.history
    touching = h.contact_segments.values > 0
    assert touching.any()
    if integrator == "phi":
        # the implicit contact keeps the wire on the yarns after the first impulse (the outer
        # two may touch a step before the middle one again): 3 at most, 3 at the end
        assert h.contact_segments.values.max() == 3 and h.contact_segments.values[-1] == 3
    else:
        assert set(h.contact_segments.values[touching]) == {3}
    np.testing.assert_array_equal(h.contact_nodes.values, 2 * h.contact_segments.values)
    per_ply = h.contact_nodes_per_ply.values
    np.testing.assert_array_equal(per_ply[:, 0], h.contact_nodes.values)
    assert (per_ply[:, 1:] == 0).all()


def test_a_sticking_segment_keeps_its_material_point_on_the_face():
    """A free 10 × 10 sheet pushed up by an electric field against the flat end face of a
    heavy cylinder at rest (radius 3 mm, over the middle of one x-yarn segment, whose end nodes
    lie 5 mm off its axis: segment contact, no node contact), with a small sideways field
    component: the in-plane pull of the whole sheet on the segment (≈ 50 nodes × q E_y) is
    an eighth of the normal push of its two end nodes (2 q E_z), so Coulomb friction
    (μ_s = 1) holds it: it sticks. Sticking means no motion relative to the body: the
    segment's midpoint, in the body's frame, stays where it first touched, to round-off. A
    segment point put only on the closest surface point would keep the tangential drift of
    each free flight (Δt² F_t/m per step; 1.3 µm here over the 180 µs, at courant 0.25)."""
    from emfabric._kernels.records import BODY_R0, BODY_X

    sc = make(**{"fabric.nodes": [10, 10], "fabric.size": [0.09, 0.09],
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "field.B": [0, 0, 0],
                 "field.E": [0.0, 0.006, 1.2], "projectile.shape": "cylinder",
                 "projectile.radius": 0.003, "projectile.length": 0.02,
                 "projectile.mass": 5.0, "projectile.axis": [0, 0, -1],
                 "projectile.position": [0.0, 0.005, 0.01002],
                 "projectile.velocity": [0.0, 0.0, 0.0], **CD})
    model = build_model(sc)
    x0 = initial_state(model).arrays.x
    a = int(np.flatnonzero(np.isclose(x0[0], -0.005) & np.isclose(x0[1], 0.005))[0])
    b = int(np.flatnonzero(np.isclose(x0[0], 0.005) & np.isclose(x0[1], 0.005))[0])
    points = []
    histories = []
    for end in (2e-5, 1e-4, 2e-4):
        res = run(sc.replace(**{"solver.end_time": end}))
        histories.append(res.history)
        assert res.end_reason == "end_time"
        x, body = res.state.arrays.x, res.state.arrays.body
        assert int(res.history.contact_segments[-1]) == 1
        assert int(res.history.contact_nodes[-1]) == 2
        mid = 0.5 * (x[:, a] + x[:, b])
        points.append(body[BODY_R0:BODY_R0 + 3].T @ (mid - body[BODY_X]))
    # on the end face (10 mm below the centre of mass), over the axis in x by symmetry
    assert points[0][2] == pytest.approx(-0.01, abs=1e-12)
    for p in points[1:]:
        np.testing.assert_allclose(p, points[0], rtol=0, atol=1e-13)
    # a contact that sticks does not slip, so friction does no work on it: the friction booked
    # after the first touch stays where it was while the field does 0.27 J of work (the
    # impulses' identity split booked k|J_t|²/2 a step for it, 5.9e-7 J by 200 µs)
    fric = [float(h.dissipation_friction[-1]) for h in histories]
    work = float(histories[-1].work_field[-1])
    assert work > 0.2
    assert abs(fric[-1] - fric[0]) < 1e-7 * work


@pytest.mark.parametrize("pull", [2.4, 0.6])
def test_friction_work_of_a_sheet_struck_on_a_face(pull):
    """A rigid free 2 × 2 sheet (all nodes alike: no yarn stretches) pulled by E = (0, E_y, E_z)
    up across a 20 µm gap into the flat end face of a heavy cylinder at rest. Closed form per
    node (q, m): it arrives after t_c = √(2 g m/(q E_z)) at v_z = q E_z t_c/m, v_y = q E_y t_c/m.
    E_y = 2 E_z > μ_s E_z: the impact slides, v_y' = v_y − μ_d v_z, friction doing
    μ_d m v_z (v_y + v_y')/2; then it slides at a = q (E_y − μ_d E_z)/m, friction doing
    μ_d q E_z × the slip. E_y = E_z/2: the impact sticks (friction takes ½ m v_y²) and then
    it stays stuck: no slip, no more friction work. The friction booked must be that
    (measured 0.06 % and 0.35 % under at courant 0.25; the impulses' identity split booked
    k|J_t|²/2 a step more while it stuck: 3.7 % over at 5 µs, growing with time). No yarn
    stretches, so the energy balance closes to round-off: the field's and gravity's work are
    booked from the kicks, and the placement's work is the yarns' alone (with the field's
    too, the stuck sheet's balance error grew by h²|qE|²/2m a step and the divergence guard
    stopped it at 7.8 µs)."""
    gap, ez, end = 2e-5, 1.2, 20e-6
    sc = make(**{"fabric.nodes": [2, 2], "fabric.size": [0.002, 0.002],
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "field.B": [0, 0, 0],
                 "field.E": [0.0, pull, ez], "projectile.shape": "cylinder",
                 "projectile.radius": 0.004, "projectile.length": 0.02,
                 "projectile.mass": 5.0, "projectile.axis": [0, 0, -1],
                 "projectile.position": [0.0, 0.0, 0.01 + gap],
                 "projectile.velocity": [0.0, 0.0, 0.0], "solver.end_time": end, **CD})
    model = build_model(sc)
    q, m = float(model.nodes.charge[0]), float(model.nodes.mass[0])
    mu_s, mu_d = sc.contact.static_friction, sc.contact.dynamic_friction
    res = run(sc)
    h = res.history
    assert int(h.contact_nodes[-1]) == 4
    t = float(h.time[-1])
    tc = math.sqrt(2 * gap * m / (q * ez))
    vz, vy = q * ez * tc / m, q * pull * tc / m
    if pull > mu_s * ez:
        vy2 = vy - mu_d * vz
        a = q * (pull - mu_d * ez) / m
        tau = t - tc
        slip = vy2 * tau + 0.5 * a * tau ** 2
        exact = 4 * (mu_d * m * vz * 0.5 * (vy + vy2) + mu_d * q * ez * slip)
        assert float(np.mean(res.state.arrays.v[1])) == pytest.approx(vy2 + a * tau, rel=5e-3)
        # and where it slides: y = q E_y t_c²/2m + the slip. A node drifted with its velocity
        # before the friction impulse and then only projected runs ahead of it, by about
        # μ_d (q E_z/m) Δt² a step: a first-order error (measured 3.0e-3 of y at courant 0.25,
        # 7.4e-4 at 0.0625). It is put where the velocity after the impulse drifts it:
        # measured 3.3e-5 at both steps
        y = 0.5 * q * pull * tc ** 2 / m + slip
        assert float(np.mean(res.state.arrays.x[1])) == pytest.approx(y, rel=2e-4)
    else:
        exact = 4 * 0.5 * m * vy ** 2
        # stuck: v_{n+1} holds only the half kick of the last force (q E_y Δt/2m ≈ 0.05 m/s)
        assert abs(float(np.mean(res.state.arrays.v[1]))) < 1e-2 * vy
    assert float(h.dissipation_friction[-1]) == pytest.approx(exact, rel=1e-2)
    assert abs(float(h.energy_balance_error[-1])) < 1e-9 * float(h.work_field[-1])


@pytest.mark.parametrize("radius", [0.004, 0.0012])
@pytest.mark.parametrize("held", [False, True])
def test_a_slip_stops_when_kinetic_friction_has_taken_it(radius, held):
    """A rigid free 2 × 2 sheet (2 mm across, all nodes alike) sliding along y at v₀ = 10 m/s
    is pulled by E_z across a 2 µm gap onto the flat end face of a heavy cylinder at rest:
    on its four nodes (radius 4 mm), or, with radius 1.2 mm, on its four yarn segments only
    (their midpoints 1 mm from the axis, the nodes 1.41 mm). μ_s = 1, μ_d = 0.2. Closed form:
    the impact slides (v₀ is 1.6 times the normal speed it arrives with), and from then on
    friction's impulse is μ_d times the face's whole normal impulse q E_z t per node, so the
    slip is v(t) = v₀ − a t with a = μ_d q E_z/m, down to 0 at t* = m v₀/(μ_d q E_z), and then
    it stays stuck. Deciding each step's stick with μ_s, as the paper's law does, stopped every
    slip slower than (μ_s q E_z/m) Δt at once: here 3.1 steps early with 0.30 m/s (4.6 a Δt)
    of slip left. A contact that slid in the previous step now sticks only where μ_d times
    its normal impulse stops it (contact.KINETIC): it stops within the step that holds t*.
    held: at rest along y, with E_y = 0.6 E_z: the impact sticks (0.6 < μ_s) and static
    friction holds the sheet for good, though the pull is three times what kinetic friction
    could hold (a contact at rest is decided with μ_s)."""
    gap, ez, v0 = 2e-6, 1.2, 10.0
    mu_s, mu_d = 1.0, 0.2
    sc = make(**{"fabric.nodes": [2, 2], "fabric.size": [0.002, 0.002],
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "field.B": [0, 0, 0],
                 "field.E": [0.0, 0.6 * ez if held else 0.0, ez],
                 "fabric.velocity": [0.0, 0.0 if held else v0, 0.0],
                 "contact.static_friction": mu_s, "contact.dynamic_friction": mu_d,
                 "projectile.shape": "cylinder", "projectile.radius": radius,
                 "projectile.length": 0.02, "projectile.mass": 5.0,
                 "projectile.axis": [0, 0, -1], "projectile.position": [0.0, 0.0, 0.01 + gap],
                 "projectile.velocity": [0.0, 0.0, 0.0], "solver.end_time": 10e-6, **CD})
    model = build_model(sc)
    q, m = float(model.nodes.charge[0]), float(model.nodes.mass[0])
    h = run(sc).history
    assert int(h.contact_nodes[-1]) == 4
    assert int(h.contact_segments[-1]) == (4 if radius < 0.002 else 0)
    t, dt = h.time.values, float(np.median(h.dt))
    slip = h.fabric_momentum.values[:, 1] / (4 * m) - h.projectile_velocity.values[:, 1]
    tc = math.sqrt(2 * gap * m / (q * ez))
    if held:
        # stuck: the velocity at a whole step holds only the half kick of the pull, q E_y Δt/2m
        # (sliding, it would gain (0.6 − μ_d) q E_z/m × 9 µs = 34 m/s)
        assert np.abs(slip[t > tc + 2 * dt]).max() < 1.01 * 0.6 * q * ez * dt / (2 * m)
        return
    a = mu_d * q * ez / m
    t_stop = m * v0 / (mu_d * q * ez)
    assert v0 > mu_s * q * ez * tc / m  # the impact slides
    moving = np.flatnonzero(np.abs(slip) > 1e-3)
    last = int(moving.max())
    # it stops in the step that holds t*, from a slip kinetic friction takes within a step,
    # and stays stuck
    assert t[last] < t_stop <= t[last + 1]
    assert 0.0 < slip[last] < a * dt
    assert np.abs(slip[last + 1:]).max() < 1e-5
    # and until then it slides at v₀ − a t (central differences' velocities at whole steps
    # lag the friction's half-step impulse by a Δt/2)
    sliding = (t > tc + 2 * dt) & (t < t_stop - 2 * dt)
    assert sliding.sum() > 100
    np.testing.assert_allclose(slip[sliding], v0 - a * t[sliding], rtol=0, atol=0.6 * a * dt)


SMALL = {"fabric.nodes": [12, 12], "solver.end_time": 120e-6, "output.snapshot_interval": 5e-6,
         "projectile.gap": 0.0, **CD}


def test_ctrl_c_then_resume_is_bitwise_the_uninterrupted_run(tmp_path):
    """Central differences resume from a checkpoint to the uninterrupted run, bit for bit (the
    State holds each node's contact and material point)."""
    full = tmp_path / "full"
    run(load_scenario("demo-small", SMALL), full)
    part = tmp_path / "part"
    interrupted_demo(part, SMALL, after=25)
    resume(part)
    import xarray as xr

    for name in ("history.nc", "snapshots.nc"):
        x, y = xr.open_dataset(part / name), xr.open_dataset(full / name)
        assert x.sizes == y.sizes
        for v in y.variables:
            np.testing.assert_array_equal(x[v].values, y[v].values, err_msg=f"{name}: {v}")


def test_threaded_force_kernel_gives_identical_results():
    """The row-block threaded force kernel gives the serial kernel's run bit for bit: with
    brittle yarns (ε_f = 0.5 %: some break), their averaged stretch (written by each block,
    recomputed unwritten for a block's first row) and the bulk viscosity they get. (Eq. 2.6
    under threads: test_adaptive_threads_switch_kernels_without_changing_the_run.)"""
    sc = load_scenario("demo-small", {"fabric.nodes": [40, 40], "solver.end_time": 15e-6,
                                      "projectile.gap": 0.0, **CD,
                                      "fabric.damage.law": "brittle",
                                      "fabric.damage.failure_strain": 0.005})
    model = build_model(sc)
    states = []
    for threads in (False, True):
        integ = CentralDifference(model, threads=threads)
        s, s2 = initial_state(model), initial_state(model)
        while s.t < 15e-6:
            integ.step(s, s2)
            s, s2 = s2, s
        states.append(s)
    a, b = states
    assert a.steps == b.steps and a.contact_count > 0
    assert (a.seg_alpha == 0.0).sum() > 0 and a.seg_strain.shape == a.seg_alpha.shape
    for name in ("node_x", "node_v", "node_f", "seg_alpha", "body", "energy", "node_contact",
                 "seg_strain", "node_fv"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_adaptive_threads_switch_kernels_without_changing_the_run(monkeypatch):
    """With the thread count chosen at run time, the integrator probes the other node kernel
    every PROBE_EVERY steps and keeps the faster: the run uses both and is the serial run bit
    for bit; fed timings where threads lose, it ends on the serial kernel, and the reverse."""
    from emfabric.integrators import base

    monkeypatch.setattr(base, "PROBE_EVERY", 6)
    monkeypatch.setattr(base, "PROBE_STEPS", 2)
    monkeypatch.setattr(base, "PROBE_FIRST", 6)
    sc = load_scenario("demo-small", {"fabric.nodes": [24, 24], "solver.end_time": 8e-6,
                                      "projectile.gap": 0.0, **CD})
    model = build_model(sc)
    states, used = [], set()
    for adaptive in (False, True):
        integ = CentralDifference(model, threads=adaptive, adaptive=adaptive)
        s, s2 = initial_state(model), initial_state(model)
        while s.t < 8e-6:
            integ.step(s, s2)
            used.add(integ.threaded)
            s, s2 = s2, s
        states.append(s)
    assert used == {False, True}
    a, b = states
    for name in ("node_x", "node_v", "seg_alpha", "body", "energy"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for slow_threads in (True, False):
        integ = CentralDifference(model, threads=True, adaptive=True)
        for _ in range(60):
            integ._after_step(2.0 if integ.threaded == slow_threads else 1.0)
        while integ._probe_left:  # finish a probe under way
            integ._after_step(2.0 if integ.threaded == slow_threads else 1.0)
        assert integ.threaded is not slow_threads


def test_energy_balance_error_is_second_order():
    """The kicks and impulses book exactly the kinetic energy they change; what is left of the
    balance (the yarns' trapezoidal work) is the scheme's own error: 4× smaller per halving of
    Δt, through contact with friction, damage and the field (as a mean over three halvings:
    measured 4.9, 2.9, 4.9 — the error changes sign within the run)."""
    errors = []
    for courant in (0.5, 0.25, 0.125, 0.0625):
        sc = load_scenario("demo-small", {"solver.end_time": 50e-6,
                                          "projectile.gap": 0.0, "solver.courant": courant,
                                          **CD})
        ds = run(sc).history
        assert int(ds.contact_nodes.max()) > 8
        errors.append(float(np.abs(ds.energy_balance_error.values).max()))
        exchanged = float(ds.kinetic_energy_projectile[0] - ds.kinetic_energy_projectile[-1])
    assert errors[0] < 2e-3 * exchanged
    assert (errors[0] / errors[-1]) ** (1 / 3) > 3.5, errors


def test_default_integrator_and_what_chooses_the_phi_scheme():
    """Central differences by default; a key only the φ-scheme reads (solver.phi, tolerance, …,
    contact.placement) chooses it when no integrator is written; a written integrator wins; the
    φ-scheme's placement option with central differences is an error naming the key."""
    from emfabric.config.scenario import ScenarioError

    assert load_scenario("paper-field").solver.integrator == "central-difference"
    for key, value in (("solver.phi", 1.0), ("solver.tolerance", 1e-8),
                       ("solver.target_iterations", 4), ("contact.placement", "closest-point")):
        assert load_scenario("paper-field", {key: value}).solver.integrator == "phi", key
        both = {key: value, "solver.integrator": "central-difference"}
        if key != "contact.placement":
            assert load_scenario("paper-field", both).solver.integrator == "central-difference"
    assert load_scenario("paper-field", {"solver.dt_max": 1e-7}).solver.integrator == \
        "central-difference"
    with pytest.raises(ScenarioError, match="contact.placement"):
        load_scenario("paper-field", {"contact.placement": "closest-point", **CD})


def test_step_below_dt_min_stops_with_a_clear_error():
    """A stable step below solver.dt_min stops the run at once, saying so."""
    from emfabric.integrators import DivergenceError

    sc = load_scenario("demo-small", {"solver.dt_min": 5e-7, "solver.end_time": 2e-6, **CD})
    with pytest.raises(DivergenceError, match="below solver.dt_min"):
        run(sc)


@pytest.mark.parametrize("threads", [False, True])
def test_history_diagnostics_from_the_kick_equal_a_separate_pass(threads):
    """The step kernel's kick leaves the fabric diagnostics of the end state (kinetic energy,
    momenta, strain energy, stretch, broken yarns, extent...) and the next step's
    no-tunnelling limit on its way; they equal diagnostics.fabric_diagnostics and
    contact.travel_step computed afresh on that state: the maxima, minima and counts exactly,
    the sums to round-off (summed per grid row, then over rows). A 2-ply pack struck hard
    enough to break yarns (brittle KM2), with a field."""
    from emfabric._kernels.contact import travel_step
    from emfabric._kernels.diagnostics import (
        AHEAD_MAX,
        AHEAD_MIN,
        APPROACH_MAX,
        BROKEN,
        COUNT,
        DEFLECTION,
        KE,
        LX,
        MIN_ALPHA,
        PX,
        RECEDE_MAX,
        STRAIN,
        STRETCH,
        fabric_diagnostics,
    )
    from emfabric._kernels.explicit import _travel_from_rows

    sc = load_scenario("pack-fsp", {"fabric.plies": 2, "fabric.nodes": [21, 21],
                                    "projectile.velocity": [0.0, 0.0, -1500.0], **CD})
    model = build_model(sc)
    integ = CentralDifference(model, threads=threads)
    s, s2 = initial_state(model), initial_state(model)
    ref = np.empty(COUNT)
    broke = 0.0
    while s.steps < 200:
        integ.step(s, s2)
        s, s2 = s2, s
        got = integ.fabric_of(s)
        assert got is not None and integ.fabric_of(s2) is None
        fabric_diagnostics(model.physics, s.node_x, s.node_v, s.seg_alpha, s.body_x,
                           model.flight_direction, ref)
        for k in (DEFLECTION, STRETCH, BROKEN, MIN_ALPHA, AHEAD_MIN, AHEAD_MAX, APPROACH_MAX,
                  RECEDE_MAX):
            assert got[k] == ref[k], k
        m = model.nodes.mass
        speed = np.linalg.norm(s.node_v, axis=0)
        assert got[KE] == pytest.approx(ref[KE], rel=1e-12, abs=1e-300)
        assert got[STRAIN] == pytest.approx(ref[STRAIN], rel=1e-12, abs=1e-300)
        np.testing.assert_allclose(got[PX:PX + 3], ref[PX:PX + 3], rtol=0,
                                   atol=1e-13 * float(m @ speed))
        arm = np.linalg.norm(s.node_x, axis=0)
        np.testing.assert_allclose(got[LX:LX + 3], ref[LX:LX + 3], rtol=0,
                                   atol=1e-13 * float(m @ (arm * speed)))
        assert _travel_from_rows(model.physics, integ.work.row_sums, model.ny, s.body) == \
            travel_step(model.physics, s.node_x, s.node_v, s.body)
        broke = max(broke, ref[BROKEN])
    assert broke > 0, "no yarn broke: the test does not test the broken-yarn terms"
