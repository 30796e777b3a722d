"""The material library and datasheet keys in a scenario (issue 24): what the library and a
style supply, what a written key overrides, and a real fabric end to end."""

import math

import numpy as np
import pytest

from emfabric.config.scenario import ScenarioError, load_scenario, scenario_from_dict
from emfabric.sim.builder import build_model

from conftest import make


def test_material_name_fills_only_what_is_not_written():
    sc = make(**{"fabric.material.name": "kevlar-29"})
    mat = sc.fabric.material
    # DuPont: Kevlar 29 1.44 g/cm³, 70.5 GPa, 2920 MPa, 3.6 % (docs/materials.md)
    assert (mat.density, mat.youngs_modulus) == (1440.0, 70.5e9)
    assert mat.tensile_strength == pytest.approx(2.92e9)
    assert mat.failure_strain == pytest.approx(0.036)
    assert sc.fabric.damage.law == "brittle"  # the default with a library material
    own = make(**{"fabric.material.name": "kevlar-29", "fabric.material.youngs_modulus": 60e9})
    assert own.fabric.material.youngs_modulus == 60e9
    # --set name on a scenario: the library's values follow, the written one stays
    assert own.replace(**{"fabric.material.name": "kevlar-49"}).fabric.material.\
        youngs_modulus == 60e9
    other = sc.replace(**{"fabric.material.name": "dyneema-sk76"}).fabric.material
    assert other.density == 970.0 and other.youngs_modulus == pytest.approx(120 * 0.97e9)
    # without a library material nothing changes: the paper's Zylon and eq. 2.6
    paper = make()
    assert paper.fabric.material.youngs_modulus == 126e9 and paper.fabric.damage.law == "zohdi"
    with pytest.raises(ScenarioError, match="allowed: zylon, "):
        make(**{"fabric.material.name": "kevlar"})


def test_style_gives_cross_section_spacing_and_network():
    """Style 706: 600 denier (66.67 tex) KM2 at 1440 kg/m³, 34 × 34 per inch, 180 g/m²: a
    yarn cross-section tex·1e-6/ρ, one network line per yarn (a pitch of 2.54/34 cm)."""
    sc = make(**{"fabric.style": "km2-600d-plain", "fabric.size": [0.1, 0.1]})
    fab = sc.fabric
    area = 600 / 9 * 1e-6 / 1440
    assert fab.yarn_radius == pytest.approx(math.sqrt(area / math.pi), rel=1e-12)
    assert fab.areal_density == pytest.approx(0.180)
    lines = round(0.1 / (0.0254 / 34)) + 1
    assert fab.nodes == fab.reference_nodes == (lines, lines)
    assert fab.material.name == "kevlar-km2" and fab.damage.law == "brittle"
    assert scenario_from_dict(sc.to_dict()) == sc  # the full scenario reads back the same
    coarse = sc.replace(**{"fabric.nodes": [41, 41]}).fabric
    assert coarse.nodes == (41, 41) and coarse.reference_nodes == (lines, lines)
    # the same datasheet with equal keys and no style
    keys = make(**{"fabric.material.name": "kevlar-km2", "fabric.yarn_denier": 600.0,
                   "fabric.thread_count": [34 / 2.54, 34 / 2.54], "fabric.size": [0.1, 0.1],
                   "fabric.areal_density": 0.18}).fabric
    assert keys.yarn_radius == pytest.approx(fab.yarn_radius, rel=1e-12)
    assert keys.nodes == fab.nodes
    # another style re-derives everything the first one supplied
    k29 = sc.replace(**{"fabric.style": "k29-3000d-plain"}).fabric
    assert k29.material.name == "kevlar-29"
    assert k29.yarn_radius == pytest.approx(math.sqrt(3000 / 9 * 1e-6 / 1440 / math.pi))
    with pytest.raises(ScenarioError, match="fibre density"):
        make(**{"fabric.yarn_linear_density": 100.0})


