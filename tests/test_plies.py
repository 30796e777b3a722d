"""Packs of plies (issue 23): the pack as data, ply-to-ply contact, and the physics a pack must
keep: momentum, mirror symmetry, plies that do not pass through each other, plies that do not
move before something reaches them, a pack that acts as one thick ply when it sticks together."""

import math

import numpy as np
import pytest
import xarray as xr
from matplotlib.tri import LinearTriInterpolator, Triangulation

from emfabric._kernels.records import BODY_W
from emfabric.config.scenario import ScenarioError, load_scenario
from emfabric.runner.loop import run
from emfabric.sim.builder import build_model

from conftest import make

SIZE = 0.1
NODES = 21
H = SIZE / (NODES - 1)


def _pack(**kw):
    """A small pack of the paper's fabric (no scatter, no field) under a 1 cm sphere."""
    return make(**{"fabric.nodes": [NODES, NODES], "fabric.size": [SIZE, SIZE],
                   "fabric.rescale": False, "fabric.material.modulus_cv": 0.0,
                   "fabric.plies": 3, "field.B": [0.0, 0.0, 0.0], "projectile.radius": 0.01,
                   "projectile.mass": 0.01, "projectile.velocity": [0.0, 0.0, -200.0],
                   "solver.end_time": 40e-6, "output.snapshot_interval": 5e-6, **kw})


def test_a_pack_is_plies_of_the_sheet():
    """Three plies of one sheet: three times its nodes and segments, each ply its own block,
    ply 1 at z = 0 and the others touching below it (the sum of the yarn radii apart)."""
    one = build_model(_pack(**{"fabric.plies": 1}))
    three = build_model(_pack())
    assert three.node_count == 3 * one.node_count
    assert three.seg_count == 3 * one.seg_count
    np.testing.assert_array_equal(three.nodes.ply_nodes, [0, 441, 882, 1323])
    np.testing.assert_array_equal(three.yarns.ply_segments, np.arange(4) * 2 * 21 * 20)
    r = 0.000185
    z = three.nodes.x0[2, three.nodes.ply_nodes[:-1]]
    np.testing.assert_allclose(z, [0.0, -2 * r, -4 * r], rtol=1e-12)
    np.testing.assert_array_equal(three.node_ply(), np.repeat([0, 1, 2], 441))
    # the same sheet in every ply: positions in the plane, masses, stiffness
    for p in range(3):
        sl = slice(441 * p, 441 * (p + 1))
        np.testing.assert_array_equal(three.nodes.x0[:2, sl], one.nodes.x0[:2])
        np.testing.assert_array_equal(three.nodes.mass[sl], one.nodes.mass)
    np.testing.assert_allclose(three.contact.ply_gap, [2 * r, 2 * r], rtol=1e-12)


def test_ply_tables_override_the_fabric():
    sc = _pack(**{"fabric.ply": [{"areal_density": 0.2}, {}, {"yarn_radius": 0.0003}]})
    m = build_model(sc)
    assert sc.fabric.plies == 3
    mass = m.nodes.mass
    assert mass[0] == pytest.approx(0.2 * SIZE**2 / NODES**2, rel=1e-12)
    assert mass[441] == pytest.approx(0.12784 * SIZE**2 / NODES**2, rel=1e-12)
    area = m.yarns.stiffness * m.yarns.rest_length / m.yarns.modulus
    assert area[-1] == pytest.approx(math.pi * 0.0003**2, rel=1e-12)
    # touching: ply 3 sits r2 + r3 below ply 2
    z = m.nodes.x0[2, m.nodes.ply_nodes[:-1]]
    assert z[1] - z[2] == pytest.approx(0.000185 + 0.0003, rel=1e-12)


@pytest.mark.parametrize("bad, words", [
    # the message leads with the key and its value
    ({"fabric.ply_angles": [0.0, 45.0]}, r"fabric.ply_angles = \[0.0, 45.0\] has 2 values for "
                                         r"fabric.plies = 3; allowed: one angle"),
    ({"fabric.ply": [{}, {}]}, "one table per ply"),
    ({"fabric.ply_spacing": 1e-4}, "interpenetrating"),
    ({"fabric.ply": [{}, {"damage": {"rate": 5.0}}, {}]}, "one damage law"),
])
def test_pack_keys_are_checked(bad, words):
    with pytest.raises(ScenarioError, match=words):
        build_model(load_scenario("paper-no-field", {
            "fabric.plies": 3, "fabric.nodes": [11, 11], **bad}))



def test_plies_not_written_follow_the_angles_or_tables_given_by_overrides():
    """As in a file (plies not written: as many as [[fabric.ply]] tables, else as ply_angles),
    an override on a scenario that does not write plies: `--set fabric.ply_angles=[0,45]` on
    the paper's sheet is a 2-ply pack, the one a file writing only ply_angles gives; a written
    plies is kept (and a mismatch refused, above)."""
    from emfabric.config.scenario import scenario_from_dict

    two = load_scenario("paper-no-field", {"fabric.ply_angles": [0.0, 45.0]})
    assert two.fabric.plies == 2 and two.fabric.ply_angles == (0.0, 45.0)
    data = load_scenario("paper-no-field").to_dict()
    data["fabric"].pop("plies")
    data["fabric"]["ply_angles"] = [0.0, 45.0]
    assert scenario_from_dict(data) == two
    assert load_scenario("paper-no-field", {"fabric.ply": [{}, {}, {}]}).fabric.plies == 3
    assert load_scenario("pack-field", {"fabric.nodes": [21, 21]}).fabric.plies == \
        load_scenario("pack-field").fabric.plies

