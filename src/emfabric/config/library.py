"""The material and fabric-style library (issue 24): fibres and woven fabrics as their sources
publish them, with the SI values emfabric uses derived from those numbers in code.

Every entry keeps ``published``: each number exactly as its source states it, with the
source's unit ("N/tex", "oz/yd^2", "1/in", ...). The SI fields (density [kg/m³], modulus and
strength [Pa], strain [-], linear density [tex], thread count [1/cm], areal density [kg/m²])
are computed from those numbers by the conversion functions below, never typed twice, and
``sources`` names the citation (a key of CITATIONS) of every SI field. docs/materials.md is
the table with the full references; ``emfabric materials`` prints it.

Conversions (exact where the unit is defined exactly):

- specific stress (tenacity, specific modulus) to stress: σ [Pa] = T [N/tex] · ρ [kg/m³] · 1e6
  (1 tex = 1e-6 kg/m, so N/tex = 1e6 N·m/kg); 1 cN/dtex = 0.1 N/tex; 1 gf/den = 9·g₀/1000
  N/tex = 0.0882599 N/tex; 1 kgf/mm² = 9.80665 MPa;
- denier to tex: tex = den/9 (g per 9 km against g per km); dtex = tex/10;
- per-inch to per-cm thread counts: /2.54;
- oz/yd² to kg/m²: 0.028349523125 kg / 0.83612736 m² = 33.906 g/m².
"""

from __future__ import annotations

import math
from dataclasses import dataclass

G0 = 9.80665
"""Standard gravity [m/s²] (gram-force, kilogram-force)."""
OUNCE = 0.028349523125
"""Avoirdupois ounce [kg] (exact)."""
YARD = 0.9144
"""Yard [m] (exact)."""
INCH = 0.0254
"""Inch [m] (exact)."""

_DENSITY = {"kg/m^3": 1.0, "g/cm^3": 1000.0}
_STRESS = {"Pa": 1.0, "MPa": 1e6, "GPa": 1e9, "kgf/mm^2": G0 * 1e6}
_SPECIFIC = {"N/tex": 1.0, "cN/dtex": 0.1, "gf/den": 9.0 * G0 / 1000.0}
"""Specific stress units, as N/tex."""
_STRAIN = {"-": 1.0, "%": 0.01}
_LINEAR = {"tex": 1.0, "dtex": 0.1, "denier": 1.0 / 9.0}
"""Linear density units, as tex."""
_COUNT = {"1/cm": 1.0, "1/in": 0.01 / INCH}
"""Thread count units, as 1/cm."""
_AREAL = {"kg/m^2": 1.0, "g/m^2": 1e-3, "oz/yd^2": OUNCE / YARD**2}


def _unit(table: dict[str, float], unit: str, what: str) -> float:
    try:
        return table[unit]
    except KeyError:
        raise ValueError(f"{what} in {unit!r}: allowed units: {', '.join(table)}") from None


def density_si(value: float, unit: str) -> float:
    """A fibre density as published, in kg/m³."""
    return value * _unit(_DENSITY, unit, "density")


def stress_si(value: float, unit: str, density: float) -> float:
    """A modulus or strength as published, in Pa: a stress unit as it is; a specific unit
    (N/tex, cN/dtex, gf/den) times the fibre density [kg/m³]."""
    if unit in _SPECIFIC:
        return value * _SPECIFIC[unit] * 1e6 * density
    return value * _unit(_STRESS, unit, "stress")


def strain_si(value: float, unit: str) -> float:
    """A strain as published (% or -), as a fraction [-]."""
    return value * _unit(_STRAIN, unit, "strain")


def linear_density_tex(value: float, unit: str) -> float:
    """A yarn linear density as published (tex, dtex, denier), in tex [g/km]."""
    return value * _unit(_LINEAR, unit, "linear density")


def thread_count_per_cm(value: float, unit: str) -> float:
    """A thread count as published (1/cm or 1/in), per cm."""
    return value * _unit(_COUNT, unit, "thread count")


def areal_density_si(value: float, unit: str) -> float:
    """An areal density as published (g/m², oz/yd², kg/m²), in kg/m²."""
    return value * _unit(_AREAL, unit, "areal density")


@dataclass(frozen=True)
class LibraryMaterial:
    """A fibre with its published properties and the SI values derived from them."""

    name: str
    """Library key, e.g. "kevlar-km2"."""
    title: str
    density: float
    """Fibre density [kg/m³]."""
    youngs_modulus: float
    """Tensile modulus along the fibre [Pa]."""
    tensile_strength: float
    """Tensile strength [Pa]."""
    failure_strain: float
    """Engineering strain at break [-]."""
    weibull_shape: float | None
    """Weibull modulus of the fibre or yarn strength where a cited source measured one."""
    sources: dict[str, str]
    """SI field name -> citation key in CITATIONS."""
    published: dict[str, tuple[float, str]]
    """Every number as its source states it, with its unit."""


