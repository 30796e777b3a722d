"""The stop rule's energy bound (emfabric.sim.reach): how far a clamped sheet can ever reach with
the energy it has, against closed forms, and a field-driven run that ends when the projectile
has left for good although the charged sheet keeps ringing in the field."""

import math

import numpy as np
import pytest

from emfabric._kernels.reach import fabric_reach, two_ball_max
from emfabric.config.scenario import load_scenario
from emfabric.runner.loop import run


def _three_by_three(a: float):
    """A 3 × 3 clamped grid of spacing a (records' layout): only the centre node is free, on
    one warp and one fill yarn of two segments each."""
    rows = np.array([[0, 3, 0, 6], [3, 3, 2, 9], [6, 3, 4, -1]], dtype=np.int64)
    ply_rows = np.array([0, 3], dtype=np.int64)
    i, j = np.meshgrid(np.arange(3), np.arange(3))
    x0 = np.vstack([(i.ravel() - 1) * a, (j.ravel() - 1) * a, np.zeros(9)])
    inv_mass = np.zeros(9)
    inv_mass[4] = 1.0
    rest = np.full(12, a)
    return rows, ply_rows, x0, inv_mass, rest


def test_two_balls():
    """The top of the intersection of two balls: a lens between two equal balls peaks at
    √(r² − (d/2)²) over the midpoint; a ball inside the other gives its own top."""
    e = np.array([0.0, 0.0, 1.0])
    c1, c2 = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    assert two_ball_max(c1, 1.5, c2, 1.5, e) == pytest.approx(math.sqrt(1.5 ** 2 - 1.0))
    assert two_ball_max(c1, 5.0, c2, 0.5, e) == pytest.approx(0.5)
    # along the line of centres: the nearer ball's far side
    assert two_ball_max(c1, 1.5, c2, 1.5, np.array([1.0, 0.0, 0.0])) == pytest.approx(0.5)


def test_a_node_between_four_clamps_reaches_the_height_its_energy_allows():
    """The centre of a 3 × 3 clamped grid (four KSV segments of stiffness k and length a)
    lifted to z stores 4 · k a² ((U² − 1)/2)²/2 = k z⁴/(2a²): with energy E it reaches
    z* = (2a²E/k)^(1/4). The bound uses the linear spring below the law (equal to it at small
    strain) and shares E between the four half-yarns in intervals: it must lie above z* and
    within a few per cent of it at small strain; an oblique direction gives at least the
    projection, and a broken yarn leaves the other to bound it."""
    a, k = 0.01, 1.0e6
    rows, ply_rows, x0, inv_mass, rest = _three_by_three(a)

    def reach(keff, energy, e, limit):
        return fabric_reach(rows, ply_rows, x0, inv_mass, rest, keff, energy, e, limit, 4)

    keff = np.full(12, k)
    up = np.array([0.0, 0.0, 1.0])
    for energy in (1e-3, 1e-1):
        z_star = (2.0 * a * a * energy / k) ** 0.25
        # below the limit the kernel shares the energy (above it, it gives up: +inf)
        bound = reach(keff, energy, up, 1.05 * z_star)
        assert z_star <= bound <= 1.05 * z_star
        assert reach(keff, energy, up, 0.999 * z_star) == math.inf
    # a direction at 60° to the normal: at least the projection of the height reached
    oblique = np.array([math.sqrt(0.75), 0.0, 0.5])
    z_star = (2.0 * a * a * 1e-3 / k) ** 0.25
    assert reach(keff, 1e-3, oblique, 1.0) >= 0.5 * z_star
    # the fill yarn broken: the warp alone (two halves sharing E) bounds the node
    energy = 1e-3
    broken = keff.copy()
    broken[6 + 1] = 0.0  # fill segment from node 1 to node 4
    alone = reach(broken, energy, up, 1.0)
    # two linear halves: 2 · ½ k (√(a² + z²) − a)² = E
    z_two = math.sqrt((a + math.sqrt(energy / k)) ** 2 - a * a)
    assert z_two * (1 - 1e-12) <= alone <= 1.1 * z_two
    # both yarns broken: nothing holds the node, no bound
    broken[2 + 1] = 0.0  # warp segment from node 4 to node 5
    assert reach(broken, energy, up, 1.0) == math.inf


def test_a_field_driven_rebound_stops_when_the_sheet_cannot_reach_the_projectile(monkeypatch):
    """The paper's sphere rebounds from a charged 20 × 20 sheet in B = 0.2 T: the sheet keeps
    gyrating faster than the sphere recedes, so the rule 'every node behind and slower' never
    passes and the run used to go on to end_time. The energy bound ends it as a rebound; the
    same run without the bound, continued to end_time, never brings a node within reach of the
    sphere after the stop."""
    import emfabric.sim.diagnostics as diag

    overrides = {"fabric.nodes": [20, 20], "field.B": [0.2, 0.0, 0.0],
                 "solver.end_time": 2.5e-3, "output.paraview": False}
    stopped = run(load_scenario("paper-field", overrides), None)
    assert stopped.end_reason == "rebound"
    t_stop = stopped.state.t
    assert t_stop < 0.6 * 2.5e-3
    monkeypatch.setattr(diag, "out_of_reach", lambda *args: False)
    full = run(load_scenario("paper-field", overrides), None)
    assert full.end_reason == "end_time"  # the old rule alone does not stop it
    h = full.history.sel(time=slice(t_stop, None))
    radius = stopped.model.geometry.bound
    gap = h.projectile_position.values[:, 2] - radius - h.max_deflection.values
    assert (h.contact_nodes.values == 0).all()
    assert gap.min() > 0.0
    # the same state where both runs stopped checking (determinism of the schedule)
    np.testing.assert_array_equal(
        full.history.sel(time=t_stop).projectile_velocity.values,
        stopped.history.projectile_velocity.values[-1])