def test_rotated_ply_is_clipped_to_the_frame():
    """A ±45° ply: a rotated grid whose nodes strictly inside the frame are free, those next to
    them clamped and the rest massless; its mass is the ply's, its free nodes fill the frame."""
    m = build_model(_pack(**{"fabric.ply_angles": [0.0, 45.0, -45.0]}))
    lo, hi = m.nodes.ply_nodes[1], m.nodes.ply_nodes[2]
    x0, mass, inv = m.nodes.x0[:, lo:hi], m.nodes.mass[lo:hi], m.nodes.inv_mass[lo:hi]
    free = inv > 0
    assert np.all(np.abs(x0[:2, free]) < SIZE / 2)
    assert mass.sum() == pytest.approx(0.12784 * SIZE**2, rel=1e-12)
    # the nodes carrying mass reach at most one diagonal spacing beyond the frame
    assert np.abs(x0[:2, mass > 0]).max() < SIZE / 2 + H * 1.0001
    # the free nodes' density matches the aligned ply's (one per H²)
    assert free.sum() == pytest.approx((SIZE / H) ** 2, rel=0.1)
    # the yarns run at 45°
    ends = m.yarns.ends[m.yarns.ply_segments[1]]
    d = m.nodes.x0[:, ends[1]] - m.nodes.x0[:, ends[0]]
    assert math.degrees(math.atan2(d[1], d[0])) == pytest.approx(45.0, abs=1e-9)


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_free_pack_struck_obliquely_conserves_momentum(integrator):
    """Free edges, no field: a yawed, spinning ogive strikes a free 3-ply pack obliquely and off
    centre. Projectile contact and ply contact exchange exactly opposite impulses (the ply
    impulses, or the φ-scheme's ply forces, summed in integers): the momentum of pack +
    projectile is conserved to round-off, while all three plies take part."""
    sc = make(**{"solver.integrator": integrator,
                 "fabric.nodes": [15, 15], "fabric.size": [SIZE, SIZE], "fabric.edges": "free",
                 "fabric.plies": 3, "field.B": [0, 0, 0], "projectile.shape": "ogive",
                 "projectile.radius": 0.005, "projectile.length": 0.03,
                 "projectile.nose_length": 0.018, "projectile.mass": 0.01,
                 "projectile.position": [0.003, -0.002, 0.02],
                 "projectile.velocity": [30.0, -20.0, -200.0],
                 "projectile.axis": [0.1, 0.05, -1.0],
                 "projectile.angular_velocity": [100.0, -300.0, 2000.0],
                 "solver.end_time": 200e-6})
    ds = run(sc).history
    p = ds.fabric_momentum.values + ds.projectile_momentum.values
    assert int(ds.contact_nodes.max()) >= 5
    # the bottom ply was pushed through the middle one
    assert float(ds.max_deflection_per_ply[-1, 2]) > 1e-3
    assert np.abs(p - p[0]).max() < 1e-13 * np.abs(p[0]).max()


def test_free_pack_struck_obliquely_keeps_its_angular_momentum_to_first_order():
    """Free edges, no field: a spinning sphere strikes a free 2-ply pack obliquely (the
    single-sheet case of tests/test_central.py with a second ply). The angular momentum of
    pack + projectile drifts only through the placements, which move nodes without momentum:
    the drift halves with the step (first order, as for one sheet). Ply contact's reaction
    lands where the line of action of each node's impulses meets the ply it pressed
    (plies._spread): when it landed on each pair's own master node, a pair's moment was off by
    its in-plane offset times its impulse, and the drift did not shrink with the step: 2.2e-4,
    2.3e-4, 2.2e-4 of the initial angular momentum at courant 0.5, 0.25, 0.125 (and grew from
    1.2e-4 to 2.1e-3 without friction)."""
    errors = []
    for courant in (0.5, 0.25, 0.125):
        ds = run(make(**{"fabric.nodes": [15, 15], "fabric.edges": "free", "fabric.plies": 2,
                         "field.B": [0, 0, 0], "projectile.velocity": [40.0, -25.0, -250.0],
                         "projectile.angular_velocity": [300.0, -200.0, 1000.0],
                         "projectile.gap": 0.0, "solver.integrator": "central-difference",
                         "solver.courant": courant, "solver.end_time": 60e-6})).history
        assert int(ds.contact_nodes_per_ply[:, 0].max()) >= 3
        p = ds.fabric_momentum.values + ds.projectile_momentum.values
        assert np.abs(p - p[0]).max() < 1e-14 * np.abs(p[0]).max()
        ang = ds.fabric_angular_momentum.values + ds.projectile_angular_momentum.values
        errors.append(np.linalg.norm(ang - ang[0], axis=1).max() / np.linalg.norm(ang[0]))
    assert errors[0] < 4e-4
    assert (errors[0] / errors[-1]) ** 0.5 >= 1.8, errors


def test_the_reaction_meets_a_folded_ply_where_its_mirror_image_does():
    """_facet on a ply folded into a ridge along x (5 × 5 nodes, z = −|y|/2 on a unit grid,
    exact in binary): a node at x = 0 under the ridge, its line of action along +y in the
    plane x = 0, meets both flanks on the column of nodes at x = 0, each at a least weight of
    exactly 0 (the point on a facet's edge). The reaction goes where the line meets the ply
    nearest the node, (0, 0.5, −0.25), not (0, −0.5, −0.25), and for the mirror image (y → −y)
    to the mirror image of that point: taken in the search's order, the two gave the same
    point, and a reversed field did not mirror a torn pack."""
    from emfabric._kernels.plies import _facet

    j, i = np.mgrid[0:5, 0:5]
    grid_x = np.vstack([(i - 2.0).ravel(), (j - 2.0).ravel(), -0.5 * np.abs(j - 2.0).ravel()])
    mass = np.ones(26)
    points = []
    for side in (1.0, -1.0):
        x = np.hstack([grid_x, [[0.0], [0.25 * side], [-0.25]]])
        least, a, t, cu, cw, cv = _facet(x, 25, (0.0, side, 0.0), (12, 0, 5, 5, 2, 2), mass)
        quad = (a, a + 1, a + 6, a + 5)
        centre = x[:, list(quad)].mean(axis=1)
        points.append(cu * x[:, quad[t]] + cw * x[:, quad[(t + 1) % 4]] + cv * centre)
        assert least == 0.0
    np.testing.assert_array_equal(points[0], [0.0, 0.5, -0.25])
    np.testing.assert_array_equal(points[1], [0.0, -0.5, -0.25])