@dataclass(frozen=True)
class FabricStyle:
    """A woven fabric from its datasheet, and the yarn network it gives."""

    name: str
    """Library key, e.g. "km2-600d-plain"."""
    title: str
    material: str
    """Fibre: a MATERIALS key."""
    linear_density_tex: float
    """Yarn linear density [tex = g/km]."""
    thread_count: tuple[float, float]
    """(ends, picks) per cm."""
    areal_density: float
    """Fabric areal density [kg/m²]."""
    weave: str
    sources: dict[str, str]
    published: dict[str, tuple[float, str]]

    @property
    def yarn_area(self) -> float:
        """Load-bearing cross-section of a yarn [m²]: linear density [kg/m] / fibre density."""
        return self.linear_density_tex * 1e-6 / MATERIALS[self.material].density

    @property
    def yarn_radius(self) -> float:
        """Radius of the circle of the yarn's load-bearing area [m]."""
        return math.sqrt(self.yarn_area / math.pi)

    @property
    def spacing(self) -> tuple[float, float]:
        """(warp, weft) yarn spacing [m]: 1 cm / (ends, picks)."""
        ends, picks = self.thread_count
        return (0.01 / ends, 0.01 / picks)

    @property
    def crimp_allowance(self) -> float:
        """Areal density over the straight-yarn mass (ends + picks) · linear density, minus 1
        [-]: the extra yarn length that weaving's crimp (and finish) puts into a square metre."""
        ends, picks = self.thread_count
        straight = (ends + picks) * 100.0 * self.linear_density_tex * 1e-6
        return self.areal_density / straight - 1.0


# ---------------------------------------------------------------------------------------------
# Sources. "Checked" means the number was read on a reachable copy of the document (or of a
# page quoting it); the others are the values the document is known to publish, marked so.

CITATIONS: dict[str, str] = {
    "zohdi-paper": (
        "T. I. Zohdi, 'High-speed impact of electromagnetically sensitive fabric and induced "
        "projectile spin' (the paper emfabric implements): section 5 model problem, 'effective "
        "Young's modulus of a yarn E = 126 GPa', 'Zylon (PBO) solid material density = 1540 "
        "kg/m³', and footnote 2, 'Zylon ruptures at approximately a 3% axial strain (Toyobo "
        "[40])'. Checked against the paper's text."
    ),
    "toyobo-zylon": (
        "Toyobo Co., Ltd., 'ZYLON (PBO fiber) Technical Information (Revised 2005.6)', section 1 "
        "Basic properties (Zylon AS: density 1.54 g/cm³, tensile strength 5.8 GPa, tensile "
        "modulus 180 GPa, elongation at break 3.5 %; Zylon HM: 1.56 g/cm³, 5.8 GPa, 270 GPa, "
        "2.5 %). https://www.toyobo-global.com/products/zylon/ (copy: https://www.yumpu.com/en/"
        "document/view/27944419/zylon-technical-informationpdf-metal-clad-fiber). Densities "
        "checked on that copy; strength, modulus and elongation checked only on pages quoting "
        "the document (Michigan Tech MY4150 fibre table; IMATTEC product page: 'Elongation "
        "3.5%-2.5%(HM)'), not on the document's own table."
    ),
    "dupont-kevlar": (
        "DuPont, 'Kevlar Aramid Fiber Technical Guide' (H-77848), Table 'Typical Properties of "
        "Kevlar Yarns' (Kevlar 29: 1.44 g/cm³, 2,920 MPa, 70.5 GPa, 3.6 %; Kevlar 49: 1.44 "
        "g/cm³, 3,000 MPa, 112.4 GPa, 2.4 %). https://www.dupont.com/"
        "content/dam/dupont/amer/us/en/safety/public/documents/en/Kevlar_Technical_Guide_0319.pdf"
        ". Values as published in the guide; not checked against the document here (only its "
        "table of contents was reachable). Kevlar KM2 is not in this table; its density is taken "
        "as the guide's 1.44 g/cm³ for Kevlar para-aramid yarns."
    ),
    "cheng-2005": (
        "M. Cheng, W. Chen and T. Weerasooriya, 'Mechanical Properties of Kevlar KM2 Single "
        "Fiber', Journal of Engineering Materials and Technology 127(2):197-203 (2005), "
        "doi:10.1115/1.1857937. Single-fibre tension: linear elastic to failure (checked in "
        "the abstract); axial modulus 84.62 GPa, strength 3.88 GPa, failure strain 4.52 % are "
        "the values as published in the paper, not checked against it here."
    ),
    "teijin-tensile": (
        "Teijin Ltd., 'Technora: Tensile properties', Table 3 'Tensile Properties of Industrial "
        "Fibers', row 'PPTA (reg)' (regular para-aramid, Teijin's Twaron type): density 1.44 "
        "g/cm³, tensile strength 20.8 cN/dtex (300 kg/mm²), tensile modulus 500 cN/dtex (7470 "
        "kg/mm²), elongation at break 3.5 %. https://www.teijin.com/products/advanced_fibers/"
        "aramid/contents/aramid/technora/eng/bussei/tech_bussei_hippari.htm. Checked on that "
        "page. The row names the polymer, not the brand: Teijin's Twaron brochure ('Twaron, a "
        "true all-round para-aramid performer') gives ranges per type."
    ),
    "dsm-sk76": (
        "DSM Dyneema, 'Dyneema SK76' product data sheet (1760 dtex): tenacity 3.7 N/tex, "
        "modulus 120 N/tex, elongation at break 3.8 %, density 0.97 g/cm³. Values as published "
        "in the data sheet; not checked against the document here. They lie within the checked "
        "ranges of the DSM Dyneema fact sheet 'UHMWPE fiber' (CIS YA100, 15-11-2010; copy: "
        "http://issuu.com/eurofibers/docs/name8f0d44) for the SK75/SK78 grades: 3.4-4.0 N/tex, "
        "112-137 N/tex, 3-4 %; the density 0.97 g/cm³ is also checked in Sanborn, DiLeonardi "
        "and Weerasooriya, J. Dynamic Behavior Mater. 1:4-14 (2015), doi:10.1007/"
        "s40870-014-0001-3."
    ),
    "hexcel-706": (
        "Hexcel (formerly Clark-Schwebel), ballistic fabric style 706: Kevlar KM2, 600 denier, "
        "34 x 34 ends/picks per inch, plain weave, 180 g/m². Values as published for the style "
        "and widely used in the US Army Research Laboratory's single-ply models; not checked "
        "against a Hexcel document here."
    ),
    "hexcel-745": (
        "Hexcel (formerly Clark-Schwebel), ballistic fabric style 745: Kevlar 29, 3000 denier, "
        "17 x 17 ends/picks per inch, plain weave, 14.0 oz/yd². Values as published for the "
        "style; not checked against a Hexcel document here."
    ),
    "example-dyneema-weave": (
        "Not a datasheet: no woven Dyneema SK76 style could be checked. This construction is "
        "an example built here: the 1760 dtex yarn of the DSM fact sheet (checked: SK75/SK78 "
        "are sold at 1760 dtex), 6.5 ends and 6.5 picks per cm, plain weave, with the "
        "areal density 240 g/m² (the straight yarns' 228.8 g/m² and a 5 % crimp allowance, "
        "rounded). Replace it with a weaver's datasheet before drawing conclusions about a "
        "real fabric."
    ),
}


