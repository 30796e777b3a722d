"""Time integration (section 3): order of the φ-scheme, energy under B, step control, damage."""

import math

import numpy as np
import pytest

from emfabric.integrators import DivergenceError, Integrator, step_factor
from emfabric.runner.loop import run
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state, update_forces

from conftest import fabric_only, make


def _prestretched(phi, dt, **kw):
    """A clamped 6×6 sheet pre-stretched by 2 % with an out-of-plane velocity bump: every yarn
    stays in tension, so the problem is smooth (no relaxed-law kink, no damage)."""
    sc = fabric_only(**{
        "fabric.nodes": [6, 6], "fabric.size": [0.05, 0.05], "solver.phi": phi,
        "solver.adaptive": False, "solver.dt_max": dt, "solver.tolerance": 1e-11,
        "solver.max_iterations": 400, **kw,
    })
    model = build_model(sc)
    s = initial_state(model)
    s.node_x[:2] *= 1.02
    r2 = (model.nodes.x0[0] ** 2 + model.nodes.x0[1] ** 2) / 0.02**2
    s.node_v[2] = 40.0 * np.exp(-r2) * (model.nodes.inv_mass > 0)
    update_forces(model, s)
    return model, s


def _solve(phi, dt, t_end=4e-6, **kw):
    model, s = _prestretched(phi, dt, **kw)
    integ = Integrator(model)
    s2 = s.copy()
    for _ in range(round(t_end / dt)):
        integ.step(s, s2)
        s, s2 = s2, s
    return s.node_x.copy()


@pytest.mark.parametrize("phi,order", [(0.5, 2.0), (1.0, 1.0)])
def test_convergence_order(phi, order):
    """φ = 0.5 is second order in Δt, φ = 1 first order (fixed step, smooth problem)."""
    dts = [8e-8, 4e-8, 2e-8]
    ref = _solve(phi, 2.5e-9)
    errs = [np.abs(_solve(phi, dt) - ref).max() for dt in dts]
    rates = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(abs(r - order) < 0.25 for r in rates), (errs, rates)


def _energy_drift(dt):
    sc = fabric_only(**{
        "fabric.nodes": [7, 7], "fabric.size": [0.05, 0.05], "fabric.velocity": [0, 0, 200.0],
        "field.B": [0.3, -0.2, 0.5], "fabric.charge_per_node": 0.5, "solver.adaptive": False,
        "solver.dt_max": dt, "solver.tolerance": 1e-12, "solver.max_iterations": 400,
        "solver.end_time": 10e-6,
    })
    ds = run(sc).history
    total = (ds.kinetic_energy_fabric + ds.strain_energy).values
    return np.abs(total - total[0]).max() / total[0], ds


def test_magnetic_force_does_no_work():
    """A clamped sheet released with a velocity in pure B keeps KE + strain energy to O(Δt²)."""
    e1, ds = _energy_drift(4e-8)
    e2, _ = _energy_drift(2e-8)
    # the yarns really work: part of the kinetic energy goes into strain
    assert float(ds.strain_energy.max()) > 0.05 * float(ds.kinetic_energy_fabric[0])
    assert e1 < 1e-3
    assert e1 / e2 > 3.0  # second order: halving Δt quarters the drift


def test_backward_euler_dissipates_as_its_closed_form_and_runs():
    """φ = 1 under a constant force from rest (a free, charged 3 × 3 sheet in uniform E, no
    yarn stretched): v_n = naΔt and x_n = aΔt²n(n + 1)/2, so the balance error after n steps
    is −1/(n + 1) of the field's work, −50 % after the first, at any Δt. That is the scheme's
    own dissipation, not a divergence: the run completes (the energy guard counts only a gain
    for φ > 1/2), where it was stopped as diverged at its first step."""
    sc = fabric_only(**{"fabric.nodes": [3, 3], "fabric.size": [0.01, 0.01],
                        "fabric.edges": "free", "fabric.charge_per_node": 1.0,
                        "field.E": [0.0, 0.0, 1.0], "solver.integrator": "phi",
                        "solver.phi": 1.0, "solver.adaptive": False, "solver.dt_max": 1e-6,
                        "solver.dt_initial": 1e-6, "solver.end_time": 2e-5})
    res = run(sc)
    ds = res.history
    assert ds.attrs["status"] == "complete"
    n = np.rint(ds.time.values / 1e-6)
    assert np.array_equal(n, np.arange(21))
    work = ds.work_field.values[1:]
    assert np.allclose(ds.energy_balance_error.values[1:], -work / (n[1:] + 1), rtol=1e-9)
    assert work[0] > 0.0