def test_ply_forces_have_no_moment():
    """The φ-scheme's ply forces on three free plies, each shifted in its plane by a fraction of
    a node spacing against the next (so no node lies over a node), bent, pressed into one
    another over their middles and moving at random: the forces sum to zero exactly (integers)
    and their moment about the origin to round-off, as the forces of pairs that act along one
    line do (plies._spread). With each pair's reaction on its own master node, the moment was
    ~1 % of Σ|x||F|."""
    from emfabric._kernels.plies import ply_forces
    from emfabric.integrators import make_integrator
    from emfabric.sim.state import initial_state

    n, size = 7, 0.012
    sc = make(**{"fabric.nodes": [n, n], "fabric.size": [size, size], "fabric.plies": 3,
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "fabric.charge_per_node": 0.0,
                 "field.B": [0, 0, 0], "field.E": [0, 0, 0], "projectile.shape": "none",
                 "solver.integrator": "phi"})
    model = build_model(sc)
    integ = make_integrator(model)
    x, v = initial_state(model).arrays.x.copy(), np.zeros((3, model.node_count))
    gap = float(integ.physics.contact.ply_gap.min())
    h = size / (n - 1)
    for p in range(3):
        ply = slice(model.nodes.ply_nodes[p], model.nodes.ply_nodes[p + 1])
        x[0, ply] += 0.31 * p * h
        x[1, ply] -= 0.17 * p * h
        x[2, ply] += 0.3 * gap * (p + 1) * np.sin(3 * x[0, ply] / size) * np.cos(
            2 * x[1, ply] / size) + 0.2 * gap * p
        # the rims apart (a node over no part of the ply above it has no line to meet it by)
        rim = np.maximum(np.abs(x[0, ply] - x[0, ply].mean()),
                         np.abs(x[1, ply] - x[1, ply].mean())) > 0.3 * size
        x[2, ply] -= 3.0 * gap * p * rim
    v[:] = 30.0 * np.random.default_rng(7).standard_normal(v.shape)
    out = np.zeros_like(x)
    assert ply_forces(integ.physics, x, v, v, integ.work, out, 1e-8) >= 20
    scale = float((np.linalg.norm(x, axis=0) * np.linalg.norm(out, axis=0)).sum())
    assert np.abs(integ.work.ply_acc).max() == 0  # read and cleared
    moment = np.cross(x.T, out.T).sum(axis=0)
    assert np.abs(moment).max() < 1e-14 * scale
    assert np.abs(out.sum(axis=1)).max() < 1e-12 * float(np.abs(out).max())


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_head_on_impact_on_an_aligned_pack_does_not_spin(integrator):
    """A sphere head-on into the centre of an aligned pack without scatter: the scene is
    mirror-symmetric in x and y, and so is every step (mirror-exact forces and normals, ply
    impulses or forces summed in integers): ω and the lateral position stay exactly zero."""
    ds = run(_pack(**{"solver.integrator": integrator})).history
    assert int(ds.contact_nodes_per_ply[:, 0].max()) >= 4
    assert float(ds.max_deflection_per_ply[-1, 2]) > 1e-3
    assert float(np.abs(ds.angular_velocity).max()) == 0.0
    assert float(np.abs(ds.projectile_position[:, :2]).max()) == 0.0


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_reversing_B_mirrors_a_pack_run(integrator):
    """A yawed ogive into a charged 2-ply pack in B = ±B e_x: the scene is mirror-symmetric in
    y, so reversing B mirrors the run to the bit (ω_x, ω_z change sign, ω_y does not)."""
    def go(bx):
        return run(make(**{"solver.integrator": integrator,
            "fabric.nodes": [NODES, NODES], "fabric.size": [SIZE, SIZE],
            "fabric.material.modulus_cv": 0.0, "fabric.plies": 2, "field.B": [bx, 0, 0],
            "projectile.shape": "ogive", "projectile.radius": 0.005,
            "projectile.length": 0.03, "projectile.nose_length": 0.018,
            "projectile.mass": 0.01, "projectile.axis": [0.1, 0.0, -1.0],
            "projectile.velocity": [20.0, 0.0, -250.0], "solver.end_time": 30e-6})).history
    a, b = go(0.05), go(-0.05)
    wa, wb = a.angular_velocity.values, b.angular_velocity.values
    assert np.abs(wa[:, 0]).max() > 1.0
    np.testing.assert_array_equal(wb[:, 0], -wa[:, 0])
    np.testing.assert_array_equal(wb[:, 1], wa[:, 1])
    np.testing.assert_array_equal(wb[:, 2], -wa[:, 2])


SPACED = 0.02