def _material(name: str, title: str, published: dict[str, tuple[float, str]],
              fields: dict[str, str], sources: dict[str, str],
              weibull: str | None = None) -> LibraryMaterial:
    """A library material whose SI fields are derived from `published`: `fields` maps each of
    density, youngs_modulus, tensile_strength, failure_strain to its published key."""
    rho = density_si(*published[fields["density"]])
    return LibraryMaterial(
        name=name, title=title, density=rho,
        youngs_modulus=stress_si(*published[fields["youngs_modulus"]], rho),
        tensile_strength=stress_si(*published[fields["tensile_strength"]], rho),
        failure_strain=strain_si(*published[fields["failure_strain"]]),
        weibull_shape=None if weibull is None else float(published[weibull][0]),
        sources=sources, published=published)


_ALL = ("density", "youngs_modulus", "tensile_strength", "failure_strain")
_FIBRE = {"density": "density", "youngs_modulus": "tensile_modulus",
          "tensile_strength": "tensile_strength", "failure_strain": "elongation_at_break"}

MATERIALS: dict[str, LibraryMaterial] = {m.name: m for m in (
    _material(
        "zylon", "Zylon PBO, the paper's (effective yarn modulus)",
        {"solid_density": (1540.0, "kg/m^3"), "effective_yarn_modulus": (126.0, "GPa"),
         "rupture_strain": (3.0, "%"), "tensile_strength": (5.8, "GPa")},
        {"density": "solid_density", "youngs_modulus": "effective_yarn_modulus",
         "tensile_strength": "tensile_strength", "failure_strain": "rupture_strain"},
        {"density": "zohdi-paper", "youngs_modulus": "zohdi-paper",
         "failure_strain": "zohdi-paper", "tensile_strength": "toyobo-zylon"}),
    _material(
        "zylon-as", "Zylon AS (Toyobo PBO, as spun)",
        {"density": (1.54, "g/cm^3"), "tensile_strength": (5.8, "GPa"),
         "tensile_modulus": (180.0, "GPa"), "elongation_at_break": (3.5, "%")},
        _FIBRE, dict.fromkeys(_ALL, "toyobo-zylon")),
    _material(
        "kevlar-29", "Kevlar 29 (DuPont para-aramid yarn)",
        {"density": (1.44, "g/cm^3"), "tensile_strength": (2920.0, "MPa"),
         "tensile_modulus": (70.5, "GPa"), "elongation_at_break": (3.6, "%")},
        _FIBRE, dict.fromkeys(_ALL, "dupont-kevlar")),
    _material(
        "kevlar-49", "Kevlar 49 (DuPont high-modulus para-aramid yarn)",
        {"density": (1.44, "g/cm^3"), "tensile_strength": (3000.0, "MPa"),
         "tensile_modulus": (112.4, "GPa"), "elongation_at_break": (2.4, "%")},
        _FIBRE, dict.fromkeys(_ALL, "dupont-kevlar")),
    _material(
        "kevlar-km2", "Kevlar KM2 (DuPont ballistic para-aramid; single-fibre tests)",
        {"density": (1.44, "g/cm^3"), "tensile_strength": (3.88, "GPa"),
         "tensile_modulus": (84.62, "GPa"), "elongation_at_break": (4.52, "%")},
        _FIBRE,
        {"density": "dupont-kevlar", "youngs_modulus": "cheng-2005",
         "tensile_strength": "cheng-2005", "failure_strain": "cheng-2005"}),
    _material(
        "twaron", "Twaron (Teijin regular para-aramid, PPTA)",
        {"density": (1.44, "g/cm^3"), "tensile_strength": (20.8, "cN/dtex"),
         "tensile_modulus": (500.0, "cN/dtex"), "elongation_at_break": (3.5, "%"),
         "tensile_strength_kgf": (300.0, "kgf/mm^2"),
         "tensile_modulus_kgf": (7470.0, "kgf/mm^2")},
        _FIBRE, dict.fromkeys(_ALL, "teijin-tensile")),
    _material(
        "dyneema-sk76", "Dyneema SK76 (DSM UHMWPE)",
        {"density": (0.97, "g/cm^3"), "tenacity": (3.7, "N/tex"),
         "modulus": (120.0, "N/tex"), "elongation_at_break": (3.8, "%")},
        {"density": "density", "youngs_modulus": "modulus", "tensile_strength": "tenacity",
         "failure_strain": "elongation_at_break"},
        dict.fromkeys(_ALL, "dsm-sk76")),
)}


