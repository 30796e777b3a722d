"""The material and fabric-style library (issue 24, items 1-2; docs/materials.md): every SI
value against a hand calculation from the number its source publishes, every value's source,
each entry's internal consistency, unknown names, and `emfabric materials`."""

import json
import math

import pytest
from typer.testing import CliRunner

from emfabric.cli import app
from emfabric.config.library import (
    CITATIONS,
    MATERIALS,
    STYLES,
    areal_density_si,
    fabric_style,
    library_material,
    linear_density_tex,
    stress_si,
    thread_count_per_cm,
)

REL = 1e-9
SI_FIELDS = ("density", "youngs_modulus", "tensile_strength", "failure_strain")

# Hand calculations, written out from the published numbers (the units as the sources print
# them): N/tex × g/cm³ = GPa; 1 cN/dtex = 0.1 N/tex; MPa and GPa as they are; % / 100.
HAND = {
    # name: (density kg/m³, E Pa, strength Pa, failure strain)
    "zylon": (1540.0, 126e9, 5.8e9, 0.03),            # paper: 1540 kg/m³, 126 GPa, 3 %;
                                                      # Toyobo: 5.8 GPa
    "zylon-as": (1.54e3, 180e9, 5.8e9, 0.035),        # Toyobo AS: 1.54 g/cm³, 180 GPa,
                                                      # 5.8 GPa, 3.5 %
    "kevlar-29": (1.44e3, 70.5e9, 2920e6, 0.036),     # DuPont: 1.44, 70.5 GPa, 2920 MPa, 3.6 %
    "kevlar-49": (1.44e3, 112.4e9, 3000e6, 0.024),    # DuPont: 1.44, 112.4 GPa, 3000 MPa, 2.4 %
    "kevlar-km2": (1.44e3, 84.62e9, 3.88e9, 0.0452),  # Cheng 2005: 84.62 GPa, 3.88 GPa, 4.52 %
    "twaron": (1.44e3, 500 * 0.1 * 1.44e9,            # Teijin: 500 cN/dtex = 50 N/tex
               20.8 * 0.1 * 1.44e9, 0.035),           # × 1.44 g/cm³ = 72 GPa; 20.8 cN/dtex
                                                      # = 2.08 N/tex × 1.44 = 2.995 GPa
    "dyneema-sk76": (0.97e3, 120 * 0.97e9,            # DSM: 120 N/tex × 0.97 g/cm³
                     3.7 * 0.97e9, 0.038),            # = 116.4 GPa; 3.7 N/tex → 3.589 GPa
}


@pytest.mark.parametrize("name", list(HAND))
def test_material_si_values_from_the_published_numbers(name):
    """Each SI field equals the hand calculation from the source's own number and unit."""
    m = library_material(name)
    rho, e, s, eps = HAND[name]
    assert m.density == pytest.approx(rho, rel=REL)
    assert m.youngs_modulus == pytest.approx(e, rel=REL)
    assert m.tensile_strength == pytest.approx(s, rel=REL)
    assert m.failure_strain == pytest.approx(eps, rel=REL)


def test_dyneema_modulus_and_the_required_materials():
    """The example of the issue: 120 N/tex × 0.97 g/cm³ = 116.4 GPa; the seven materials the
    scenario keys name are all there, and the paper's Zylon is the paper's."""
    assert MATERIALS["dyneema-sk76"].youngs_modulus == pytest.approx(116.4e9, rel=1e-12)
    assert set(MATERIALS) >= {"zylon", "zylon-as", "kevlar-29", "kevlar-49", "kevlar-km2",
                              "twaron", "dyneema-sk76"}
    z = MATERIALS["zylon"]
    assert (z.youngs_modulus, z.density, z.failure_strain) == (126e9, 1540.0, 0.03)


def test_teijin_units_agree_with_each_other():
    """Teijin prints the same strength and modulus in cN/dtex and in kgf/mm²: the two
    conversions agree within the rounding of the table (2 %)."""
    tw = MATERIALS["twaron"]
    kgf_strength = 300.0 * 9.80665e6     # 300 kg/mm² → 2.942 GPa
    kgf_modulus = 7470.0 * 9.80665e6     # 7470 kg/mm² → 73.26 GPa
    assert tw.tensile_strength == pytest.approx(kgf_strength, rel=0.02)
    assert tw.youngs_modulus == pytest.approx(kgf_modulus, rel=0.02)
    assert stress_si(*tw.published["tensile_strength_kgf"], tw.density) == kgf_strength