def test_step_factor_formula():
    """Φ_K of eq. 3.9 with ϖ_0 = 1: shrink when K_d is exceeded, grow when met early."""
    tol, kd, p = 1e-6, 6, 2.0
    assert step_factor(1e-6, 6, tol, kd, p) == pytest.approx(1.0)
    assert step_factor(1e-8, 3, tol, kd, p) > 1.0
    assert step_factor(1e-3, 6, tol, kd, p) < 1.0
    assert step_factor(1e-3, 6, tol, kd, p) == pytest.approx((tol / 1e-3) ** (1 / 12))


def _paper_sheet(**kw):
    """A 16×16 patch with the paper's node spacing and node mass (its stiffness/mass ratio), run
    by the φ-scheme (this module's subject)."""
    h = 0.254 / 99
    return fabric_only(**{"fabric.nodes": [16, 16], "fabric.size": [15 * h, 15 * h],
                          "fabric.velocity": [0, 0, 50.0], "solver.integrator": "phi", **kw})


def test_controller_history_follows_eq_3_9():
    """history.nc obeys eq. 3.9: after an accepted step Δt_next = min(dt_max, 0.9 Φ_K(ϖ, K) Δt)."""
    h = 0.254 / 99
    sc = _paper_sheet(**{"solver.end_time": 3e-5})
    # at the paper's dt_max the fixed-point map does not contract: ρ ≈ φ²Δt²·4k/m (the largest
    # in-plane mode of the yarn lines, MODEL §3) is above 1, so the first attempt must be rejected
    fab = sc.fabric
    k = fab.material.youngs_modulus * math.pi * fab.yarn_radius**2 / h
    m = fab.areal_density * fab.size[0] * fab.size[1] / (fab.nodes[0] * fab.nodes[1])
    assert 0.5**2 * 1e-6**2 * 4 * k / m > 1.0
    ds = run(sc).history
    dt, it, err = ds.dt.values, ds.iterations.values, ds.error.values
    rejected = np.diff(ds.rejected_steps.values)  # rejected attempts before each accepted step
    assert rejected[0] >= 1 and dt[1] < 0.9 ** rejected[0] * 1e-6
    tol, k_d, p, safety, dt_max = 1e-6, 6, 2.0, 0.9, 1e-6
    # eq. 3.9 with ϖ_0 = 1, written out here (not the package's step_factor)
    phi_k = tol ** (1 / (p * k_d)) / err[1:-1] ** (1 / (p * it[1:-1]))
    proposed = np.minimum(dt_max, dt[1:-1] * safety * phi_k)
    after = rejected[1:]  # the last step is cut to end_time: not a proposal
    taken = dt[2:]
    clean = after == 0
    clean[-1] = False
    assert clean.sum() > 50 and (after > 0).sum() > 3  # both branches are exercised
    np.testing.assert_allclose(taken[clean], proposed[clean], rtol=1e-13)
    # a rejection multiplies by 0.9 (TOL/ϖ_Kd)^(1/(p K_d)) < 0.9 (ϖ_Kd > TOL)
    assert np.all(taken[after > 0] < 0.9 ** after[after > 0] * proposed[after > 0])


N_MODE, H_MODE, U_MODE = 9, 2.0**-7, 1.25