def test_a_distant_ply_rests_until_something_reaches_it():
    """Two plies 2 cm apart, the top one thin and brittle (λ = 500) so that a fast sphere tears
    it: the lower ply does not move at all (not one node, to the bit) until the top ply has
    broken or has come down to it."""
    sc = _pack(**{"fabric.plies": 2, "fabric.ply_spacing": SPACED,
                  "fabric.ply": [{"yarn_radius": 0.00008}, {}],
                  "fabric.damage.rate": 500.0, "projectile.velocity": [0, 0, -400.0],
                  "solver.end_time": 150e-6})
    ds = run(sc).history
    moved = ds.max_deflection_per_ply.values[:, 1] > 0.0
    assert moved.any()
    reached = ((ds.broken_yarns_per_ply.values[:, 0] > 0)
               | (ds.max_deflection_per_ply.values[:, 0] >= SPACED - 2 * 0.00008))
    first = int(np.argmax(moved))
    assert reached[:first + 1].any()
    assert not moved[:int(np.argmax(reached))].any()


def test_a_stopped_projectile_leaves_lower_plies_undamaged():
    """A slow sphere that the top ply stops (it rebounds): the plies below, 2 cm away, keep
    every yarn intact and never move; the summary counts no ply perforated."""
    sc = _pack(**{"fabric.ply_spacing": SPACED, "projectile.velocity": [0, 0, -60.0],
                  "solver.end_time": 1.5e-3})
    res = run(sc)
    ds = res.history
    assert res.summary["perforated"] == 0
    assert res.summary["plies_perforated"] == 0
    assert int(ds.broken_yarns_per_ply[:, 1:].max()) == 0
    assert float(ds.max_deflection_per_ply[:, 1:].max()) == 0.0
    m = res.model
    assert float(res.state.seg_alpha[m.yarns.ply_segments[1]:].min()) == 1.0


def test_plies_in_contact_act_as_one_ply_of_their_sum():
    """A flat-faced cylinder pushes a pack of two touching plies, and in a second run one ply
    with their summed mass (areal density) and stiffness (yarn area): the friction of the ply
    contact makes the pack one sheet, so the projectile's speed and the deflection agree
    within discretisation error (the plies are 0.37 mm apart, the wave is the same)."""
    base = {"projectile.shape": "cylinder", "projectile.radius": 0.008,
            "projectile.length": 0.01, "projectile.mass": 0.02,
            "projectile.velocity": [0, 0, -100.0], "fabric.damage.rate": 0.0,
            "solver.end_time": 150e-6}
    pack = run(_pack(**{**base, "fabric.plies": 2})).history
    one = run(_pack(**{**base, "fabric.plies": 1, "fabric.areal_density": 2 * 0.12784,
                       "fabric.yarn_radius": 0.000185 * math.sqrt(2.0)})).history
    drop_pack = 100.0 + float(pack.projectile_velocity[-1, 2])
    drop_one = 100.0 + float(one.projectile_velocity[-1, 2])
    assert drop_one > 10.0
    assert drop_pack == pytest.approx(drop_one, rel=0.03)
    assert float(pack.max_deflection[-1]) == pytest.approx(float(one.max_deflection[-1]),
                                                            rel=0.03)


@pytest.fixture(scope="module")
def hard_impact(tmp_path_factory):
    """A hard impact (400 m/s, no damage, 60 µs) on three touching plies, run by each scheme:
    {integrator: output folder}."""
    runs = {}
    for integrator in ("central-difference", "phi"):
        out = tmp_path_factory.mktemp("hard") / integrator
        run(_pack(**{"fabric.damage.rate": 0.0, "projectile.velocity": [0, 0, -400.0],
                     "solver.end_time": 60e-6, "solver.integrator": integrator}), out)
        runs[integrator] = out
    return runs