@pytest.mark.parametrize("name", list(MATERIALS))
def test_every_value_has_a_source(name):
    """Density, modulus, strength and failure strain each cite a key that CITATIONS holds,
    and every published number carries a unit."""
    m = MATERIALS[name]
    assert m.name == name and m.title
    for field in SI_FIELDS:
        assert m.sources.get(field) in CITATIONS, (name, field)
    if m.weibull_shape is not None:
        assert m.sources.get("weibull_shape") in CITATIONS
    for key, (value, unit) in m.published.items():
        assert math.isfinite(value) and value > 0 and unit, (name, key)


@pytest.mark.parametrize("name", list(MATERIALS))
def test_strength_is_roughly_modulus_times_failure_strain(name):
    """A sanity check of each entry, not physics: these fibres are nearly linear to break, so
    strength ≈ E·ε_f. A typo of a factor 10 (GPa for MPa, % for fraction) would land far
    outside 0.6-1.6; a real fibre lands inside (the aramids' curves stiffen, ratio > 1; UHMWPE
    softens, < 1; the paper's Zylon pairs an effective yarn modulus with the fibre strength,
    1.53)."""
    m = MATERIALS[name]
    ratio = m.tensile_strength / (m.youngs_modulus * m.failure_strain)
    assert 0.6 <= ratio <= 1.6, (name, ratio)


def test_unit_conversions_by_hand():
    """Denier → tex, per inch → per cm, oz/yd² → kg/m², N/tex → Pa, written out."""
    assert linear_density_tex(600.0, "denier") == pytest.approx(600.0 / 9.0, rel=REL)
    assert linear_density_tex(1760.0, "dtex") == pytest.approx(176.0, rel=REL)
    assert thread_count_per_cm(34.0, "1/in") == pytest.approx(34.0 / 2.54, rel=REL)
    assert areal_density_si(14.0, "oz/yd^2") == pytest.approx(14.0 * 33.906e-3, rel=1e-4)
    assert areal_density_si(180.0, "g/m^2") == pytest.approx(0.180, rel=REL)
    assert stress_si(3.7, "N/tex", 970.0) == pytest.approx(3.589e9, rel=REL)
    with pytest.raises(ValueError, match="allowed units"):
        areal_density_si(1.0, "lb/ft^2")


# name: (tex, ends/cm, picks/cm, areal kg/m², fibre density kg/m³), from the datasheets
STYLE_HAND = {
    "km2-600d-plain": (600 / 9, 34 / 2.54, 34 / 2.54, 0.180, 1440.0),
    "k29-3000d-plain": (3000 / 9, 17 / 2.54, 17 / 2.54, 14.0 * 33.906e-3, 1440.0),
    "sk76-1760dtex-plain": (176.0, 6.5, 6.5, 0.240, 970.0),
}


@pytest.mark.parametrize("name", list(STYLE_HAND))
def test_style_derived_values_by_hand(name):
    """Linear density, thread count and areal density from the datasheet's units; the yarn's
    load-bearing area tex·1e-6/ρ, its radius √(A/π) and the spacing 1 cm/count."""
    st = fabric_style(name)
    tex, ends, picks, areal, rho = STYLE_HAND[name]
    assert st.linear_density_tex == pytest.approx(tex, rel=REL)
    assert st.thread_count == pytest.approx((ends, picks), rel=REL)
    assert st.areal_density == pytest.approx(areal, rel=1e-4)
    area = tex * 1e-6 / rho                     # kg/m ÷ kg/m³
    assert st.yarn_area == pytest.approx(area, rel=REL)
    assert st.yarn_radius == pytest.approx(math.sqrt(area / math.pi), rel=REL)
    assert st.spacing == pytest.approx((0.01 / ends, 0.01 / picks), rel=REL)