def _mode_problem(p, q, **kw):
    """A clamped 9×9 sheet stretched uniformly to U = 1.25 (exact binary coordinates, so every
    in-plane force balances to the bit) with the out-of-plane velocity of the membrane mode
    (p, q). Its deflection (about 1e-11 m) changes no yarn length within round-off: the step
    is exactly linear, m z̈ = −K z, with K the tension over length T/L = 𝔼A0(U²−1)/(2L0) of
    each yarn on a 5-point Laplacian. Returns the model, the state and the mode's eigenvalue
    λ of K/m."""
    size = (N_MODE - 1) * H_MODE
    sc = fabric_only(**{"fabric.nodes": [N_MODE, N_MODE], "fabric.size": [size, size], **kw})
    model = build_model(sc)
    s = initial_state(model)
    s.node_x[:2] *= U_MODE
    i, j = np.arange(model.node_count) % N_MODE, np.arange(model.node_count) // N_MODE
    shape = np.sin(p * np.pi * i / (N_MODE - 1)) * np.sin(q * np.pi * j / (N_MODE - 1))
    s.node_v[2] = 1e-5 * shape * (model.nodes.inv_mass > 0)
    update_forces(model, s)
    fab = sc.fabric
    k_z = fab.material.youngs_modulus * math.pi * fab.yarn_radius**2 * (U_MODE**2 - 1) / (
        2 * H_MODE)
    mass = fab.areal_density * size * size / N_MODE**2
    lam = 4 * k_z / mass * (math.sin(p * math.pi / (2 * (N_MODE - 1))) ** 2
                            + math.sin(q * math.pi / (2 * (N_MODE - 1))) ** 2)
    return model, s, lam


def _mode_error(rho, k):
    """ϖ_K of a linear fixed-point map x ← b − ρ x started at ϖ_0's iterate (the start state):
    increments δ_K = (−ρ)^(K−1) δ_1, so ϖ_K = |δ_K| / |Σ δ| = ρ^(K−1) (1 + ρ) / |1 − (−ρ)^K|."""
    return rho ** (k - 1) * (1 + rho) / abs(1 - (-rho) ** k)


@pytest.mark.parametrize("phi,p,q,rho", [(0.5, 7, 7, 0.2), (1.0, 3, 5, 0.35)])
def test_fixed_point_contracts_at_its_constant(phi, p, q, rho):
    """On a linear mode the iteration contracts by ρ = φ²Δt²λ per sweep: ϖ_K and K as predicted."""
    _, _, lam = _mode_problem(p, q)
    dt = math.sqrt(rho / lam) / phi
    for k in range(2, 10):
        # a tolerance between ϖ_(K−1) and ϖ_K: the iteration must stop at exactly K
        tol = math.sqrt(_mode_error(rho, k) * _mode_error(rho, k - 1))
        model, s, _ = _mode_problem(p, q, **{
            "solver.phi": phi, "solver.adaptive": False, "solver.dt_max": dt,
            "solver.tolerance": tol, "solver.max_iterations": 50})
        info = Integrator(model).step(s, s.copy())
        assert info.iterations == k
        assert info.error == pytest.approx(_mode_error(rho, k), rel=1e-9)


def _controller(dt, lam, steps, *, tol=1e-6, k_d=6, p=2.0, safety=0.9, dt_max, phi=0.5):
    """MODEL §3 / eq. 3.9 played out with the closed-form ϖ_K of the mode: per accepted step
    (Δt, K, ϖ_K, rejected attempts), and the smallest |log(ϖ_K/TOL)| met on the way."""
    out, margin = [], math.inf
    for _ in range(steps):
        rejected = 0
        while True:
            rho = phi**2 * dt**2 * lam
            errs = [_mode_error(rho, k) for k in range(1, k_d + 1)]
            margin = min([margin] + [abs(math.log(e / tol)) for e in errs])
            k = next((k for k, e in enumerate(errs, 1) if e <= tol), None)
            if k is not None:
                break
            dt *= safety * tol ** (1 / (p * k_d)) / errs[-1] ** (1 / (p * k_d))
            rejected += 1
        out.append((dt, k, errs[k - 1], rejected))
        dt = min(dt_max, dt * safety * tol ** (1 / (p * k_d)) / errs[k - 1] ** (1 / (p * k)))
    return out, margin