def _gaps(snapshots, nodes=NODES):
    """For every snapshot and every pair of neighbouring plies (k, k + 1): the heights of ply
    k + 1's nodes under ply k's current triangulated surface (masked where a node is not under
    it), (snapshots, plies − 1) masked arrays."""
    snaps = xr.open_dataset(snapshots)
    ply = snaps.node_ply.values - 1  # 1 is the top ply
    x = snaps.node_position.values
    i, j = np.meshgrid(np.arange(nodes - 1), np.arange(nodes - 1))
    a = (j * nodes + i).ravel()
    tri = np.concatenate([np.stack([a, a + 1, a + nodes + 1], 1),
                          np.stack([a, a + nodes + 1, a + nodes], 1)])
    out = []
    for s in range(x.shape[0]):
        row = []
        for k in range(int(ply.max())):
            upper, lower = x[s][ply == k], x[s][ply == k + 1]
            surf = LinearTriInterpolator(Triangulation(upper[:, 0], upper[:, 1], tri),
                                         upper[:, 2])
            row.append(surf(lower[:, 0], lower[:, 1]) - lower[:, 2])
        out.append(row)
    return out, x


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_no_ply_passes_through_the_one_above(integrator, hard_impact):
    """A hard impact (400 m/s, no damage) on three touching plies: at every snapshot every node
    of ply k + 1 lies below the surface of ply k (its position interpolated on ply k's current
    triangulated surface)."""
    gaps, x = _gaps(hard_impact[integrator] / "snapshots.nc")
    checked = 0
    for row in gaps:
        for h in row:
            assert np.all(h.compressed() > 0.0)
            checked += h.count()
    assert checked > 1000
    assert float(x[-1][:, 2].min()) < -5e-3


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_a_point_load_does_not_press_plies_into_one_another(integrator, tmp_path):
    """A .22 FSP (5.6 mm) at 600 m/s on an 8-ply pack of 5 mm cells pushes on one node of the
    top ply: kilonewtons through single pairs of nodes, passed down the whole pack. At every
    snapshot every ply's nodes stay below the ply above by at least a quarter of the contact
    distance d (the sum of the yarn radii): the yarns may press into each other, never through.
    (One simultaneous pass of central differences' impulses per step, and a penalty of
    constant stiffness in the φ-scheme, both let the top plies' gaps close to nothing.)"""
    out = tmp_path / integrator
    res = run(_pack(**{"fabric.plies": 8, "fabric.damage.rate": 0.0,
                       "projectile.shape": "fsp", "projectile.radius": 0.00278,
                       "projectile.mass": 0.0011, "projectile.velocity": [0, 0, -600.0],
                       "solver.end_time": 16e-6, "output.snapshot_interval": 1e-6,
                       "solver.integrator": integrator}), out)
    d = float(res.model.physics.contact.ply_gap[0])
    assert d == pytest.approx(2 * 0.000185)
    gaps, x = _gaps(out / "snapshots.nc")
    assert len(gaps) >= 16
    for row in gaps:
        for h in row:
            assert h.count() > 100
            assert float(h.min()) > 0.25 * d
    # the whole pack was pushed: the bottom ply's centre moved by more than 20 contact distances
    assert float(x[-1][:, 2].min()) < float(x[0][:, 2].min()) - 20 * d
    assert float(res.history.projectile_velocity[-1, 2]) > -550.0


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
@pytest.mark.parametrize("name", ["pack-field", "pack-no-field", "pack-fsp"])
def test_builtin_packs_run(name, integrator, tmp_path):
    """The built-in packs build as their descriptions say, and run (a few µs, on a coarser
    grid) through the command line's code path with per-ply outputs, with either scheme."""
    sc = load_scenario(name)
    m = build_model(sc)
    assert m.ply_count == (8 if name == "pack-fsp" else 4)
    assert sc.solver.integrator == "central-difference"
    # pack-fsp's 5.6 mm FSP needs a finer grid than 11 × 11 (2.5 cm cells) for the φ-scheme
    nodes = [21, 21] if name == "pack-fsp" else [11, 11]
    res = run(load_scenario(name, {"fabric.nodes": nodes, "solver.end_time": 3e-6,
                                   "solver.integrator": integrator}), tmp_path / name)
    assert res.status == "complete"
    ds = xr.open_dataset(tmp_path / name / "history.nc")
    assert ds.broken_yarns_per_ply.dims == ("time", "ply")
    assert ds.sizes["ply"] == m.ply_count
    assert res.summary["plies"] == m.ply_count


def test_both_schemes_agree_on_a_hard_impact_and_close_the_energy_budget(hard_impact):
    """The same hard impact (400 m/s, no damage, 60 µs) on three touching plies with central
    differences (impulse and placement) and with the φ-scheme (damped penalty and regularised
    friction, docs/theory.md §5.1): two different contact laws for one physical contact, so
    the projectile's loss of speed agrees within 3 % and every ply's deflection within 3 %; each
    closes its energy budget to 1e-3 of the impact energy, and the φ run's contacts are
    counted per ply as central differences' are."""
    cd, phi = (xr.open_dataset(hard_impact[k] / "history.nc")
               for k in ("central-difference", "phi"))
    drop_cd, drop_phi = (400.0 + float(ds.projectile_velocity[-1, 2]) for ds in (cd, phi))
    assert drop_cd > 50.0
    assert drop_phi == pytest.approx(drop_cd, rel=0.03)
    np.testing.assert_allclose(phi.max_deflection_per_ply[-1].values,
                               cd.max_deflection_per_ply[-1].values, rtol=0.03)
    assert float(phi.max_deflection_per_ply[-1, 2]) > 0.01  # all three plies were pushed
    impact = float(cd.kinetic_energy_projectile[0])
    for ds in (cd, phi):
        assert abs(float(ds.energy_balance_error[-1])) < 1e-3 * impact
    assert int(phi.contact_nodes_per_ply[:, 0].max()) >= 4
    assert int(phi.contact_nodes_per_ply[:, 1:].max()) == 0  # the sphere meets the top ply
    np.testing.assert_array_equal(phi.contact_nodes_per_ply.values.sum(axis=1),
                                  phi.contact_nodes.values)


def test_a_pack_gives_the_same_numbers_on_any_thread_count():
    """Ply contact's sweeps run in a fixed order and sum each pair in integers: a pack struck
    by the sphere ends in the same state, to the bit, with the serial kernels and with two
    threads."""
    sc = load_scenario("pack-no-field", {"fabric.nodes": [41, 41], "solver.end_time": 5e-6})
    one, two = run(sc, threads=1), run(sc, threads=2)
    assert int(one.history.contact_nodes.max()) >= 1
    assert float(one.history.max_deflection_per_ply[-1, 1]) > 0.0
    for name in ("node_x", "node_v", "body"):
        np.testing.assert_array_equal(getattr(one.state, name), getattr(two.state, name))