def test_km2_706_numbers():
    """Style 706 by hand: 600 den = 66.67 tex; 66.67e-6 kg/m / 1440 kg/m³ = 4.630e-8 m², a
    circle of radius 121.4 µm; 34/in = 13.386/cm, spacing 0.747 mm."""
    st = STYLES["km2-600d-plain"]
    assert st.yarn_area == pytest.approx(4.6296e-8, rel=1e-4)
    assert st.yarn_radius == pytest.approx(121.39e-6, rel=1e-4)
    assert st.spacing[0] == pytest.approx(0.74706e-3, rel=1e-4)


@pytest.mark.parametrize("name", list(STYLES))
def test_areal_density_against_the_yarns(name):
    """A woven fabric weighs at least its straight yarns, (ends + picks)·tex per unit area,
    and not much more: crimp (the yarns' waviness) and finish add a few per cent, ~25 % at
    most for the constructions here."""
    st = STYLES[name]
    ends, picks = st.thread_count
    straight = (ends + picks) * 100.0 * st.linear_density_tex * 1e-6     # [kg/m²]
    assert straight <= st.areal_density <= 1.25 * straight, (name, st.areal_density, straight)
    assert st.crimp_allowance == pytest.approx(st.areal_density / straight - 1.0, rel=1e-9)


@pytest.mark.parametrize("name", list(STYLES))
def test_every_style_value_has_a_source(name):
    """A style names a library material, a weave, and a cited source for each derived field."""
    st = STYLES[name]
    assert st.name == name and st.title and st.weave
    assert st.material in MATERIALS
    for field in ("linear_density_tex", "thread_count", "areal_density"):
        assert st.sources.get(field) in CITATIONS, (name, field)
    for key, (value, unit) in st.published.items():
        assert math.isfinite(value) and value > 0 and unit, (name, key)


def test_required_styles():
    """A 600-denier KM2 weave, a 3000-denier Kevlar 29 weave and a Dyneema weave."""
    by_material = {(s.material, round(s.linear_density_tex * 9)) for s in STYLES.values()}
    assert ("kevlar-km2", 600) in by_material and ("kevlar-29", 3000) in by_material
    assert any(s.material == "dyneema-sk76" for s in STYLES.values())


def test_citations_are_full_references():
    """Every citation is used, and reads as a reference (a title, and a year or URL)."""
    used = {k for m in MATERIALS.values() for k in m.sources.values()}
    used |= {k for s in STYLES.values() for k in s.sources.values()}
    assert used == set(CITATIONS)
    for key, ref in CITATIONS.items():
        assert len(ref) > 60 and ("http" in ref or any(c.isdigit() for c in ref)), key


def test_unknown_names_list_the_allowed_ones():
    with pytest.raises(ValueError) as err:
        library_material("kevlar-99")
    assert "kevlar-99" in str(err.value)
    assert all(n in str(err.value) for n in MATERIALS)
    with pytest.raises(ValueError) as err:
        fabric_style("style-000")
    assert "style-000" in str(err.value)
    assert all(n in str(err.value) for n in STYLES)


def test_materials_command_table():
    """`emfabric materials` prints both tables and the references."""
    r = CliRunner().invoke(app, ["materials"])
    assert r.exit_code == 0, r.output
    for text in ("Materials", "Fabric styles", "kg/m³", "GPa", "116.4", "km2-600d-plain",
                 "13.39×13.39", "Sources", "Cheng", "doi:10.1115/1.1857937"):
        assert text in r.output, text
    for name in list(MATERIALS) + list(STYLES) + list(CITATIONS):
        assert name in r.output, name


def test_materials_command_json():
    """`emfabric materials --json`: the same data, SI units named in the keys."""
    r = CliRunner().invoke(app, ["materials", "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.output)
    mats = {m["name"]: m for m in data["materials"]}
    assert set(mats) == set(MATERIALS)
    sk76 = mats["dyneema-sk76"]
    assert sk76["youngs_modulus_pa"] == pytest.approx(116.4e9)
    assert sk76["density_kg_m3"] == 970.0
    assert sk76["published"]["modulus"] == {"value": 120.0, "unit": "N/tex"}
    styles = {s["name"]: s for s in data["styles"]}
    km2 = styles["km2-600d-plain"]
    assert km2["denier"] == pytest.approx(600.0)
    assert km2["yarn_radius_m"] == pytest.approx(STYLES["km2-600d-plain"].yarn_radius)
    assert km2["areal_density_kg_m2"] == pytest.approx(0.180)
    assert data["citations"] == CITATIONS