@pytest.mark.parametrize("rho0,dt_max", [(1.5, 4e-6), (2e-3, 4e-7)])
def test_step_control_follows_eq_3_9_on_a_linear_mode(rho0, dt_max):
    """Δt, K, ϖ and rejections of 25 steps equal eq. 3.9 played out with ϖ_K's closed form."""
    _, _, lam = _mode_problem(7, 7)
    dt0 = math.sqrt(rho0 / lam) / 0.5  # ρ0 = 1.5: diverges, rejected; 2e-3: grows to dt_max
    expected, margin = _controller(dt0, lam, 25, dt_max=dt_max)
    assert margin > 0.05  # no decision of the prediction is within 5 % of TOL
    model, s, _ = _mode_problem(7, 7, **{"solver.dt_max": dt_max, "solver.dt_initial": dt0})
    integ = Integrator(model)
    s2 = s.copy()
    for dt, k, err, rejected in expected:
        info = integ.step(s, s2)
        s, s2 = s2, s
        assert (info.iterations, info.rejected) == (k, rejected)
        assert info.dt == pytest.approx(dt, rel=1e-9)
        assert info.error == pytest.approx(err, rel=1e-7)
    if rho0 > 1:
        assert expected[0][3] > 0  # the first attempts do not contract: rejected
    else:
        assert expected[-1][0] == dt_max  # grown until dt_max caps it


def test_controller_grows_small_steps():
    """A step far below what the iteration needs is grown (fewer than K_d iterations)."""
    sc = _paper_sheet(**{"solver.end_time": 0.5e-6, "solver.dt_initial": 1e-10})
    ds = run(sc).history
    dt = ds.dt.values[1:]
    assert dt[0] == pytest.approx(1e-10)
    assert dt[-1] > 10 * dt[0]
    assert int(ds.iterations[1]) < 6


def test_dt_min_stops_with_a_clear_error():
    """A step that cannot converge even at dt_min stops with time, Δt and the largest force."""
    sc = _paper_sheet(**{"solver.dt_min": 5e-7, "solver.end_time": 2e-6})
    with pytest.raises(DivergenceError) as info:
        run(sc)
    msg = str(info.value)
    assert "t = 0 s" in msg and "dt_min" in msg and "largest force" in msg
    # the step it stopped at, in the message and on the error
    assert f"Δt = {info.value.dt:.3g} s" in msg and 0.0 < info.value.dt < 5e-7
    assert info.value.result.status == "diverged"


def test_a_failed_step_names_a_free_node():
    """The node a failed step names is the free node with the largest force: a clamped node's
    force is a reaction that drives nothing. A clamped sheet in E = 100 V/m whose φ-step cannot
    meet a tolerance below round-off (1e-13) named node 2, on the clamped edge j = 0, where
    every charged node carries the same q E."""
    sc = make(**{"fabric.nodes": [10, 10], "fabric.size": [0.1, 0.1],
                 "projectile.shape": "none", "fabric.charge_per_node": 1.0,
                 "fabric.material.modulus_cv": 0.0,
                 "field.B": [0.0, 0.0, 0.0], "field.E": [0.0, 0.0, 100.0],
                 "fabric.damage.rate": 0.0, "solver.integrator": "phi",
                 "solver.adaptive": False, "solver.dt_max": 1.5e-8,
                 "solver.tolerance": 1e-13, "solver.end_time": 3e-6})
    with pytest.raises(DivergenceError) as info:
        run(sc)
    assert "largest force" in str(info.value)
    assert build_model(sc).nodes.inv_mass[info.value.node] > 0


def test_a_non_finite_step_says_where_it_went_non_finite():
    """A field too strong for the numbers (|B| overflows in q B Δt / m) makes the first step
    non-finite everywhere but at the clamped edge: the message names a free node whose
    position went non-finite, not only the largest force of the state before (an edge node's
    1e-10 N here)."""
    sc = make(**{"fabric.nodes": [10, 10], "field.B": [1e300, 0.0, 0.0],
                 "solver.end_time": 2e-6})
    with pytest.raises(DivergenceError) as info:
        run(sc)
    msg = str(info.value)
    assert "non-finite values in an explicit step" in msg
    assert "the first non-finite position is node 11's (grid i=1, j=1)" in msg