def test_a_viscous_torn_pack_gives_the_same_numbers_on_any_thread_count():
    """Brittle plies have a bulk viscosity, whose rate the kick takes from where ply contact's
    placements put a node a step back (records.Work.visc_base): the threaded kernel's block
    that starts at a row of placed nodes recomputes the fill tensions from the row below with
    that same base, so that the FSP's head-on strike of three plies (threads: blocks of 16 rows,
    the third ply's row 14 under the FSP) is the serial run bit for bit, and stays mirror
    symmetric. With the base of the step's start there, the two-thread run spun the FSP
    (ω_x = −3394 rad/s by 40 µs)."""
    sc = load_scenario("pack-fsp", {"fabric.size": [0.05, 0.05], "fabric.nodes": [25, 25],
                                    "fabric.plies": 3, "fabric.material.modulus_cv": 0.0,
                                    "field.B": [0.0, 0.0, 0.0], "solver.end_time": 3e-6})
    assert build_model(sc).physics.yarns.damping.size > 0  # brittle: viscous by default
    one, two = run(sc, threads=1), run(sc, threads=2)
    assert int(one.history.contact_nodes.max()) >= 1
    assert float(one.history.max_deflection_per_ply[-1, 2]) > 0.0
    for name in ("node_x", "node_v", "node_fv", "body"):
        np.testing.assert_array_equal(getattr(one.state, name), getattr(two.state, name),
                                      err_msg=name)
    np.testing.assert_array_equal(two.state.body[BODY_W], 0.0)


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
@pytest.mark.parametrize("pull", [0.0, 1.5])
def test_a_ply_pressed_onto_the_next_by_a_field(integrator, pull):
    """Two free rigid 2 × 2 plies (all nodes alike), touching; the top one
    charged (q per node), the lower one not, E = (0, E_y, −E_z) presses the top ply onto the
    lower one. Closed form per node pair (mass m each): the pack's momentum grows by 4 q E t
    (exact: no other force acts on it); pressed (E_y = 0) the plies move as one at
    q E_z t/(2m); E_y = 1.25 E_z > μ_s E_z slides the top ply over the lower one, which is
    dragged by μ_d N (N = q E_z/2 per node): v_y = μ_d q E_z t/(2m) below, q (E_y − μ_d E_z/2)
    t/m above, and along z the plies move as one on average but tip: the friction between
    them acts the contact distance from their nodes, and ply contact keeps its moment
    (plies._spread). Pressed, no yarn stretches, so the energy budget closes to round-off (slid,
    to the scheme's own error over the strain the tipping puts in): the placement's
    work is the yarns' alone (plies._apply; with the field's too, central differences booked
    h²|qE|²/2m a step twice and the divergence guard stopped the pressed pack at its first
    step)."""
    ez, end = 1.2, (20e-6 if pull == 0.0 else 5e-6)
    sc = make(**{"fabric.nodes": [2, 2], "fabric.size": [0.002, 0.002], "fabric.plies": 2,
                 "fabric.ply": [{}, {"charge_per_node": 0.0}], "fabric.rescale": False,
                 "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "field.B": [0, 0, 0],
                 "field.E": [0.0, pull, -ez], "projectile.shape": "none",
                 "solver.end_time": end, "solver.integrator": integrator})
    model = build_model(sc)
    q, m = float(model.nodes.charge[0]), float(model.nodes.mass[0])
    assert float(model.nodes.charge[4:].max()) == 0.0
    res = run(sc)
    h, v = res.history, res.state.arrays.v
    t = float(h.time[-1])
    assert t == pytest.approx(end)
    momentum = m * v.sum(axis=1)
    assert momentum[2] == pytest.approx(-4 * q * ez * t, rel=1e-9)
    assert momentum[1] == pytest.approx(4 * q * pull * t, rel=1e-9, abs=1e-15)
    # the plies move as one along the normal (the φ-scheme's penalty lets them breathe a
    # little); pulled along y, on average: friction acts between the plies, the contact
    # distance from the nodes of each, and its moment about them tips the plies (the rows
    # at −y and +y move apart along z), as the angular momentum requires of a pack whose
    # only external force acts on the top ply's nodes
    vz = -q * ez * t / (2 * m)
    if pull == 0.0:
        np.testing.assert_allclose(v[2], vz, rtol=5e-3)
    else:
        np.testing.assert_allclose([v[2, :4].mean(), v[2, 4:].mean()], vz, rtol=5e-3)
        assert np.ptp(v[2]) > 0.05 * abs(vz)
    if pull > 0.0:
        mu_s, mu_d = sc.contact.static_friction, sc.contact.dynamic_friction
        assert pull > mu_s * ez
        np.testing.assert_allclose(v[1, 4:], mu_d * q * ez * t / (2 * m), rtol=1e-2)
        np.testing.assert_allclose(v[1, :4], q * (pull - mu_d * ez / 2) * t / m, rtol=1e-2)
    assert res.status == "complete"
    # pressed, no yarn stretches and the budget closes to round-off; slid, the tipping
    # stretches the yarns (3.2e-9 J of strain at 5 µs) and central differences close it to
    # their own second-order error: 4.2e-11 / 1.1e-11 / 3.0e-12 J at courant 0.25 / 0.125 /
    # 0.0625 (the φ-scheme 9e-14 J)
    bound = 1e-9 if pull == 0.0 else 1e-7
    assert abs(float(h.energy_balance_error[-1])) < bound * float(h.work_field[-1])


def _three_rigid_plies(size=0.002, **kw):
    """Three free plies of 2 × 2 nodes, size × size, stacked at the contact distance, no
    field, no projectile, central differences: (model, integrator, initial state, the three
    plies' node slices from the top)."""
    from emfabric.integrators import make_integrator
    from emfabric.sim.state import initial_state

    sc = make(**{"fabric.nodes": [2, 2], "fabric.size": [size, size], "fabric.plies": 3,
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "fabric.charge_per_node": 0.0,
                 "field.B": [0, 0, 0], "field.E": [0, 0, 0], "projectile.shape": "none",
                 "solver.integrator": "central-difference", **kw})
    model = build_model(sc)
    nodes = model.nodes
    assert np.all(nodes.mass == nodes.mass[0])
    plies = tuple(slice(nodes.ply_nodes[p], nodes.ply_nodes[p + 1]) for p in range(3))
    return model, make_integrator(model), initial_state(model), plies