def test_a_pack_mixes_materials_and_strengths():
    sc = make(**{"fabric.nodes": [11, 11], "fabric.material.name": "kevlar-km2",
                 "fabric.plies": 2, "fabric.ply": [{}, {"material": {"name": "dyneema-sk76"},
                                     "damage": {"failure_strain": 0.02}}]})
    m = build_model(sc)
    fail = np.sqrt(m.yarns.failure_stretch2) - 1.0
    first, second = (fail[m.yarns.ply_segments[p]:m.yarns.ply_segments[p + 1]] for p in (0, 1))
    assert first == pytest.approx(0.0452) and second == pytest.approx(0.02)
    mod = m.yarns.modulus
    assert mod[:m.yarns.ply_segments[1]].mean() == pytest.approx(84.62e9, rel=0.02)
    assert mod[m.yarns.ply_segments[1]:].mean() == pytest.approx(116.4e9, rel=0.02)
    with pytest.raises(ScenarioError, match="one damage law"):
        make(**{"fabric.material.name": "kevlar-km2", "fabric.plies": 2,
                "fabric.ply": [{}, {"damage": {"law": "zohdi"}}]})



def test_a_ply_may_name_its_own_datasheet():
    """MODEL.md: [[fabric.ply]] overrides any fabric key that is not the frame's geometry, so
    the datasheet keys too: a KM2 pack whose second ply is the Dyneema style is, ply by ply,
    the single sheets of those styles on the same frame (material, cross-section tex·1e-6/ρ,
    pitch, areal density, one network line per yarn unless the ply writes its nodes), with the
    pack's damage law; written out in full it reads back to the same plies; a bad ply names it."""
    frame = {"fabric.size": [0.1, 0.1]}
    pack = make(**frame, **{"fabric.style": "km2-600d-plain", "fabric.plies": 2,
                            "fabric.ply": [{}, {"style": "sk76-1760dtex-plain"}]})
    for p, style in enumerate(("km2-600d-plain", "sk76-1760dtex-plain")):
        ply = pack.fabric.ply_fabric(p)
        alone = make(**frame, **{"fabric.style": style}).fabric
        for key in ("nodes", "reference_nodes", "areal_density", "yarn_radius", "thread_count",
                    "yarn_linear_density"):
            assert getattr(ply, key) == getattr(alone, key), (style, key)
        assert ply.material == alone.material and ply.damage.law == "brittle"
    dyneema = pack.fabric.ply_fabric(1)
    assert dyneema.material.name == "dyneema-sk76" and dyneema.areal_density == 0.24
    assert dyneema.yarn_radius == pytest.approx(math.sqrt(176.0 * 1e-6 / 970.0 / math.pi))
    assert dyneema.reference_nodes == (round(0.1 * 100 * 6.5) + 1,) * 2
    assert scenario_from_dict(pack.to_dict()).fabric.ply_fabric(1) == dyneema
    # its own keys over its datasheet; the pack's law (eq. 2.6 here) for every ply
    mixed = make(**frame, **{"fabric.plies": 2, "fabric.ply": [
        {}, {"yarn_denier": 600.0, "material": {"name": "kevlar-km2"}, "nodes": [21, 21]}]})
    km2 = mixed.fabric.ply_fabric(1)
    assert km2.nodes == (21, 21) and km2.damage.law == mixed.fabric.damage.law == "zohdi"
    assert km2.yarn_radius == pytest.approx(math.sqrt(600 / 9 * 1e-6 / 1440 / math.pi))
    m = build_model(pack.replace(**{"fabric.ply": [{"nodes": [21, 21]},
                                                   {"style": "sk76-1760dtex-plain",
                                                    "nodes": [15, 15]}]}))
    assert [m.ply_grid(p) for p in range(2)] == [(21, 21), (15, 15)]
    with pytest.raises(ScenarioError, match=r"ply\[1\]\.style = 'nope'.*allowed"):
        make(**{"fabric.plies": 2, "fabric.ply": [{}, {"style": "nope"}]})
    with pytest.raises(ScenarioError, match=r"ply\[1\]: yarn_denier = 600.0 needs the fibre"):
        make(**{"fabric.plies": 2, "fabric.ply": [{}, {"yarn_denier": 600.0}]})


def test_ply_tables_are_checked_like_the_fabric():
    """A ply's library material name is checked at load (the allowed names listed), and a
    ply's brittle-law keys under a pack of eq. 2.6 are refused, as on a single sheet."""
    with pytest.raises(ScenarioError, match=r"ply.*material.*name.*'kevlar'.*allowed.*kevlar-km2"):
        make(**{"fabric.plies": 2, "fabric.ply": [{}, {"material": {"name": "kevlar"}}]})
    with pytest.raises(ScenarioError, match=r"ply\[1\]\.damage\.failure_strain = 0.03 is a key "
                                            r"of law = 'brittle'"):
        make(**{"fabric.plies": 2, "fabric.ply": [{}, {"damage": {"failure_strain": 0.03}}]})
    with pytest.raises(ScenarioError, match=r"ply\[0\]\.damage\.weibull_shape"):
        make(**{"fabric.plies": 2, "fabric.ply": [{"damage": {"weibull_shape": 5.0}}, {}]})