def test_damage_is_monotone_and_rejected_steps_leave_it():
    """Damage never heals, and a rejected attempt (which over-stretches) does not commit α."""
    sc = _paper_sheet(**{"fabric.velocity": [0, 0, 400.0], "fabric.damage.rate": 30.0,
                         "fabric.damage.critical_stretch": 1.005, "solver.end_time": 3e-6,
                         "output.snapshot_interval": 0.2e-6})
    res = run(sc)
    assert int(res.history.rejected_steps[-1]) > 0
    assert float(res.history.min_damage[-1]) < 0.9
    model = res.model
    # replay: every accepted step's α equals the damage law at the accepted positions
    s = initial_state(model)
    integ = Integrator(model)
    s2 = s.copy()
    prev = s.seg_alpha.copy()
    uc, lam = 1.005, 30.0
    a, b = model.yarns.ends.T
    for _ in range(40):
        info = integ.step(s, s2)
        s, s2 = s2, s
        assert np.all(s.seg_alpha <= prev)
        u = np.linalg.norm(s.node_x[:, b] - s.node_x[:, a], axis=0) / model.yarns.rest_length
        law = np.minimum(prev, np.where(u > uc, np.exp(-lam * (u - uc) / uc), 1.0))
        # α is committed from the last force evaluation of the accepted attempt (within TOL)
        assert np.allclose(s.seg_alpha, law, atol=1e-4)
        prev = s.seg_alpha.copy()
        if info.rejected:
            break
    else:
        pytest.fail("expected at least one rejected attempt in the replay")


def test_threaded_kernel_gives_identical_results():
    """The row-block threaded kernel reproduces the serial one bit for bit (any thread count)."""
    sc = _paper_sheet(**{"fabric.nodes": [23, 37], "fabric.material.modulus_cv": 0.1,
                         "field.B": [0.02, 0.03, 0.05], "fabric.damage.rate": 5.0,
                         "fabric.damage.critical_stretch": 1.001})
    model = build_model(sc)
    runs = []
    for threads in (False, True):
        integ = Integrator(model, threads=threads)
        assert (integ.threads is not None) == threads and (integ.rowbuf is None) == threads
        s = initial_state(model)
        s2 = s.copy()
        for _ in range(30):
            integ.step(s, s2)
            s, s2 = s2, s
        runs.append(s)
    a, b = runs
    np.testing.assert_array_equal(a.node_x, b.node_x)
    np.testing.assert_array_equal(a.node_v, b.node_v)
    np.testing.assert_array_equal(a.seg_alpha, b.seg_alpha)
    assert a.t == b.t and a.evaluations == b.evaluations
    assert float(a.seg_alpha.min()) < 1.0


def test_predictor_changes_the_start_not_the_solution():
    """The explicit predictor x0 + Δt v0 + φΔt² ψ/m starts the iteration O(Δt³) from the fixed
    point instead of O(Δt) (x0): the same solution to the tolerance, in fewer iterations."""
    results = {}
    for predictor in ("explicit", "start"):
        model, s = _prestretched(0.5, 4e-8, **{"solver.predictor": predictor})
        integ = Integrator(model)
        s2 = s.copy()
        iterations = 0
        for _ in range(50):
            iterations += integ.step(s, s2).iterations
            s, s2 = s2, s
        results[predictor] = (s.node_x.copy(), iterations)
    (xe, ke), (xs, ks) = results["explicit"], results["start"]
    scale = np.abs(xs).max()
    assert np.abs(xe - xs).max() < 1e-9 * scale
    assert ke < 0.8 * ks, (ke, ks)


def test_step_factor_at_the_ends_of_a_doubles_range():
    """Eq. 3.9 with a tiny exponent p puts ϖ^(1/(pK)) beyond a double's range: the factor is
    then inf (ϖ < 1: the power underflows to 0) or 0 (ϖ > 1: it overflows), not an exception;
    at the paper's p = 2 it is the formula's value."""
    from emfabric.integrators.phi import step_factor

    assert step_factor(0.5, 6, 1e-6, 6, 1e-5) == math.inf
    assert step_factor(2.0, 6, 1e-6, 6, 1e-5) == 0.0
    assert step_factor(1e-4, 6, 1e-6, 6, 2.0) == (1e-6 ** (1 / 12)) / (1e-4 ** (1 / 12))