def test_the_projectile_brings_the_pack_below_to_its_speed_within_one_step():
    """Three free rigid 2 × 2 plies, overlapping by a tenth of the contact distance d: the top
    ply's nodes held by the projectile (State.contact[3]), moving down at V, the two below at
    rest. A held node acts as one of infinite mass, so the sweeps of one step bring both plies
    below to −V along the normal (closed form of the converged stick/inelastic impulses), and
    the held nodes take the whole −J once the sweeps end: +2V each, since the plies below gained
    8 m V and the pack's momentum is exact. With the held nodes' −J applied after each sweep,
    they slowed and parted from the ply below after the first one, which left plies 2 and 3
    at −V/2 (and the push went on a step later; docs/theory.md §5.1)."""
    from emfabric._kernels.plies import ply_contact

    model, integ, state, (top, mid, low) = _three_rigid_plies()
    phys, nodes = integ.physics, model.nodes
    gap = float(phys.contact.ply_gap.min())
    m = float(nodes.mass[0])
    x, v = state.arrays.x.copy(), state.arrays.v.copy()
    x[2, top] -= 0.1 * gap
    x[2, low] += 0.1 * gap
    speed = 100.0
    v[2, top] = -speed
    held = np.zeros(model.node_count)
    held[top] = 1.0
    p0 = m * v.sum(axis=1)
    ply_contact(phys, state.arrays, x, v, integ.work, 1e-8, held)
    np.testing.assert_allclose(v[2, mid], -speed, rtol=0.05)
    np.testing.assert_allclose(v[2, low], -speed, rtol=0.05)
    np.testing.assert_allclose(v[:2], 0.0, atol=1e-9 * speed)
    np.testing.assert_allclose(m * v.sum(axis=1), p0, atol=1e-12 * m * speed)
    # the held nodes took what the plies below gained, once
    gained = float(v[2, mid].mean() + v[2, low].mean())
    np.testing.assert_allclose(v[2, top], -speed - gained, rtol=1e-9)
    # no ply passes through the next: every gap opened to the contact distance
    assert float(x[2, top].min() - x[2, mid].max()) >= 0.99 * gap
    assert float(x[2, mid].min() - x[2, low].max()) >= 0.99 * gap


def test_ply_friction_obeys_coulombs_law_over_the_step_sweeps():
    """Three free rigid 2 × 2 plies: the top one held, tilted by θ about y (tan θ = 0.25) and
    moving down at V; the middle one parallel to it, at rest; the bottom one level and sliding
    along x at W = 2V. μ_s = 0.5, μ_d = 0.3. The step's sweeps converge to the middle ply
    stuck to the top one (v = (0, 0, −V), closed form): the impulse across their interface,
    m(0, 0, −V) less what the bottom ply gave the middle one, leans from the top ply's normal by
    0.27–0.28 in tangent (the pairs' summed impulses, records.Work.ply_sum), inside the static
    cone. The bottom ply's friction reaches the middle one sweep by sweep, each piece with μ_d
    of its own normal impulse about the bottom ply's normal: about the tilted normal above, a
    piece leans (μ_d + tan θ)/(1 − μ_d tan θ) = 0.59 > μ_s. Each sweep's impulse cut to the
    cone of its own normal impulse, as before, slid every such piece, and a node of the middle
    ply kept 4.3 m/s of the bottom ply's slip along x (4 % of V); with the step's summed
    impulse cut to the cone, the pair sticks (docs/theory.md §5.1). The increments a sweep
    applies keep exact action and reaction: the pack's momentum is exact. The bottom ply is
    slowed by friction: each of its nodes by at least half of μ_d times its normal speed change
    against the same step without friction (there the middle ply's tilted normal alone pushes
    them along +x, to 210–214 m/s)."""
    from emfabric._kernels.plies import ply_contact

    size = 0.0005
    speed = 100.0
    mu_d = 0.3

    def step(static, dynamic):
        model, integ, state, (top, mid, low) = _three_rigid_plies(
            size, **{"contact.static_friction": static, "contact.dynamic_friction": dynamic})
        gap = float(integ.physics.contact.ply_gap.min())
        x, v = state.arrays.x.copy(), state.arrays.v.copy()
        slope = -0.25
        centre = x[0, top].mean()
        x[2, top] -= 0.03 * gap + slope * (x[0, top] - centre)
        x[2, mid] -= slope * (x[0, mid] - centre)
        x[2, low] += 0.3 * gap
        v[2, top] = -speed
        v[0, low] = 2.0 * speed
        held = np.zeros(model.node_count)
        held[top] = 1.0
        v_top = v[:, top].copy()
        m = float(model.nodes.mass[0])
        p0 = m * v.sum(axis=1)
        ply_contact(integ.physics, state.arrays, x, v, integ.work, 1e-8, held)
        np.testing.assert_allclose(m * v.sum(axis=1), p0, atol=1e-12 * m * speed)
        return v, v_top, (top, mid, low)

    v, v_top, (top, mid, low) = step(0.5, mu_d)
    # stuck to the top ply's velocity before the sweeps (the held nodes take −ΣJ only after
    # them), within the sweeps' convergence (PLY_VELOCITY_TOLERANCE)
    np.testing.assert_allclose(v[:, mid], v_top, atol=0.01 * speed)
    # and the bottom ply still slides under it, slowed by friction
    assert np.all(v[0, low] > v[0, mid] + speed)
    assert v[0, low].mean() < 2.0 * speed
    free, _, _ = step(0.0, 0.0)
    assert np.all(free[0, low] - v[0, low] > 0.5 * mu_d * np.abs(v[2, low])), (free, v)