def test_fsp_into_a_real_fabric_breaks_yarns_at_their_failure_strain():
    """The issue's user: style and library material, an FSP through one ply; yarns break at
    KM2's 4.52 %. On the instantaneous stretch (strain_averaging = 0) yarns break, and the
    largest stretch of a yarn still intact comes within 0.1 % of U_f = 1.0452 and never passes
    it. On the stretch averaged over 5 wave transits (the default) yarns break too, and an
    intact one passes U_f only for the average's lag (τ = 5√(m̄/k) ≈ 0.5 µs here) and never
    by more than the cap: a Green strain 1.25 × U_f's, U = 1.0562. The summary says the
    paper's charge is not physical."""
    from emfabric.runner.loop import run
    from emfabric.runner.summary import summarize

    keys = {"fabric.size": [0.03, 0.03], "solver.end_time": 4e-5}
    s = summarize(run(load_scenario("km2-fsp", {**keys, "fabric.damage.strain_averaging": 0}),
                      None))
    assert s["broken_yarns"] > 0
    assert 1.0452 * (1 - 1e-3) < s["max_stretch"] <= 1.0452
    s = summarize(run(load_scenario("km2-fsp", keys), None))
    assert s["broken_yarns"] > 0
    cap = math.sqrt(1 + 1.25 * (1.0452**2 - 1))
    assert 1.0452 < s["max_stretch"] <= cap
    assert s["charge_plausible"] is False and s["plausibility_warnings"]


def test_datasheet_keys_without_a_style_give_the_yarns_mass_as_areal_density():
    """Linear density and thread count without a style or an areal density: the areal density
    is the straight yarns' mass, tex·1e-6 kg/m × 100 (ends + picks) m/m² (no crimp); written,
    it is kept."""
    sc = make(**{"fabric.material.name": "kevlar-29", "fabric.yarn_denier": 3000.0,
                 "fabric.thread_count": [6.693, 6.693], "fabric.size": [0.1, 0.1]})
    assert sc.fabric.areal_density == pytest.approx(3000 / 9 * 1e-6 * 100 * 2 * 6.693,
                                                    rel=1e-12)
    own = sc.replace(**{"fabric.areal_density": 0.5}).fabric
    assert own.areal_density == 0.5


def test_a_pack_of_library_plies_breaks_like_its_materials():
    """Every ply names a library material (a style or a name) and the pack none: the brittle
    law, as for one sheet of either; a ply of the paper's fabric among them keeps eq. 2.6."""
    plies = [{"style": "km2-600d-plain"}, {"material": {"name": "dyneema-sk76"}}]
    sc = make(**{"fabric.nodes": [11, 11], "fabric.plies": 2, "fabric.ply": plies})
    assert sc.fabric.damage.law == "brittle"
    fail = np.sqrt(build_model(sc).yarns.failure_stretch2) - 1.0
    # KM2 4.52 %, SK76 3.8 % (docs/materials.md): each ply breaks at its own
    assert sorted(set(np.round(fail[fail > 0], 6))) == pytest.approx([0.038, 0.0452])
    mixed = make(**{"fabric.nodes": [11, 11], "fabric.plies": 2,
                    "fabric.ply": [{"style": "km2-600d-plain"}, {}]})
    assert mixed.fabric.damage.law == "zohdi"


@pytest.mark.parametrize("m", [1e-6, 0.005, 0.49])
def test_a_weibull_shape_below_one_half_is_refused_naming_it(m):
    """Γ(1 + 1/m) overflows below m ≈ 0.006 (it named solver.dt_min, the scenario's most
    extreme value); any m below 0.5 scatters the strengths by more than 224 %."""
    with pytest.raises(ScenarioError, match=rf"fabric\.damage\.weibull_shape = {m}: must be 0"):
        make(**{"fabric.material.name": "kevlar-km2", "fabric.damage.weibull_shape": m})
    assert make(**{"fabric.material.name": "kevlar-km2",
                   "fabric.damage.weibull_shape": 0.5}).fabric.damage.weibull_shape == 0.5