def _style(name: str, title: str, material: str, weave: str,
           published: dict[str, tuple[float, str]], source: str) -> FabricStyle:
    """A fabric style whose SI fields are derived from `published` (keys "yarn", "ends",
    "picks", "areal_density"), all from one source."""
    return FabricStyle(
        name=name, title=title, material=material,
        linear_density_tex=linear_density_tex(*published["yarn"]),
        thread_count=(thread_count_per_cm(*published["ends"]),
                      thread_count_per_cm(*published["picks"])),
        areal_density=areal_density_si(*published["areal_density"]),
        weave=weave,
        sources=dict.fromkeys(("linear_density_tex", "thread_count", "areal_density",
                               "weave"), source),
        published=published)


STYLES: dict[str, FabricStyle] = {s.name: s for s in (
    _style("km2-600d-plain", "Kevlar KM2 600 denier plain weave (Hexcel style 706)",
           "kevlar-km2", "plain",
           {"yarn": (600.0, "denier"), "ends": (34.0, "1/in"), "picks": (34.0, "1/in"),
            "areal_density": (180.0, "g/m^2")}, "hexcel-706"),
    _style("k29-3000d-plain", "Kevlar 29 3000 denier plain weave (Hexcel style 745)",
           "kevlar-29", "plain",
           {"yarn": (3000.0, "denier"), "ends": (17.0, "1/in"), "picks": (17.0, "1/in"),
            "areal_density": (14.0, "oz/yd^2")}, "hexcel-745"),
    _style("sk76-1760dtex-plain",
           "Dyneema SK76 1760 dtex plain weave (example construction, not a datasheet)",
           "dyneema-sk76", "plain",
           {"yarn": (1760.0, "dtex"), "ends": (6.5, "1/cm"), "picks": (6.5, "1/cm"),
            "areal_density": (240.0, "g/m^2")},
           "example-dyneema-weave"),
)}


def library_material(name: str) -> LibraryMaterial:
    """The library material `name`, or a ValueError naming it and the allowed names."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise ValueError(f"material {name!r} is not in the library: allowed: "
                         f"{', '.join(MATERIALS)}") from None


def fabric_style(name: str) -> FabricStyle:
    """The fabric style `name`, or a ValueError naming it and the allowed names."""
    try:
        return STYLES[name]
    except KeyError:
        raise ValueError(f"fabric style {name!r} is not in the library: allowed: "
                         f"{', '.join(STYLES)}") from None