def test_plies_stuck_together_keep_their_shear():
    """Two free aligned plies of 9 × 9 nodes, the top one closing onto the bottom one at V
    and sheared in its plane, v_x = a (y − y_c) with a |y − y_c| ≤ V/2, the bottom one at rest;
    μ_s = 1, so every contact sticks. One step's sweeps converge to both plies moving as one at
    the mean velocity, v = (a (y − y_c)/2, 0, −V/2) (closed form: equal masses, stick and
    inelastic): each node's pairs with the nodes around it sum to the stick impulse towards
    the shares' average of their velocities, which for a linear field on an aligned grid is
    the velocity under the node, and the contact keeps the plies' shear rather than making
    the patch move as one. Away from the columns at the x-edges the velocities are within 2 %
    of V of it. At those columns each row's friction
    couple comes out: the friction between the plies acts the contact distance from their
    nodes, along x, and its moment about y is carried by the end nodes of the row, which
    move apart along z (±8.8 m/s at the corners): the reaction of a node's impulses lands
    where their line of action meets the other ply (plies._spread). The pack's momentum is
    exact."""
    from emfabric._kernels.plies import ply_contact
    from emfabric.integrators import make_integrator
    from emfabric.sim.state import initial_state

    n = 9
    size = 0.004
    sc = make(**{"fabric.nodes": [n, n], "fabric.size": [size, size], "fabric.plies": 2,
                 "fabric.rescale": False, "fabric.edges": "free", "fabric.damage.rate": 0.0,
                 "fabric.material.modulus_cv": 0.0, "fabric.charge_per_node": 0.0,
                 "field.B": [0, 0, 0], "field.E": [0, 0, 0], "projectile.shape": "none",
                 "solver.integrator": "central-difference"})
    model = build_model(sc)
    nodes = model.nodes
    assert np.all(nodes.mass == nodes.mass[0])
    integ = make_integrator(model)
    state = initial_state(model)
    top = slice(nodes.ply_nodes[0], nodes.ply_nodes[1])
    low = slice(nodes.ply_nodes[1], nodes.ply_nodes[2])
    gap = float(integ.physics.contact.ply_gap.min())
    x, v = state.arrays.x.copy(), state.arrays.v.copy()
    x[2, top] -= 0.05 * gap
    speed = 100.0
    yc = float(x[1, top].mean())
    a = 0.5 * speed / float(np.abs(x[1, top] - yc).max())
    v[2, top] = -speed
    v[0, top] = a * (x[1, top] - yc)
    m = float(nodes.mass[0])
    p0 = m * v.sum(axis=1)
    ply_contact(integ.physics, state.arrays, x, v, integ.work, 1e-8, np.zeros(model.node_count))
    inner = np.zeros((n, n), dtype=bool)
    inner[:, 1:n - 1] = True  # columns i = 1 … n − 2 (node index j·n + i)
    inner = inner.ravel()
    for ply in (top, low):
        vp = v[:, ply]
        want_x = 0.5 * a * (x[1, ply] - yc)
        np.testing.assert_allclose(vp[0, inner], want_x[inner], atol=0.02 * speed)
        np.testing.assert_allclose(vp[1, inner], 0.0, atol=0.02 * speed)
        np.testing.assert_allclose(vp[2, inner], -0.5 * speed, atol=0.02 * speed)
    # the shear is kept: the interior's velocities span the half of the top ply's
    span = float(v[0, top][inner].max() - v[0, top][inner].min())
    want = 0.5 * a * float(x[1, top][inner].max() - x[1, top][inner].min())
    np.testing.assert_allclose(span, want, rtol=0.04)
    np.testing.assert_allclose(m * v.sum(axis=1), p0, atol=1e-12 * m * speed)


def test_ply_contact_never_places_a_node_further_than_the_contact_distance():
    """A brittle 3-ply pack perforated by a sphere (31 × 31, 300 m/s): torn flaps and folds
    give ply contact constraints no placement meets, and its sweeps carried nodes up to 0.9 mm
    in one step, 3.7 contact distances d, putting 1.6 J of strain into the yarns at once. A
    pair that met at a gap of at least 0 never needs more than d in a step (the step keeps
    their relative motion below d): no node leaves the step's own motion by more than d
    (plies.PLY_PLACEMENT_LIMIT) but those the projectile holds, which it places."""
    from emfabric.integrators import make_integrator
    from emfabric.sim.state import initial_state

    sc = make(**{"fabric.style": "km2-600d-plain", "fabric.size": [0.05, 0.05],
                 "fabric.nodes": [31, 31], "fabric.plies": 3, "fabric.charge_per_node": 0.0,
                 "field.B": [0.0, 0.0, 0.0], "projectile.radius": 0.004,
                 "projectile.mass": 0.0011, "projectile.velocity": [0.0, 0.0, -300.0],
                 "solver.end_time": 6.5e-5})
    model = build_model(sc)
    integ = make_integrator(model)
    d = float(model.contact.ply_gap.max())
    im = model.nodes.inv_mass
    s, s2 = initial_state(model), initial_state(model)
    worst = 0.0
    while s.t < 6.5e-5 * (1 - 1e-12):
        integ.step(s, s2, dt_limit=6.5e-5 - s.t)
        h = s2.t - s.t
        drifted = s.node_x + h * (s.node_v + 0.5 * h * s.node_f * im)
        free = (s2.node_contact[3] == 0) & (im > 0)
        jump = np.sqrt(((s2.node_x - drifted) ** 2).sum(0))[free]
        worst = max(worst, float(jump.max()))
        s, s2 = s2, s
    assert int(s.seg_alpha.size - np.count_nonzero(s.seg_alpha)) > 50  # torn through
    assert worst <= d * (1 + 1e-9)
    assert worst > 0.5 * d  # the limit was reached: the sweeps would place further
