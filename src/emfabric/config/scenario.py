"""Scenario files: the TOML schema as validated, frozen types; load, dump, dotted overrides.

Every default is the paper's section-5 value (Zohdi, model problem), so an empty file is the
paper's field-on case. Unknown keys and bad values raise :class:`ScenarioError`, whose message
names the key's dotted path, the value given and what is allowed.
"""

from __future__ import annotations

import ast
import copy
import difflib
import json
import logging
import math
import re
import tomllib
from importlib import resources
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import tomli_w
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo

Vec3 = tuple[float, float, float]
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
FiniteVec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
LIGHT_SPEED = 299_792_458.0
"""The speed of light [m/s]: the model is Newtonian, and an initial speed must be below it."""


def _slower_than_light(v: tuple) -> tuple:
    speed = math.hypot(*v)  # no overflow for components near the largest double
    if not speed < LIGHT_SPEED:
        raise ValueError(f"a speed of {speed:.4g} m/s; allowed: below the speed of light, "
                         f"{LIGHT_SPEED:.9g} m/s (the model is Newtonian)")
    return v


Velocity = Annotated[FiniteVec3, AfterValidator(_slower_than_light)]
"""An initial velocity [m/s]: finite, and slower than light."""


def _library_material_name(v: str | None) -> str | None:
    if v is not None:
        from emfabric.config.library import library_material

        library_material(v)  # ValueError naming the allowed names
    return v


def _fabric_style_name(v: str | None) -> str | None:
    if v is not None:
        from emfabric.config.library import fabric_style

        fabric_style(v)  # ValueError naming the allowed styles
    return v


def straight_yarn_mass(tex: float, thread_count: tuple[float, float]) -> float:
    """The areal density of a weave's straight yarns [kg/m²]: tex [g/km] = 1e-6 kg/m, and
    ends + picks per cm make 100 (ends + picks) m of yarn per m² (crimp adds to it)."""
    return tex * 1e-6 * 100.0 * (thread_count[0] + thread_count[1])


WEIBULL_SHAPE_MIN = 0.5
"""The smallest Weibull modulus a scenario may give (besides 0, no scatter): m = 0.5 already
scatters the failure strains by 224 % (coefficient of variation √(Γ(1 + 2/m)/Γ(1 + 1/m)² − 1)),
and below about 0.006 the mean's normalisation Γ(1 + 1/m) overflows a double."""


def _weibull_shape(v: float | None) -> float | None:
    if v is not None and 0.0 < v < WEIBULL_SHAPE_MIN:
        raise ValueError(f"must be 0 (no scatter) or at least {WEIBULL_SHAPE_MIN} (m = 0.5 "
                         "already scatters the failure strains by 224 %)")
    return v


WeibullShape = Annotated[NonNegFloat, AfterValidator(_weibull_shape)]
"""A Weibull modulus [-]: 0 (no scatter) or at least WEIBULL_SHAPE_MIN."""
MaterialName = Annotated[str | None, AfterValidator(_library_material_name)]
"""A material of the library (emfabric.config.library), or None."""
StyleName = Annotated[str | None, AfterValidator(_fabric_style_name)]
"""A fabric style of the library, or None."""



class ScenarioError(ValueError):
    """A scenario file or override is invalid; the message names key, value and what is allowed."""


class _Section(BaseModel):
    # strict: no string-to-number or number-to-bool coercion (a TOML "0.037" is an error)
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True,
                              use_attribute_docstrings=True)


LIBRARY_KEYS = ("youngs_modulus", "density", "tensile_strength", "failure_strain")
"""MaterialSpec keys a library material supplies where the scenario does not write them."""


def _set_unset(section: BaseModel, values: dict[str, Any]) -> None:
    """Fill a frozen section's keys the scenario did not write (its model_fields_set keeps
    only what was written, so an override of the library name can drop what came from it)."""
    for key, value in values.items():
        if key not in section.model_fields_set:
            object.__setattr__(section, key, value)


class MaterialSpec(_Section):
    name: MaterialName = None
    """A library material (`emfabric materials`; docs/materials.md): "zylon" (the paper's),
    "zylon-as", "kevlar-29", "kevlar-49", "kevlar-km2", "twaron", "dyneema-sk76"; it supplies
    youngs_modulus, density, tensile_strength and failure_strain where they are not written."""
    model: Literal["kirchhoff-saint-venant", "fung"] = "kirchhoff-saint-venant"
    """Yarn law: "kirchhoff-saint-venant" (relaxed, eq. 2.4) or "fung" (section 6)."""
    youngs_modulus: PositiveFloat = 126e9
    """Mean Young's modulus of a yarn [Pa] (KSV law; default the paper's, or the library's)."""
    modulus_cv: NonNegFloat = 0.10
    """Coefficient of variation of the per-yarn modulus (Gaussian scatter)."""
    seed: Annotated[int, Field(ge=0)] = 0
    """Seed of numpy.random.default_rng for the modulus scatter (and the strength scatter)."""
    c: PositiveFloat | None = None
    """Fung constant c [Pa] (model = "fung")."""
    H: PositiveFloat | None = None
    """Fung constant H [-] (model = "fung")."""
    density: PositiveFloat | None = None
    """Fibre density [kg/m³] (the library's; with a yarn linear density it gives the yarn's
    cross-section)."""
    tensile_strength: PositiveFloat | None = None
    """Yarn tensile strength [Pa] (the library's; reported against the electrostatic
    pressure)."""
    failure_strain: PositiveFloat | None = None
    """Engineering strain at break [-] (the library's; the default of damage.failure_strain)."""

    @model_validator(mode="after")
    def _fung_needs_constants(self) -> MaterialSpec:
        if self.model == "fung":
            missing = [k for k in ("c", "H") if getattr(self, k) is None]
            if missing:
                raise ValueError(
                    f"model = 'fung' needs {' and '.join(missing)} (positive numbers): "
                    "S = c·H·E·exp(H·E²/2)"
                )
        return self

    @model_validator(mode="after")
    def _library_values(self) -> MaterialSpec:
        if self.name is not None:
            from emfabric.config.library import library_material

            lib = library_material(self.name)
            _set_unset(self, {key: getattr(lib, key) for key in LIBRARY_KEYS})
        return self


class Damage(_Section):
    law: Literal["zohdi", "brittle"] | None = None
    """"zohdi" (eq. 2.6: gradual, past critical_stretch at rate λ) or "brittle" (a yarn carries
    load up to its failure strain, then none). Not given: the law whose keys are written
    (failure_strain, weibull_shape, strain_averaging: brittle; critical_stretch, rate: zohdi),
    else "brittle" with a library material (fabric.material.name or fabric.style), else
    "zohdi" (the paper's)."""
    critical_stretch: Annotated[float, Field(ge=1.0, allow_inf_nan=False)] = 1.03
    """U_crit of eq. 2.6 [-] (law = "zohdi")."""
    rate: NonNegFloat = 0.1
    """Damage decay parameter λ of eq. 2.6 [-]; 0 disables damage (law = "zohdi")."""
    broken_below: Annotated[float, Field(gt=0, lt=1)] = 0.01
    """A yarn whose α falls below this counts as broken in the statistics."""
    failure_strain: PositiveFloat | None = None
    """law = "brittle": mean engineering strain at break of a segment at the reference spacing
    [-]; default fabric.material.failure_strain (the library's)."""
    weibull_shape: WeibullShape = 0.0
    """law = "brittle": Weibull modulus m of the per-segment failure strain (0: no scatter, every
    segment breaks at failure_strain) [-]. Seeded by fabric.material.seed."""
    strain_averaging: Annotated[float, Field(ge=0.0, le=100.0)] = 5.0
    """law = "brittle": a segment breaks when its stretch, averaged over this many times the
    time a wave takes to cross it (τ = n·√(m̄/k), an exponential average), passes its stretch
    at break, or at once when its Green strain passes 1.25 × its Green strain at break [-].
    It removes the lumped network's ringing at a struck node (+21 % for ~10 h/c), which broke
    a yarn struck at 0.87 of Smith's critical speed, and converges to the instantaneous
    criterion as the spacing shrinks; 0: the instantaneous stretch (docs/theory.md §2.1)."""

    @property
    def brittle(self) -> bool:
        return self.law == "brittle"


class Fabric(_Section):
    nodes: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] = (100, 100)
    """Grid nodes along x and y [-]."""
    size: tuple[PositiveFloat, PositiveFloat] = (0.254, 0.254)
    """Sheet size [m] along x and y."""
    areal_density: PositiveFloat = 0.12784
    """[kg/m²] (default the paper's; a style's; or, from yarn_linear_density and thread_count
    without a style, the mass of the straight yarns, tex × (ends + picks): no crimp)."""
    yarn_radius: PositiveFloat = 0.000185
    """[m]; A0 = π r²."""
    charge_per_node: FiniteFloat = 1.0
    """[C]."""
    edges: Literal["clamped", "free"] = "clamped"
    """Boundary nodes: "clamped" (fixed) or "free"."""
    velocity: Velocity = (0.0, 0.0, 0.0)
    """Initial velocity of every free node [m/s]."""
    rescale: bool = True
    """Run this grid as the same fabric as `reference_nodes` on this sheet: yarn area scales
    with the spacing (same stiffness per unit width), charge with the node mass (same q/m);
    false: yarn_radius and charge_per_node are taken as they are at this spacing."""
    reference_nodes: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] = (100, 100)
    """Grid on this sheet that yarn_radius and charge_per_node describe (rescale = true) [-]."""
    material: MaterialSpec = MaterialSpec()
    damage: Damage = Damage()
    plies: Annotated[int, Field(ge=1, le=64)] = 1
    """Plies in the pack [-] (default 1: one sheet; not given, as many as [[fabric.ply]]
    tables, else as ply_angles)."""
    ply_spacing: PositiveFloat | None = None
    """Distance between neighbouring plies' mid-planes [m]: ply 1 at z = 0, the others below
    it; default: touching (the sum of their yarn radii)."""
    ply_angles: tuple[FiniteFloat, ...] = ()
    """In-plane rotation of each ply's weave [deg], one per ply (default: all 0). A weave at
    a multiple of 90° is the frame's grid; at any other angle it is the rotated grid clipped
    to the frame (its nodes on or outside the frame next to the sheet are clamped)."""
    ply: tuple[PlySpec, ...] = ()
    """Per-ply overrides ([[fabric.ply]] tables, one per ply, in order from the top): any
    fabric key that is not the frame's geometry."""
    style: StyleName = None
    """A fabric from its datasheet (`emfabric materials`; docs/materials.md), e.g.
    "km2-600d-plain": supplies material.name, yarn_linear_density, thread_count and
    areal_density where they are not written."""
    yarn_linear_density: PositiveFloat | None = None
    """Yarn linear density [tex = g/km] (denier/9): with the fibre density (material.density)
    it gives the yarn's cross-section, so yarn_radius = √(tex/(ρ π)) where it is not written."""
    yarn_denier: PositiveFloat | None = None
    """Yarn linear density in denier [g/9 km]; the same as yarn_linear_density = denier/9."""
    thread_count: tuple[PositiveFloat, PositiveFloat] | None = None
    """Ends and picks per cm [1/cm] (warp yarns run along x, ends/cm counted along y): the yarn
    spacing. Where reference_nodes is not written it is one network line per yarn on this
    sheet, and where nodes is not written the network is that one."""

    @model_validator(mode="after")
    def _datasheet(self) -> Fabric:
        if self.style is not None:
            from emfabric.config.library import fabric_style

            st = fabric_style(self.style)
            if self.material.name is None:
                written = self.material.model_dump(include=self.material.model_fields_set)
                material = MaterialSpec.model_validate({**written, "name": st.material})
                object.__setattr__(material, "__pydantic_fields_set__",
                                   set(self.material.model_fields_set))
                object.__setattr__(self, "material", material)
            given = {"yarn_linear_density", "yarn_denier"} & self.model_fields_set
            _set_unset(self, {"areal_density": st.areal_density,
                              "thread_count": tuple(st.thread_count)})
            if not given:
                _set_unset(self, {"yarn_linear_density": st.linear_density_tex})
        if self.yarn_denier is not None:
            if ("yarn_linear_density" in self.model_fields_set and not math.isclose(
                    self.yarn_linear_density, self.yarn_denier / 9.0, rel_tol=1e-12)):
                raise ValueError(
                    f"yarn_denier = {self.yarn_denier} and yarn_linear_density = "
                    f"{self.yarn_linear_density}: allowed: one of them (tex = denier/9)")
            object.__setattr__(self, "yarn_linear_density", self.yarn_denier / 9.0)
        if (self.style is None and self.yarn_linear_density is not None
                and self.thread_count is not None):
            # a datasheet without a style and without an areal density: its straight yarns'
            # mass, tex × (ends + picks) (no crimp: a written areal_density holds it)
            _set_unset(self, {"areal_density": straight_yarn_mass(self.yarn_linear_density,
                                                                  self.thread_count)})
        if self.yarn_linear_density is not None:
            rho = self.material.density
            if rho is None:
                given = (f"yarn_denier = {self.yarn_denier}" if self.yarn_denier is not None
                         and "yarn_linear_density" not in self.model_fields_set else
                         f"yarn_linear_density = {self.yarn_linear_density} tex")
                raise ValueError(
                    f"{given} needs the fibre density: allowed: a library material "
                    "(material.name) or material.density [kg/m³]")
            area = self.yarn_linear_density * 1e-6 / rho
            _set_unset(self, {"yarn_radius": math.sqrt(area / math.pi)})
        if self.thread_count is not None:
            lx, ly = self.size
            ends, picks = self.thread_count
            lines = (max(2, round(lx * 100.0 * picks) + 1), max(2, round(ly * 100.0 * ends) + 1))
            _set_unset(self, {"reference_nodes": lines})
            _set_unset(self, {"nodes": self.reference_nodes})
        return self

    @model_validator(mode="after")
    def _damage_law(self) -> Fabric:
        dmg = self.damage
        if dmg.law is None:
            # not given: a key only one law reads chooses it (as the φ-scheme's keys choose the
            # φ-scheme), else the library material's failure (brittle), else eq. 2.6
            brittle_keys = (dmg.failure_strain is not None or dmg.weibull_shape > 0.0
                            or dmg.strain_averaging != Damage.model_fields[
                                "strain_averaging"].default)
            zohdi_keys = any(getattr(dmg, k) != Damage.model_fields[k].default
                             for k in ("critical_stretch", "rate"))
            # a library material: the pack's, or every ply's own (a style or a material name)
            library = self.material.name is not None or (bool(self.ply) and all(
                t.style is not None or (t.material is not None and t.material.name is not None)
                for t in self.ply))
            law = ("brittle" if brittle_keys and not zohdi_keys else
                   "zohdi" if zohdi_keys and not brittle_keys else
                   "brittle" if library else "zohdi")
            written = dmg.model_dump(include=dmg.model_fields_set)
            damage = Damage.model_validate({**written, "law": law})
            object.__setattr__(damage, "__pydantic_fields_set__", set(dmg.model_fields_set))
            object.__setattr__(self, "damage", damage)
            dmg = damage
        for i, table in enumerate(self.ply):
            if table.damage is not None and table.damage.law not in (None, dmg.law):
                raise ValueError(
                    f"ply[{i}].damage.law = {table.damage.law!r} differs from fabric.damage.law "
                    f"= {dmg.law!r}; allowed: one damage law for the whole pack")
            if table.damage is not None and not dmg.brittle:
                for key in ("failure_strain", "weibull_shape"):
                    value = getattr(table.damage, key)
                    if value is not None and value != 0.0:
                        raise ValueError(
                            f"ply[{i}].damage.{key} = {value} is a key of law = 'brittle'; the "
                            f"pack's law is {dmg.law!r} (one law per pack): allowed: "
                            "fabric.damage.law = 'brittle' with it, or leave it out")
        if dmg.brittle:
            own = bool(self.ply) and all(  # every ply with a failure strain of its own
                t.style is not None
                or (t.material is not None and (t.material.name is not None
                                                or t.material.failure_strain is not None))
                or (t.damage is not None and t.damage.failure_strain is not None)
                for t in self.ply)
            if dmg.failure_strain is None and self.material.failure_strain is None and not own:
                # the key that chose the law (failure_strain is not given here)
                chooser = ("weibull_shape" if dmg.weibull_shape > 0.0 else "strain_averaging")
                why = ("damage.law = 'brittle'" if "law" in dmg.model_fields_set else
                       f"damage.{chooser} = {getattr(dmg, chooser)} chooses law = 'brittle', "
                       "which")
                raise ValueError(
                    f"{why} needs a failure strain: allowed: damage.failure_strain, "
                    "material.failure_strain or a library material (material.name)")
            # (the defaults are allowed: a full scenario written out holds every key; and
            # rate = 0, eq. 2.6 off)
            zohdi = {k for k in ("critical_stretch", "rate")
                     if getattr(dmg, k) not in (Damage.model_fields[k].default, 0.0)}
            if zohdi:
                key = sorted(zohdi)[0]
                raise ValueError(
                    f"damage.{key} = {getattr(dmg, key)} is a key of law = 'zohdi' (eq. 2.6); "
                    "with law = 'brittle' a yarn breaks at failure_strain: allowed: "
                    "failure_strain, weibull_shape, strain_averaging")
        else:
            brittle = set() if dmg.failure_strain is None else {"failure_strain"}
            if dmg.weibull_shape > 0.0:
                brittle.add("weibull_shape")
            if dmg.strain_averaging != Damage.model_fields["strain_averaging"].default:
                brittle.add("strain_averaging")
            if brittle:
                key = sorted(brittle)[0]
                raise ValueError(
                    f"damage.{key} = {getattr(dmg, key)} is a key of law = 'brittle'; the "
                    "law is 'zohdi' (eq. 2.6): allowed: law = 'brittle' with it, or "
                    "critical_stretch and rate")
        return self

    def failure_strain(self) -> float | None:
        """The brittle law's mean failure strain of this fabric (damage, else material)."""
        if not self.damage.brittle:
            return None
        fs = self.damage.failure_strain
        return fs if fs is not None else self.material.failure_strain

    @model_validator(mode="before")
    @classmethod
    def _plies_from_tables(cls, data: Any) -> Any:
        # plies not given: as many as [[fabric.ply]] tables, else as ply_angles
        if isinstance(data, dict) and "plies" not in data:
            for key in ("ply", "ply_angles"):
                if isinstance(data.get(key), list | tuple) and data[key]:
                    return {**data, "plies": len(data[key])}
        return data

    @model_validator(mode="after")
    def _ply_lists_match(self) -> Fabric:
        if self.ply and len(self.ply) != self.plies:
            raise ValueError(
                f"fabric.ply has {len(self.ply)} [[fabric.ply]] tables for fabric.plies = "
                f"{self.plies}; allowed: one "
                f"table per ply (or none): set plies = {len(self.ply)} or give {self.plies} "
                "table(s)")
        if self.ply_angles and len(self.ply_angles) != self.plies:
            raise ValueError(
                f"fabric.ply_angles = {list(self.ply_angles)} has {len(self.ply_angles)} "
                f"values for fabric.plies = {self.plies}; "
                f"allowed: one angle [deg] per ply (or none: all 0): set plies = "
                f"{len(self.ply_angles)} or give {self.plies} angle(s)")
        for i, table in enumerate(self.ply):
            if table.material is not None and table.material.model not in (
                    None, self.material.model):
                raise ValueError(
                    f"ply[{i}].material.model = {table.material.model!r} differs from "
                    f"fabric.material.model = {self.material.model!r}; allowed: one yarn law "
                    "for the whole pack")
            if table.damage is not None:
                for key, value in table.damage.model_dump(exclude_none=True).items():
                    if key in ("failure_strain", "weibull_shape", "law"):
                        continue  # per segment: a pack may mix strengths (law: _damage_law)
                    if value != getattr(self.damage, key):
                        raise ValueError(
                            f"ply[{i}].damage.{key} = {value} differs from fabric.damage."
                            f"{key} = {getattr(self.damage, key)}; allowed: one damage law "
                            "for the whole pack (per ply: failure_strain and "
                            "weibull_shape)")
        return self

    @model_validator(mode="after")
    def _ply_fabrics(self) -> Fabric:
        # every ply's fabric is built here, so that its errors are the scenario's (naming the
        # ply) and not the model builder's
        for i in range(len(self.ply)):
            try:
                self.ply_fabric(i)
            except ValidationError as err:
                raise _ply_error(i, err) from None
        return self

    def ply_fabric(self, index: int) -> Fabric:
        """The fabric of ply `index` (0 = the top one): this section with that ply's table
        laid over it."""
        if not self.ply:
            return self
        over = self.ply[index].model_dump(exclude_none=True)
        if any(k in over for k in DATASHEET_KEYS):
            return self._datasheet_ply(index, over)
        base = self.model_dump()
        if "name" in over.get("material", {}):
            # another library material: what the pack's came from its library entry is not kept
            mat = self.material
            kept = (mat.model_fields_set - set(LIBRARY_KEYS) if mat.name is not None
                    else set(base["material"]) - set(LIBRARY_KEYS))
            base["material"] = {k: v for k, v in base["material"].items() if k in kept}
        for key in ("material", "damage"):
            if key in over:
                over[key] = {**base[key], **over[key]}
        if ("material" in over and "yarn_radius" not in over
                and "yarn_radius" not in self.model_fields_set
                and self.yarn_linear_density is not None):
            # the yarn's cross-section from its linear density and this ply's fibre density
            rho = MaterialSpec(**over["material"]).density or self.material.density
            over["yarn_radius"] = math.sqrt(self.yarn_linear_density * 1e-6 / rho / math.pi)
        return self.model_copy(update={**{k: (MaterialSpec(**v) if k == "material" else
                                               Damage(**v) if k == "damage" else v)
                                            for k, v in over.items()}, "ply": ()})

    def _datasheet_ply(self, index: int, over: dict[str, Any]) -> Fabric:
        """A ply whose table names its own datasheet (DATASHEET_KEYS): the pack's section without
        its datasheet and what a datasheet derives (DERIVED_KEYS), nor, where the ply names
        a style or a material, the pack's material name and library values; the ply's table
        over that; validated, so that the ply's datasheet supplies the rest. The same ply
        whether the pack's values were written or derived (a scenario written out in full
        reads back to the same plies). The damage law stays the pack's (one law per pack)."""
        base = self.model_dump(exclude={"ply", *DATASHEET_KEYS, *DERIVED_KEYS})
        if "style" in over or "name" in over.get("material", {}):
            base["material"] = {k: v for k, v in base["material"].items()
                                if k not in (*LIBRARY_KEYS, "name")}
        for key in ("material", "damage"):
            if key in over:
                over[key] = {**base[key], **over[key]}
        try:
            return Fabric.model_validate({**base, **over})
        except ValidationError as err:
            raise _ply_error(index, err) from None


def _ply_error(index: int, err: ValidationError) -> ValueError:
    """A ply's fabric that does not validate: its first error, naming the ply and the key."""
    first = err.errors()[0]
    where = ".".join(str(x) for x in first["loc"])
    msg = first["msg"].removeprefix("Value error, ")
    return ValueError(f"ply[{index}]{'.' + where if where else ''}: {msg}")


class _MaterialOverride(_Section):
    name: MaterialName = None
    """A library material for this ply (its values replace those the pack's came with)."""
    model: Literal["kirchhoff-saint-venant", "fung"] | None = None
    """Must equal fabric.material.model."""
    density: PositiveFloat | None = None
    """Fibre density [kg/m³]."""
    tensile_strength: PositiveFloat | None = None
    """[Pa]."""
    failure_strain: PositiveFloat | None = None
    """Engineering strain at break [-]."""
    youngs_modulus: PositiveFloat | None = None
    """Mean Young's modulus of this ply's yarns [Pa]."""
    modulus_cv: NonNegFloat | None = None
    """Coefficient of variation of this ply's per-yarn modulus."""
    seed: Annotated[int, Field(ge=0)] | None = None
    """Seed of this ply's modulus scatter (default: the sequence (seed, ply index))."""
    c: PositiveFloat | None = None
    """Fung constant c [Pa]."""
    H: PositiveFloat | None = None
    """Fung constant H [-]."""


class _DamageOverride(_Section):
    law: Literal["zohdi", "brittle"] | None = None
    """Must equal the pack's (one damage law per pack)."""
    critical_stretch: Annotated[float, Field(ge=1.0, allow_inf_nan=False)] | None = None
    """U_crit of eq. 2.6 [-] (must equal the pack's)."""
    rate: NonNegFloat | None = None
    """λ of eq. 2.6 [-] (must equal the pack's)."""
    failure_strain: PositiveFloat | None = None
    """law = "brittle": this ply's mean failure strain [-] (default its material's)."""
    weibull_shape: WeibullShape | None = None
    """law = "brittle": this ply's Weibull modulus [-]."""


class PlySpec(_Section):
    nodes: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] | None = None
    """This ply's grid nodes along its weave's two directions [-]."""
    areal_density: PositiveFloat | None = None
    """[kg/m²]."""
    yarn_radius: PositiveFloat | None = None
    """[m]."""
    charge_per_node: FiniteFloat | None = None
    """[C]."""
    velocity: Velocity | None = None
    """Initial velocity of this ply's free nodes [m/s]."""
    rescale: bool | None = None
    """As fabric.rescale, for this ply."""
    reference_nodes: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] | None = None
    """As fabric.reference_nodes, for this ply."""
    style: StyleName = None
    """This ply's fabric from its datasheet (as fabric.style): it supplies this ply's
    material.name, yarn_linear_density, thread_count and areal_density (and from them its
    yarn_radius, reference_nodes and nodes) where this table does not write them."""
    yarn_linear_density: PositiveFloat | None = None
    """[tex] (as fabric.yarn_linear_density), for this ply."""
    yarn_denier: PositiveFloat | None = None
    """[denier] (as fabric.yarn_denier), for this ply."""
    thread_count: tuple[PositiveFloat, PositiveFloat] | None = None
    """Ends and picks per cm [1/cm] (as fabric.thread_count), for this ply."""
    material: _MaterialOverride | None = None
    damage: _DamageOverride | None = None


DATASHEET_KEYS = ("style", "yarn_linear_density", "yarn_denier", "thread_count")
"""A ply table that writes one of these is its own fabric from its datasheet (Fabric.ply_fabric)."""
DERIVED_KEYS = ("areal_density", "yarn_radius", "reference_nodes", "nodes")
"""What a datasheet gives a fabric where it is not written."""


Fabric.model_rebuild()


class PointCharge(_Section):
    position: FiniteVec3
    """Position relative to the centre of mass, body frame at t = 0 [m]."""
    charge: FiniteFloat
    """[C]."""


class Projectile(_Section):
    shape: Literal["sphere", "ogive", "cylinder", "fsp", "none"] = "sphere"
    """Projectile shape: "sphere"; "ogive" (tangent-ogive nose on a cylinder, flat base);
    "cylinder" (right circular, flat faces); "fsp" (fragment-simulating projectile: cylinder
    with a chisel nose, proportions from the calibre); or "none" for the fabric alone."""
    radius: PositiveFloat = 0.02635
    """Sphere radius, or the body radius (calibre/2) of the other shapes [m]."""
    length: PositiveFloat | None = None
    """Overall length [m]: needed for "ogive" and "cylinder"; "fsp" default 1.16 × calibre."""
    nose_length: PositiveFloat | None = None
    """Ogive nose length [m], from radius (hemispherical nose) to length (all nose)."""
    mass: PositiveFloat = 0.037
    """Projectile mass [kg] (uniform density: the inertia follows from the shape)."""
    position: FiniteVec3 | None = None
    """Centre of mass [m]; default: lowest point `gap` above the sheet centre."""
    gap: NonNegFloat = 1e-4
    """Initial clearance below the projectile when `position` is not given [m]."""
    velocity: Velocity = (0.0, 0.0, -250.0)
    """Initial velocity of the centre of mass [m/s]."""
    axis: FiniteVec3 | None = None
    """Nose direction in the world frame at t = 0 (the shape's axis, and the tilt and yaw
    marker); default: along the velocity."""
    angular_velocity: FiniteVec3 = (0.0, 0.0, 0.0)
    """Initial angular velocity (inertial frame) [rad/s]."""
    principal_inertia: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = None
    """Principal moments of inertia [kg m²]; default: the shape's at uniform density. Sphere:
    about the world x, y, z axes; other shapes: about e1, e2 and the nose axis e3 (e1: world
    x made perpendicular to the axis, world y when the nose points along ±x; e2 = e3 × e1)."""
    charges: tuple[PointCharge, ...] = ()
    """Charged points fixed on the body (section 6)."""

    @model_validator(mode="after")
    def _dimensions(self) -> Projectile:
        if self.shape in ("ogive", "cylinder") and self.length is None:
            raise ValueError(f'shape = "{self.shape}" needs length (the overall length [m])')
        if self.shape == "ogive":
            if self.nose_length is None:
                raise ValueError('shape = "ogive" needs nose_length (the ogive nose length [m])')
            if not self.radius <= self.nose_length <= self.length:
                raise ValueError(
                    f"nose_length = {self.nose_length} must lie in [radius, length] = "
                    f"[{self.radius}, {self.length}] (a tangent ogive shorter than the radius "
                    f"does not close to a point)")
        elif self.nose_length is not None:
            raise ValueError(f'nose_length = {self.nose_length} is only for shape = "ogive" '
                             f'(shape = "{self.shape}")')
        if self.shape == "sphere" and self.length is not None:
            raise ValueError(f'length = {self.length} is not used by shape = "sphere"; allowed '
                             f'with "ogive", "cylinder", "fsp"')
        if self.principal_inertia is not None:
            moments = sorted(self.principal_inertia)
            if moments[2] > (moments[0] + moments[1]) * (1.0 + 1e-12):
                raise ValueError(
                    f"principal_inertia = {list(self.principal_inertia)}: no rigid body has "
                    f"these moments (each is at most the sum of the other two: {moments[2]:g} > "
                    f"{moments[0]:g} + {moments[1]:g}); allowed: I1 + I2 ≥ I3 in every order")
        return self


class _Current(_Section):
    """A source carrying a current, and how the current runs in time."""

    current: FiniteFloat | None = None
    """Current [A] (per turn); not with waveform = "table"."""
    turns: Annotated[int, Field(ge=1, le=100000)] = 1
    """Number of turns [-]."""
    waveform: Literal["constant", "ramp", "damped-sine", "table"] = "constant"
    """I(t): "constant"; "ramp" (0 → current over rise_time from start_time); "damped-sine"
    (current·exp(−u/decay_time)·sin(2π frequency u), u = t − start_time ≥ 0); "table"."""
    start_time: FiniteFloat = 0.0
    """When "ramp" and "damped-sine" start [s] (zero current before)."""
    rise_time: PositiveFloat | None = None
    """Duration of the "ramp" [s]."""
    frequency: PositiveFloat | None = None
    """Frequency of the "damped-sine" [Hz]."""
    decay_time: PositiveFloat | None = None
    """Decay time of the "damped-sine" [s]."""
    table: tuple[tuple[FiniteFloat, FiniteFloat], ...] | None = None
    """"table": [[t, I], ...] [s, A], t increasing; linear between points, held outside."""
    wire_radius: PositiveFloat | None = None
    """Radius of the wire [m] (default 1 % of the loop radius, below half of it): within it the
    field is that of the wire's surface scaled by the distance to its centre line, finite."""

    @model_validator(mode="after")
    def _waveform_keys(self) -> _Current:
        needs = {"constant": (), "ramp": ("rise_time",), "damped-sine": ("frequency",
                                                                          "decay_time"),
                 "table": ("table",)}[self.waveform]
        for key in needs:
            if getattr(self, key) is None:
                raise ValueError(f'waveform = "{self.waveform}" needs {key}')
        for key in ("rise_time", "frequency", "decay_time", "table"):
            if key not in needs and getattr(self, key) is not None:
                raise ValueError(f'{key} is not used by waveform = "{self.waveform}"')
        if self.waveform == "table":
            if self.current is not None:
                raise ValueError('current is not used with waveform = "table" (the table '
                                 'holds the current)')
            times = [p[0] for p in self.table]
            if len(times) < 2 or any(b <= a for a, b in zip(times, times[1:], strict=False)):
                raise ValueError(f"table = {[list(p) for p in self.table]}: allowed: at least "
                                 f"two [t, I] points with t increasing")
        elif self.current is None:
            raise ValueError("current [A] is needed")
        radius = getattr(self, "radius", None)
        if radius is not None and radius < MIN_COIL_RADIUS:
            raise ValueError(f"radius = {radius:g} m: allowed: at least {MIN_COIL_RADIUS:g} m")
        if self.wire_radius is not None and self.wire_radius < 0.01 * MIN_COIL_RADIUS:
            raise ValueError(f"wire_radius = {self.wire_radius:g} m: allowed: at least "
                             f"{0.01 * MIN_COIL_RADIUS:g} m")
        _within_reach("centre", getattr(self, "centre", None))
        _within_reach("radius", (radius,) if radius is not None else None)
        length = getattr(self, "length", None)
        _within_reach("length", (length,) if length is not None else None)
        if self.wire_radius is not None and radius is not None and \
                not self.wire_radius < 0.5 * radius:
            raise ValueError(f"wire_radius = {self.wire_radius}: allowed: below half the radius "
                             f"({0.5 * radius})")
        return self


MIN_COIL_RADIUS = 1e-6
"""Smallest loop or solenoid radius [m] (its default wire radius, 1 % of it, stays a number
the field's closed forms can divide by), and smallest magnet dimension."""
SOURCE_REACH = 1e4
"""Farthest a source's centre may be from the sheet's centre, per coordinate, and its largest
size [m]: its field on the sheet is nil beyond, and the closed forms overflow."""
MAX_ORIENTATION = 3600.0
"""Largest rotation vector of a magnet's orientation [deg] (ten turns; any rotation is one of
at most 180°)."""


def _within_reach(key: str, values) -> None:
    if values is not None and max(abs(c) for c in values) > SOURCE_REACH:
        raise ValueError(f"{key} = {list(values)}: allowed: at most {SOURCE_REACH:g} m (from "
                         f"the sheet's centre in x, y and z for a position)")


class LoopSource(_Current):
    kind: Literal["loop"]
    """A circular current loop (exact field, elliptic integrals)."""
    centre: FiniteVec3
    """Centre of the loop [m]."""
    normal: FiniteVec3
    """Normal of the loop's plane; the current circulates right-handed about it."""
    radius: PositiveFloat
    """Loop radius [m]."""


class SolenoidSource(_Current):
    kind: Literal["solenoid"]
    """A finite solenoid: `turns` loops evenly spaced over `length` (at most 200 loops, each
    then carrying current × turns/200)."""
    centre: FiniteVec3
    """Centre of the solenoid [m]."""
    axis: FiniteVec3
    """Axis; the current circulates right-handed about it."""
    radius: PositiveFloat
    """Radius [m]."""
    length: PositiveFloat
    """Length [m]."""


class UniformSource(_Section):
    kind: Literal["uniform"]
    """A uniform field (added to field.E and field.B)."""
    E: FiniteVec3 = (0.0, 0.0, 0.0)
    """Electric field [V/m]."""
    B: FiniteVec3 = (0.0, 0.0, 0.0)
    """Magnetic field [T]."""


class MapSource(_Section):
    kind: Literal["map"]
    """A static field map from a netCDF file: coordinates x, y, z [m] (increasing), variables
    Bx, By, Bz [T] and optionally Ex, Ey, Ez [V/m] on that grid; trilinear between the
    points, zero outside the map (the run says how many nodes start outside)."""
    file: Annotated[str, Field(min_length=1)]
    """Path of the netCDF file (relative paths: from the working directory)."""
    scale: FiniteFloat = 1.0
    """Factor on the map's fields [-]."""


class MagnetSource(_Section):
    kind: Literal["magnet"]
    """A permanent magnet, uniformly polarized (magpylib computes its field: needs the
    "magnets" extra, pip install 'emfabric[magnets]')."""
    shape: Literal["cuboid", "cylinder"]
    """"cuboid" (dimension = [a, b, c], side lengths along its x, y, z) or "cylinder"
    (dimension = [d, h], diameter and height, axis along its z)."""
    polarization: FiniteVec3
    """Magnetic polarization J = μ₀M [T] in the magnet's own frame (a remanence of ~1.3 T for
    NdFeB)."""
    dimension: tuple[PositiveFloat, ...]
    """[a, b, c] (cuboid) or [d, h] (cylinder) [m]."""
    position: FiniteVec3 = (0.0, 0.0, 0.0)
    """Centre of the magnet [m]."""
    orientation: FiniteVec3 = (0.0, 0.0, 0.0)
    """Rotation of the magnet's frame as a rotation vector [deg]: axis × angle (zero: the
    magnet's axes are the world's)."""

    @model_validator(mode="after")
    def _dimension_count(self) -> MagnetSource:
        count = 3 if self.shape == "cuboid" else 2
        if len(self.dimension) != count:
            what = "[a, b, c]" if count == 3 else "[d, h]"
            raise ValueError(f'dimension = {list(self.dimension)}: allowed for shape = '
                             f'"{self.shape}": {what}, {count} positive lengths [m]')
        _within_reach("position", self.position)
        _within_reach("dimension", self.dimension)
        if min(self.dimension) < MIN_COIL_RADIUS:
            raise ValueError(f"dimension = {list(self.dimension)}: allowed: lengths of at least "
                             f"{MIN_COIL_RADIUS:g} m (magpylib's closed forms stall far below)")
        turn = math.sqrt(sum(c * c for c in self.orientation))
        if turn > MAX_ORIENTATION:
            raise ValueError(f"orientation = {list(self.orientation)}: allowed: a rotation "
                             f"vector of at most {MAX_ORIENTATION:g} degrees")
        return self


Source = Annotated[UniformSource | LoopSource | SolenoidSource | MapSource | MagnetSource,
                   Field(discriminator="kind")]


class FieldSpec(_Section):
    E: FiniteVec3 = (0.0, 0.0, 0.0)
    """Electric field [V/m] (uniform)."""
    B: FiniteVec3 = (0.05, 0.0, 0.0)
    """Magnetic field [T] (uniform; 0 by default when sources are given)."""
    region: Literal["uniform", "half-space"] = "uniform"
    """Where the field acts: "uniform" (everywhere) or "half-space" (z < z0)."""
    z0: FiniteFloat = 0.0
    """With region = "half-space": the field acts where z < z0 [m]."""
    gravity: FiniteVec3 = (0.0, 0.0, 0.0)
    """Gravitational acceleration [m/s²] (off by default)."""
    sources: tuple[Source, ...] = ()
    """Field sources, summed with the uniform E, B above: kind = "uniform" | "loop" |
    "solenoid" | "magnet" | "map" (docs/fields.md)."""
    grid: bool = True
    """Take the loops' and solenoids' fields from a grid precomputed over the fabric's reach
    (exact near the wires and outside the grid; docs/fields.md), or evaluate them exactly at
    every node (false: several times slower). Magnets always use the grid."""
    grid_cells: Annotated[int, Field(ge=8, le=512)] = 96
    """Cells of the source grid across the fabric's larger side [-]."""
    grid_tolerance: Annotated[float, Field(gt=0.0, le=0.1)] = 1e-3
    """Largest relative error of the grid's interpolation of the loops (estimated on each
    cell's edges); cells above it evaluate the loops exactly [-]."""

    @model_validator(mode="before")
    @classmethod
    def _no_default_uniform_with_sources(cls, data: Any) -> Any:
        # with sources, only what is written acts: the paper's default B = 0.05 e_x is not added
        if isinstance(data, dict) and data.get("sources") and "B" not in data:
            data = {**data, "B": (0.0, 0.0, 0.0)}
        return data


class ContactSpec(_Section):
    static_friction: NonNegFloat = 1.0
    """Static friction coefficient μ_s [-]."""
    dynamic_friction: NonNegFloat = 0.95
    """Dynamic friction coefficient μ_d ≤ μ_s [-]."""
    segments: Literal["auto"] | bool = "auto"
    """Also resolve contact of the yarn segments between the nodes (true), or of the nodes
    only (false, the paper's model); "auto": nodes only for the sphere, nodes and segments for
    the other shapes (a pointed nose can pass between nodes)."""
    placement: Literal["phi-update", "closest-point"] = "phi-update"
    """Where a node in contact is put: "phi-update", the closest surface point to where the
    φ-update with its velocity after contact takes it (follows the surface; default), or
    "closest-point", the closest surface point to its position before contact (the paper as
    printed: an O(Δt) lag of sticking nodes, docs/theory.md §5)."""

    @model_validator(mode="after")
    def _dynamic_not_above_static(self) -> ContactSpec:
        if self.dynamic_friction > self.static_friction:
            raise ValueError(
                f"dynamic_friction = {self.dynamic_friction} exceeds static_friction = "
                f"{self.static_friction}; allowed: dynamic_friction ≤ static_friction"
            )
        return self


PHI_KEYS = ("scheme", "predictor", "phi", "tolerance", "target_iterations", "exponent",
            "adaptive", "max_iterations", "dt_initial", "safety", "anderson_depth")
"""The solver keys only the φ-scheme reads: a scenario that sets one of them and not
`integrator` runs the φ-scheme."""


BULK_VISCOSITY = 0.06
"""solver.bulk_viscosity where yarns break and it is not given (Abaqus/Explicit's and LS-DYNA's
default linear bulk-viscosity coefficient): measured on Smith's struck yarn, docs/theory.md
§2.1."""


class SolverSpec(_Section):
    integrator: Literal["phi", "central-difference"] = "central-difference"
    """Time integration: "central-difference" (explicit, one force evaluation per step, Δt =
    courant × the stability limit of the current state; the default) or "phi", the paper's
    implicit φ-scheme (fixed-point iteration, adaptive Δt, eq. 3.9). Not given, it is "phi"
    when the scenario sets a key only the φ-scheme reads (PHI_KEYS: phi, tolerance,
    target_iterations, …), else "central-difference"."""
    courant: Annotated[float, Field(gt=0.0, le=1.0)] = 0.25
    """central-difference: the fraction of the stable step (2/ω_max, ω_max² ≤ max 2Σk_t/m at the
    current stretches, or (20 ω_c)² where a charged node's cyclotron frequency ω_c = |qB|/m is
    higher: it turns about B by at most 0.1 × courant rad a step) taken [-]."""
    bulk_viscosity: Annotated[float, Field(ge=0.0, le=1.0)] | None = None
    """central-difference: q of the yarns' linear bulk viscosity [-]: a taut segment carries,
    besides its elastic tension, q·√(k m)·L̇ (k its axial stiffness 𝔼A0/L0, m the mass of its
    nodes; the viscous part of the highest mode's damping ratio is q), which spreads a
    loading wave front over a few segments instead of letting the lumped network ring behind
    it (docs/theory.md §2.1). Not given: BULK_VISCOSITY (0.06, Abaqus/Explicit's and
    LS-DYNA's default linear coefficient) where yarns break, fabric.damage.law = "brittle",
    else 0 (the paper's model). The φ-scheme has none."""
    scheme: Literal["fixed-point", "anderson"] = "fixed-point"
    """Solver of each φ-step: the paper's fixed-point iteration, or its Anderson acceleration."""
    predictor: Literal["start", "explicit"] = "start"
    """Initial iterate of each step: "start" the start-of-step state (the paper's, ϖ_0 = 1), or
    "explicit" x0 + Δt v0 + φΔt² ψ(t)/m (19 % fewer force evaluations on paper-field, but a free
    sheet's energy drifts about 3× faster: docs/theory.md §4)."""
    phi: Annotated[float, Field(ge=0.0, le=1.0)] = 0.5
    """φ of the φ-scheme (0 explicit, 0.5 trapezoidal, 1 implicit) [-]."""
    tolerance: PositiveFloat = 1e-6
    """Fixed-point tolerance on the normalised iteration error ϖ (eq. 3.10) [-]."""
    target_iterations: Annotated[int, Field(ge=1, le=1000)] = 6
    """K_d of eq. 3.9: iterations per step the controller aims at [-]."""
    exponent: PositiveFloat = 2.0
    """p of eq. 3.9."""
    adaptive: bool = True
    """False: fixed Δt = dt_max, iterate to `tolerance` within `max_iterations`."""
    max_iterations: Annotated[int, Field(ge=1, le=100000)] = 200
    """Iteration limit per step when adaptive = false; with adaptive = true, the limit of a
    "patient" step, tried before Δt would fall below dt_min (docs/theory.md §4) [-]."""
    dt_max: PositiveFloat = 1e-6
    """Largest time step [s]."""
    dt_min: PositiveFloat = 1e-13
    """Smallest time step; below it the run stops as diverged (the φ-scheme first tries a
    patient step of max_iterations at the step's first Δt) [s]."""
    dt_initial: PositiveFloat | None = None
    """First Δt tried; default dt_max (the paper)."""
    end_time: PositiveFloat = 1.5e-3
    """Longest simulated time [s]; a run stops earlier once the projectile has left the sheet."""
    safety: Annotated[float, Field(gt=0, le=1)] = 0.9
    """Factor on Φ_K of eq. 3.9; 1.0 is the paper-literal controller."""
    anderson_depth: Annotated[int, Field(ge=1, le=20)] = 5
    """History depth of scheme = "anderson" [-]."""

    @model_validator(mode="before")
    @classmethod
    def _phi_keys_choose_phi(cls, data: Any) -> Any:
        if isinstance(data, dict) and "integrator" not in data and any(
                k in data for k in PHI_KEYS):
            data = {**data, "integrator": "phi"}
        return data

    @model_validator(mode="after")
    def _dt_order(self) -> SolverSpec:
        if self.dt_min >= self.dt_max:
            raise ValueError(
                f"dt_min = {self.dt_min} must be smaller than dt_max = {self.dt_max}"
            )
        if self.dt_initial is not None and not self.dt_min <= self.dt_initial <= self.dt_max:
            raise ValueError(
                f"dt_initial = {self.dt_initial} must lie in [dt_min, dt_max] = "
                f"[{self.dt_min}, {self.dt_max}]"
            )
        return self


class Output(_Section):
    snapshot_interval: PositiveFloat = 10e-6
    """Simulated time between snapshots [s]."""
    paraview: bool = True
    """Write the ParaView files (vtk/*.vtu and fabric.pvd, projectile.pvd) beside snapshots.nc;
    false: snapshots.nc only (a 100 × 100 run writes ~1 MB of .vtu per snapshot)."""
    size_limit: PositiveFloat = 20e9
    """Largest output a run may write [B] (snapshots × nodes, estimated before it starts);
    above it the run is refused: raise it to ask for more."""
    checkpoint_seconds: PositiveFloat = 5.0
    """Wall time between checkpoints [s]: new history records and snapshots are appended and
    checkpoint.nc is replaced (a killed run loses at most this much)."""


class Scenario(_Section):
    name: str = "custom"
    """Names the run; default output folder runs/<name> (a scenario file: runs/<file name>)."""
    description: str = ""
    """One line saying what the scenario is."""
    fabric: Fabric = Fabric()
    projectile: Projectile = Projectile()
    field: FieldSpec = FieldSpec()
    contact: ContactSpec = ContactSpec()
    solver: SolverSpec = SolverSpec()
    output: Output = Output()

    @model_validator(mode="before")
    @classmethod
    def _placement_chooses_phi(cls, data: Any) -> Any:
        # contact.placement is the φ-update's option: written without an integrator, it
        # chooses the φ-scheme (as the φ-scheme's solver keys do, SolverSpec)
        if not isinstance(data, dict):
            return data
        contact, solver = data.get("contact"), data.get("solver")
        if (isinstance(contact, dict) and "placement" in contact
                and (solver is None or isinstance(solver, dict))
                and not (isinstance(solver, dict) and "integrator" in solver)):
            # (a solver that is not a table is left for validation to refuse)
            solver = dict(solver) if isinstance(solver, dict) else {}
            data = {**data, "solver": {**solver, "integrator": "phi"}}
        return data

    @model_validator(mode="after")
    def _viscosity_is_central_only(self) -> Scenario:
        if self.solver.integrator == "phi" and self.solver.bulk_viscosity:
            raise ValueError(
                f"solver.bulk_viscosity = {self.solver.bulk_viscosity} is an option of central "
                "differences; the φ-scheme has no viscosity. Allowed: solver.integrator = "
                "\"central-difference\" with it, or bulk_viscosity = 0 (or none) with the "
                "φ-scheme")
        return self

    @property
    def bulk_viscosity(self) -> float:
        """The yarns' bulk viscosity q the run uses: solver.bulk_viscosity, or when not given
        BULK_VISCOSITY for a central-difference run of yarns that break (damage.law =
        "brittle"), else 0."""
        q = self.solver.bulk_viscosity
        if q is not None:
            return float(q)
        if self.solver.integrator == "central-difference" and self.fabric.damage.brittle:
            return BULK_VISCOSITY
        return 0.0

    @model_validator(mode="after")
    def _placement_is_phi_only(self) -> Scenario:
        if (self.solver.integrator == "central-difference"
                and self.contact.placement != "phi-update"):
            raise ValueError(
                f"contact.placement = {self.contact.placement!r} is an option of the φ-scheme; "
                "central differences put a sticking node where its material point on the "
                "surface has moved (docs/theory.md §4.1). Allowed: solver.integrator = \"phi\" "
                "with it, or no contact.placement")
        return self

    @field_validator("name")
    @classmethod
    def _name_is_simple(cls, v: str) -> str:
        if (not v or v in (".", "..") or any(ch in v for ch in "/\\\n\r\0")
                or v != v.strip()):
            raise ValueError("allowed: a non-empty single-line name without path separators, "
                             "not '.' or '..' (it names the default output folder)")
        return v

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every value (defaults included), None entries dropped."""
        return _drop_none(self.model_dump(mode="python"))

    def to_toml(self) -> str:
        """The full scenario as TOML text (every default written out)."""
        return tomli_w.dumps(_tomlable(self.to_dict()))

    def to_commented_toml(self) -> str:
        """The full scenario as TOML to read and edit: one line per key, arrays on one line, a
        comment with each key's meaning and unit; keys without a value are shown commented out.
        Parses back to the same scenario."""
        return _commented(self)

    def replace(self, **dotted: Any) -> Scenario:
        """A copy with dotted-key overrides: ``s.replace(**{"field.B": [0, 0, 0.1]})``."""
        return apply_overrides(self, dotted)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        # a TOML basic string: JSON's escapes are TOML's, except DEL, which TOML forbids raw
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def _comment(field: Any) -> str:
    text = " ".join((field.description or "").split())
    return f"  # {text}" if text else ""


DERIVED_FABRIC_KEYS = ("areal_density", "yarn_radius", "reference_nodes", "nodes",
                       "thread_count", "yarn_linear_density", "plies")
"""FabricSpec keys a style, a library material or datasheet keys supply where the scenario does
not write them (apply_overrides derives them again; a commented file leaves them out)."""


_FROM_LIBRARY = "derived from the material, style or datasheet keys: write it to fix it"


def _derived_paths(scenario: Scenario) -> dict[str, str]:
    """The dotted keys whose values the scenario did not write but took from its library
    material, fabric style or datasheet keys, or from the other keys written (what
    apply_overrides derives again), each with why: written out as values, they would pin the
    old material's numbers after its name or style is edited."""
    fab = scenario.fabric
    mat = fab.material
    out: dict[str, str] = {}
    if "law" not in fab.damage.model_fields_set:
        out["fabric.damage.law"] = ("chosen from the keys written and the material: write it "
                                    "to fix it")
    if fab.style is None and mat.name is None and not (
            {"yarn_linear_density", "yarn_denier", "thread_count"} & fab.model_fields_set):
        return out
    out.update({f"fabric.{k}": _FROM_LIBRARY for k in DERIVED_FABRIC_KEYS
                if k not in fab.model_fields_set})
    out.update({f"fabric.material.{k}": _FROM_LIBRARY for k in (*LIBRARY_KEYS, "name")
                if k not in mat.model_fields_set})
    return out


def _section_lines(model: BaseModel, path: str, out: list[str],
                   derived: dict[str, str] | None = None,
                   effective: dict[str, Any] | None = None) -> None:
    subs = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        why = (derived or {}).get(f"{path}{name}")
        if why is not None and value is not None and not isinstance(value, BaseModel):
            # what the material, style, datasheet or other keys give: shown, not pinned
            out.append(f"# {name} = {_toml_value(value)}  # ({why}){_comment(field)[3:]}")
            continue
        if value is None and effective and f"{path}{name}" in effective:
            out.append(f"# {name} = (not set: {_toml_value(effective[path + name])} in this "
                       f"scenario){_comment(field)}")
            continue
        if isinstance(value, BaseModel):
            subs.append((name, value))
        elif isinstance(value, tuple) and value and isinstance(value[0], BaseModel):
            subs.append((name, value))
        elif value is None:
            out.append(f"# {name} = (not set){_comment(field)}")
        elif isinstance(value, tuple) and not value and _model_in(field.annotation):
            out.append(f"# [[{path}{name}]] (none){_comment(field)}")
        else:
            out.append(f"{name} = {_toml_value(value)}{_comment(field)}")
    for name, value in subs:
        if isinstance(value, tuple):
            for item in value:
                out += ["", f"[[{path}{name}]]"]
                _section_lines(item, f"{path}{name}.", out)
        else:
            out += ["", f"[{path}{name}]"]
            _section_lines(value, f"{path}{name}.", out, derived, effective)


def _commented(scenario: Scenario) -> str:
    out: list[str] = []
    # keys whose default depends on the rest of the scenario: the value it takes here
    effective = {"solver.bulk_viscosity": scenario.bulk_viscosity}
    _section_lines(scenario, "", out, _derived_paths(scenario), effective)
    return "\n".join(out).lstrip("\n") + "\n"


def _drop_none(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _drop_none(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, list | tuple):
        return [_drop_none(v) for v in obj]
    return obj


def _tomlable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _tomlable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_tomlable(v) for v in obj]
    return obj


def _format_errors(err: ValidationError, source: str, data: Any = None) -> str:
    """One line per wrong key, in the scenario file's words (never pydantic's):
    `key.path = value: what is allowed`, the path as the user writes it
    (`field.sources[0].centre`), the value as given (an array whole: `field.B = [0.05, 0]`)
    and what the key takes, with the unit of its docstring: "needs 3 numbers [Bx, By, Bz] in
    T", "needs a number > 0 (kg), not text", "must be > 0 (kg)", "allowed: 'phi',
    'central-difference'". A key missing from a table is `path: missing; needs …`; an unknown
    key lists the keys of its section and the closest one. `data` is what was validated (for
    the whole array an error inside it belongs to).

    A key of several forms (a union: "auto" or a boolean; a source table told apart by its
    `kind`) gets one line listing every allowed form, not pydantic's line per member."""
    lines: list[Any] = [f"invalid scenario ({source}):"]
    errors = err.errors()
    found = [_locate(e["loc"]) for e in errors]
    # a union whose value has one member's form (an error below that member's level, or its
    # own rule between keys): that member's errors say what is wrong; the other members'
    # forms are dropped
    formed = [w.union_at is not None and (len(w.path) > w.union_at or e["type"] in _RULE_ERRORS)
              for e, w in zip(errors, found, strict=True)]
    deep = {tuple(w.path[:w.union_at]) for w, f in zip(found, formed, strict=True) if f}
    merged: dict[tuple, list] = {}
    arrays: dict[tuple, _ArrayLine] = {}
    for e, where, form in zip(errors, found, formed, strict=True):
        path = _path_text(where.path)
        value = e.get("input")
        shown = _show(value)
        kind = e["type"]
        if where.union_at is not None and not form:
            key = tuple(where.path)
            if key in deep:
                continue
            if key not in merged:  # one line for the whole union, where its first error was
                merged[key] = [path, shown, []]
                lines.append(merged[key])
            merged[key][2] += [a for a in _allowed_forms(e) if a not in merged[key][2]]
            continue
        if where.key is not None and where.key.is_array and not (
                kind == "missing" and len(where.path) == where.key_len):
            # an error in or at an array of numbers: one line for the array, its value whole
            at = tuple(where.path[:where.key_len])
            if at not in arrays:
                whole = _value_at(data, at)
                if whole is _NOTHING:
                    whole = value if len(where.path) == where.key_len or kind == "missing" \
                        else "[...]"
                arrays[at] = _ArrayLine(_path_text(at), whole, where.key)
                lines.append(arrays[at])
            arrays[at].errors.append((e, tuple(where.path[where.key_len:])))
            continue
        if kind == "extra_forbidden":
            parent = _locate(e["loc"][:-1]).type
            allowed = sorted(parent.model_fields) if _is_model(parent) else []
            hint = _did_you_mean(where.path[-1] if where.path else None, allowed, key=True)
            lines.append(f"  {path}: unknown key{f' ({hint})' if hint else ''}; allowed keys "
                         f"here: {', '.join(allowed)}")
            continue
        tags = _tags(where.type, where.discriminator)
        if kind in ("union_tag_not_found", "union_tag_invalid") and tags and \
                isinstance(value, dict):
            disc = where.discriminator
            if kind == "union_tag_not_found":
                lines.append(f"  {path}.{disc}: missing; allowed: {', '.join(tags)}")
            else:
                tag = value.get(disc)
                hint = _did_you_mean(tag, [t.strip("'") for t in tags])
                lines.append(f"  {path}.{disc} = {_show(tag)}: allowed: {', '.join(tags)}"
                             f"{f' ({hint})' if hint else ''}")
            continue
        key = where.key if len(where.path) == where.key_len else None
        spec = key if key is not None else _Key(None, where.type, (), "")
        if kind == "missing":
            lines.append(f"  {path}: missing; {_needs(spec)}")
            continue
        rule = _rule(e, spec)
        if tags and kind in _TYPE_ERRORS:  # an array of tables told apart by a key
            rule = (f"needs a table with {where.discriminator} = {_one_of(tags)}, "
                    f"{_not(value, dict)}")
        if kind in _RULE_ERRORS and (not where.path or rule.startswith(f"{path}.")):
            # a rule of the whole scenario, or of a section that names its keys by their
            # dotted path, says itself what is wrong: not after "fabric = {...}:"
            lines.append(f"  {rule}")
        else:
            lines.append(f"  {path} = {shown}: {rule}")
    return "\n".join(line if isinstance(line, str) else
                     f"  {line[0]} = {line[1]}: allowed: {', '.join(line[2])}"
                     if isinstance(line, list) else line.text() for line in lines)


_RULE_ERRORS = ("value_error", "assertion_error")
"""Errors of a schema's own rule (a validator): the value had the form its rule checks."""

_TYPE_ERRORS = ("model_type", "model_attributes_type", "dict_type", "tuple_type", "list_type",
                "float_type", "int_type", "bool_type", "string_type", "int_from_float",
                "float_parsing", "int_parsing", "bool_parsing", "is_instance_of")
"""Errors of a value of the wrong type (text for a number, a number for a table, …)."""

_RANGE_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal")

_FORM_WORDS = {"bool_type": ["true", "false"], "int_type": ["an integer"],
               "float_type": ["a number"], "string_type": ["text in quotes"],
               "model_type": ["a table"], "model_attributes_type": ["a table"],
               "dict_type": ["a table"], "tuple_type": ["an array"], "list_type": ["an array"]}
"""What a union member allows, by the type of its error when the value is not of its type."""

_COMPONENTS = {"nodes": ("nx", "ny"), "reference_nodes": ("nx", "ny"), "size": ("Lx", "Ly"),
               "thread_count": ("ends", "picks"), "principal_inertia": ("I1", "I2", "I3"),
               "table": ("t", "I")}
"""The names of an array key's numbers, where they are not x, y, z of the key."""

_SYMBOLS = {"velocity": "v", "angular_velocity": "ω", "gravity": "g", "polarization": "J",
            "normal": "n"}
"""The symbol of a vector key in its components' names (vx, ωz); B and E are their own;
other vectors (position, centre, axis) are [x, y, z]."""

_NOTHING = object()


class _Key:
    """A key of the schema: its name, annotation, constraints (annotated-types metadata) and
    docstring (for the unit)."""

    def __init__(self, name: str | None, ann: Any, meta: Any, doc: str) -> None:
        self.name = name
        self.ann, more = _strip(ann)
        self.meta = [*_flat_meta(meta), *more]
        self.doc = " ".join((doc or "").split())

    @property
    def is_array(self) -> bool:
        """An array of numbers (or of arrays of them): its errors are reported whole."""
        return get_origin(self.ann) is tuple and _model_in(self.ann) is None

    @property
    def unit(self) -> str | None:
        """The unit in the docstring's first [brackets] that hold one ([-]: none)."""
        for m in re.finditer(r"(?<![\[\w])\[([^\[\]]+)\](?!\])", self.doc):
            unit = m.group(1).strip()
            if any(c in unit for c in ',."\'') or len(unit) > 16:
                continue
            return None if unit == "-" else unit
        return None


class _ArrayLine:
    """One message line for an array key and every error found in it."""

    def __init__(self, path: str, value: Any, key: _Key) -> None:
        self.path, self.value, self.key = path, value, key
        self.errors: list[tuple[dict, tuple]] = []

    def text(self) -> str:
        own = [_rule(e, self.key) for e, sub in self.errors
               if not sub and e["type"] in _RULE_ERRORS]
        if own:  # the array's own rule (a validator of the whole array): its words
            return f"  {self.path} = {_show(self.value)}: {'; '.join(own)}"
        finite = any(e["type"] == "finite_number" for e, _ in self.errors)
        rule = _needs(self.key, finite=finite)
        details = []
        for e, sub in self.errors:
            if e["type"] not in _TYPE_ERRORS:
                continue
            if not sub:  # the key itself has the wrong type: a number or a table for an array
                if not isinstance(self.value, int | float) or isinstance(self.value, bool):
                    rule += f", not {_kind_of(self.value)}"
                continue
            item = e.get("input")
            item_type = _strip(_item_ann(self.key.ann, sub))[0]
            what = ("not an integer" if item_type is int and isinstance(item, float)
                    else f"{_kind_of(item)}")
            name = _item_name(self.key, sub)
            details.append(f"{name} is None" if item is None else
                           f"{name} = {_show(item)} is {what}")
        if details:
            rule += "; " + ", ".join(details)
        return f"  {self.path} = {_show(self.value)}: {rule}"


def _strip(ann: Any) -> tuple[Any, list]:
    """The type without Annotated and Optional, and the constraints Annotated held."""
    meta: list = []
    while True:
        if get_origin(ann) is Annotated:
            ann, *more = get_args(ann)
            meta += _flat_meta(more)
        elif _is_union(ann) and len(_members(ann)) == 1:
            ann = _members(ann)[0]
        else:
            return ann, meta


def _flat_meta(meta: Any) -> list:
    out: list = []
    for m in meta:
        out += list(getattr(m, "metadata", None) or []) if isinstance(m, FieldInfo) else [m]
    return out


def _bounds(meta: list) -> str:
    """"> 0", "≥ 0 and < 1", "from 1 to 64": the range the constraints allow ("": any)."""
    lo = hi = None
    for m in meta:
        for attr, op in (("gt", ">"), ("ge", "≥")):
            if getattr(m, attr, None) is not None:
                lo = (op, _number(getattr(m, attr)))
        for attr, op in (("lt", "<"), ("le", "≤")):
            if getattr(m, attr, None) is not None:
                hi = (op, _number(getattr(m, attr)))
    if lo and hi:
        if lo[0] == "≥" and hi[0] == "≤":
            return f"from {lo[1]} to {hi[1]}"
        return f"{lo[0]} {lo[1]} and {hi[0]} {hi[1]}"
    bound = lo or hi
    return f"{bound[0]} {bound[1]}" if bound else ""


def _number(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _noun(ann: Any, meta: list, plural: bool = False, finite: bool = False) -> str | None:
    """What one value of a scalar type is: "a number", "integers", "true or false"."""
    if ann is bool:
        return "true or false"
    if ann is int:
        return "integers" if plural else "an integer"
    if ann is float:
        word = "finite numbers" if plural else "a finite number"
        return word if finite else word.replace("finite ", "")
    if ann is str:
        empty = any(getattr(m, "min_length", None) for m in meta)
        return f"{'non-empty ' if empty else ''}text in quotes"
    if _is_model(ann) or (_is_union(ann) and all(_is_model(_strip(m)[0])
                                                  for m in _members(ann))):
        return "tables" if plural else "a table"
    return None


def _literals(ann: Any) -> list[str] | None:
    """The values a Literal allows, as a scenario file writes them."""
    return [_show(a) for a in get_args(ann)] if get_origin(ann) is Literal else None


def _names(key: _Key, count: int) -> tuple[str, ...] | None:
    """The names of an array's numbers: [Bx, By, Bz], [nx, ny], [x, y, z] (None: unknown)."""
    names = _COMPONENTS.get(key.name or "")
    if names is not None and len(names) == count:
        return names
    if count == 3 and key.name is not None:
        sym = _SYMBOLS.get(key.name, key.name if len(key.name) <= 2 else "")
        return tuple(f"{sym}{c}" for c in "xyz")
    return None


def _needs(key: _Key, finite: bool = False) -> str:
    """What a key takes: "needs 3 numbers [Bx, By, Bz] in T", "needs a number > 0 (kg)",
    "allowed: 'phi', 'central-difference'"."""
    ann, unit = key.ann, key.unit
    literals = _literals(ann)
    if literals is not None:
        return f"allowed: {', '.join(literals)}"
    if _is_union(ann) and _noun(ann, []) is None:
        forms: list[str] = []
        for m in _members(ann):
            base, meta = _strip(m)
            forms += _literals(base) or (["true", "false"] if base is bool else
                                         [_noun(base, meta) or "a value"])
        return f"allowed: {', '.join(forms)}"
    if get_origin(ann) is tuple:
        args = get_args(ann)
        if len(args) == 2 and args[1] is Ellipsis:
            item, meta = _strip(args[0])
            if get_origin(item) is tuple:
                inner = get_args(item)
                names = _names(key, len(inner))
                what = f"[{', '.join(names)}] pairs" if names and len(inner) == 2 else \
                    f"arrays of {len(inner)} {_noun(_strip(inner[0])[0], [], True) or 'values'}"
                return f"needs an array of {what}"
            noun = _noun(item, meta, plural=True, finite=finite) or "values"
            bounds = _bounds(meta)
            return (f"needs an array of {noun}{f' in {unit}' if unit else ''}"
                    f"{f', each {bounds}' if bounds else ''}")
        items = [_strip(a) for a in args]
        same = all(i[0] is items[0][0] for i in items)
        noun = (_noun(items[0][0], items[0][1], plural=True, finite=finite) if same else None)
        names = _names(key, len(args))
        bounds = _bounds(items[0][1]) if same and all(
            _bounds(i[1]) == _bounds(items[0][1]) for i in items) else ""
        listed = f" [{', '.join(names)}]" if names else ""
        return (f"needs {len(args)} {noun or 'values'}{listed}"
                f"{f' in {unit}' if unit else ''}{f', each {bounds}' if bounds else ''}")
    noun = _noun(ann, key.meta, finite=finite)
    if noun is None:
        return "needs a value of another form"
    bounds = _bounds(key.meta) if ann in (int, float) else ""
    return f"needs {noun}{f' {bounds}' if bounds else ''}{f' ({unit})' if unit else ''}"


def _rule(e: dict, key: _Key) -> str:
    """What a value breaks, said in the key's terms."""
    kind, value = e["type"], e.get("input")
    if kind in _RULE_ERRORS:
        msg = e["msg"]
        for prefix in ("Value error, ", "Assertion failed, "):
            msg = msg.removeprefix(prefix)
        return msg
    unit = f" ({key.unit})" if key.unit else ""
    if kind == "literal_error":
        literals = _literals(key.ann) or re.split(r"(?:, | or )(?=['\"])",
                                                  e.get("ctx", {}).get("expected", "?"))
        hint = _did_you_mean(value, [a.strip("'\"") for a in literals])
        return f"allowed: {', '.join(literals)}{f' ({hint})' if hint else ''}"
    if kind in _RANGE_ERRORS:
        bounds = _bounds(key.meta) or _bounds([_Bound(e.get("ctx", {}))])
        return f"must be {bounds}{unit}"
    if kind == "finite_number":
        bounds = _bounds(key.meta)
        return f"must be a finite number{f' {bounds}' if bounds else ''}{unit}"
    needs = _needs(key)
    if kind in _TYPE_ERRORS:
        return f"{needs}, {_not(value, key.ann)}"
    return needs


class _Bound:
    """A constraint from an error's context (gt, ge, lt, le)."""

    def __init__(self, ctx: dict) -> None:
        for attr in ("gt", "ge", "lt", "le"):
            setattr(self, attr, ctx.get(attr))


def _not(value: Any, expected: Any) -> str:
    """"not text (write 0.037 without quotes)", "not a boolean", "not 2.0 (write 2)"."""
    if isinstance(value, str):
        try:
            parsed = tomllib.loads(f"v = {value.strip()}")["v"]
        except (tomllib.TOMLDecodeError, RecursionError):
            parsed = None
        fits = (isinstance(parsed, bool) if expected is bool else
                isinstance(parsed, int) and not isinstance(parsed, bool) if expected is int else
                isinstance(parsed, int | float) and not isinstance(parsed, bool)
                if expected is float else False)
        return f"not text (write {value.strip()} without quotes)" if fits else "not text"
    if expected is int and isinstance(value, float) and not isinstance(value, bool):
        return f"not {value!r} (write {int(value)})" if value.is_integer() else \
            f"not {_show(value)}"
    return f"not {_kind_of(value)}"


def _kind_of(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "text"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array"
    return "None" if value is None else type(value).__name__


def _item_ann(ann: Any, sub: tuple) -> Any:
    for part in sub:
        child, _ = _child(_strip(ann)[0], part)
        ann = child
    return ann


def _item_name(key: _Key, sub: tuple) -> str:
    """Bz, nx, or the item's place: ply_angles[1], table[0][1]."""
    args = get_args(key.ann)
    if len(sub) == 1 and not (len(args) == 2 and args[1] is Ellipsis):
        names = _names(key, len(args))
        if names is not None and 0 <= sub[0] < len(names):
            return names[sub[0]]
    return f"{key.name}{''.join(f'[{i}]' for i in sub)}"


def _show(value: Any) -> str:
    """A value as the scenario file writes it: arrays in brackets, true/false, a table as
    {...}."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "{...}"
    if isinstance(value, list | tuple):
        return f"[{', '.join(_show(v) for v in value)}]"
    return repr(value)


def _path_text(path: list | tuple) -> str:
    """field.sources[0].centre: keys dotted, array items indexed."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else f".{part}" if out else str(part)
    return out


def _value_at(data: Any, path: tuple) -> Any:
    for part in path:
        if isinstance(data, dict) and part in data:
            data = data[part]
        elif isinstance(data, list | tuple) and isinstance(part, int) and \
                0 <= part < len(data):
            data = data[part]
        else:
            return _NOTHING
    return data


def _did_you_mean(name: Any, allowed: list[str], key: bool = False) -> str:
    """"did you mean 'areal_density'?" for a close name, or a key's place in another section
    ("did you mean 'solver.courant'?"); "" for none."""
    if not isinstance(name, str) or not name:
        return ""
    lower = {a.lower(): a for a in allowed}
    close = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.75)
    if close:
        return f"did you mean {lower[close[0]]!r}?"
    elsewhere = [p for p in _key_paths() if p.rsplit(".", 1)[-1] == name] if key else []
    if elsewhere:
        return f"did you mean {' or '.join(repr(p) for p in elsewhere[:3])}?"
    return ""


def _key_paths(model: type[BaseModel] | None = None, prefix: str = "") -> list[str]:
    """Dotted paths of the scenario's keys (the sections' tables, not the arrays of them)."""
    out = []
    for name, field in (model or Scenario).model_fields.items():
        base = _strip(field.annotation)[0]
        if _is_model(base):
            out += _key_paths(base, f"{prefix}{name}.")
        else:
            out.append(f"{prefix}{name}")
    return out


def key_unit(path: str) -> str | None:
    """The unit of the scenario key at the dotted `path` for a CF `units` attribute: the one
    its docstring gives in [brackets], "1" for a key of no unit; None where `path` is not a
    key of the scenario (a study's own dimension such as `case`)."""
    parts = tuple(path.split("."))
    try:
        where = _locate(parts)
    except (KeyError, TypeError, ValueError, IndexError):
        return None
    if where.key is None or where.key_len != len(parts):
        return None
    return where.key.unit or "1"


def _allowed_forms(error: dict) -> list[str]:
    """The forms one member of a union allows, from its error on the union's value."""
    kind = error["type"]
    ctx = error.get("ctx", {})
    if kind == "literal_error" and "expected" in ctx:
        # "'a', 'b' or 'c'": each quoted value
        return re.split(r"(?:, | or )(?=['\"])", ctx["expected"])
    if kind in _FORM_WORDS:
        return _FORM_WORDS[kind]
    if kind in _RANGE_ERRORS:
        return [f"a number {_bounds([_Bound(ctx)])}"]
    if kind == "finite_number":
        return ["a finite number"]
    return ["a value of another form"]


def _one_of(forms: list[str]) -> str:
    """'a', 'b' or 'c'."""
    return forms[0] if len(forms) == 1 else f"{', '.join(forms[:-1])} or {forms[-1]}"


class _Where:
    """An error's location resolved against the schema: the key path as written (pydantic's
    union member labels and tags, such as `literal['auto']`, `bool` or `loop`, dropped), the
    type found there, the discriminator key of a tagged union there, `union_at`: the length
    of the path at the innermost untagged union the location passed through (None: none),
    and the innermost key of a table on the path (`key`, at path[:key_len]; None: none)."""

    def __init__(self, path: list, type_: Any, discriminator: str | None,
                 union_at: int | None, key: _Key | None = None, key_len: int = 0) -> None:
        self.path, self.type, self.discriminator, self.union_at = (path, type_, discriminator,
                                                                   union_at)
        self.key, self.key_len = key, key_len


def _locate(loc: tuple) -> _Where:
    ann: Any = Scenario
    disc: str | None = None
    path: list = []
    union_at = None
    key, key_len = None, 0
    for part in loc:
        ann, disc = _unwrap(ann, disc)
        if _is_union(ann):
            # a member's label or tag: pydantic's, not a key the user wrote; a tagged union
            # validates only the member its tag names, others try every member
            if disc is None:
                union_at = len(path)
            ann, disc = _member(ann, part, disc), None
            continue
        path.append(part)
        if _is_model(ann) and isinstance(part, str) and part in ann.model_fields:
            field = ann.model_fields[part]
            key = _Key(part, field.annotation, field.metadata, field.description or "")
            key_len = len(path)
        ann, disc = _child(ann, part)
    ann, disc = _unwrap(ann, disc)
    return _Where(path, ann, disc, union_at, key, key_len)


def _is_union(ann: Any) -> bool:
    return get_origin(ann) in (Union, UnionType)


def _is_model(ann: Any) -> bool:
    return isinstance(ann, type) and issubclass(ann, BaseModel)


def _members(ann: Any) -> list[Any]:
    """A union's members; None is not one (an optional key's null is no form of its own)."""
    return [a for a in get_args(ann) if a is not type(None)]


def _unwrap(ann: Any, disc: str | None = None) -> tuple[Any, str | None]:
    """The type without Annotated and Optional, and the discriminator of a tagged union."""
    while True:
        if get_origin(ann) is Annotated:
            ann, *meta = get_args(ann)
            for m in meta:
                if isinstance(getattr(m, "discriminator", None), str):
                    disc = m.discriminator
        elif _is_union(ann) and len(_members(ann)) == 1:
            ann = _members(ann)[0]
        else:
            return ann, disc


def _child(ann: Any, part: Any) -> tuple[Any, str | None]:
    """The type of a model's key or of a tuple's item (None: not in the schema)."""
    if _is_model(ann) and isinstance(part, str) and part in ann.model_fields:
        field = ann.model_fields[part]
        disc = field.discriminator
        return field.annotation, disc if isinstance(disc, str) else None
    if get_origin(ann) is tuple and isinstance(part, int):
        args = get_args(ann)
        if len(args) == 2 and args[1] is Ellipsis:
            return args[0], None
        if 0 <= part < len(args):
            return args[part], None
    return None, None


def _member(union: Any, label: Any, disc: str | None) -> Any:
    """The member of a union that pydantic's loc label names: the table whose discriminator
    takes that tag, or the type of that name (None: not known, the path below is kept)."""
    for m in _members(union):
        base, _ = _unwrap(m)
        if disc is not None and _is_model(base) and disc in base.model_fields:
            if label in get_args(base.model_fields[disc].annotation):
                return base
        elif getattr(base, "__name__", None) in _label_names(label):
            return base
    return None


def _label_names(label: Any) -> set[str]:
    """Type names a pydantic union member label may stand for: `Sub`, `tuple[float, float]`
    (tuple), `constrained-float` (float), `function-after[_check(), Sub]` (Sub)."""
    if not isinstance(label, str):
        return set()
    names = {label, label.split("[", 1)[0], label.rsplit("-", 1)[-1]}
    if label.startswith("function-") and label.endswith("]"):
        names |= _label_names(label[:-1].rsplit(", ", 1)[-1].split("[", 1)[-1])
    return names


def _tags(ann: Any, disc: str | None) -> list[str]:
    """The tags a tagged union takes (its members' discriminator values), quoted."""
    if disc is None or not _is_union(ann):
        return []
    tags = []
    for m in _members(ann):
        base, _ = _unwrap(m)
        if _is_model(base) and disc in base.model_fields:
            tags += [repr(t) for t in get_args(base.model_fields[disc].annotation)]
    return tags


def _model_in(ann: Any) -> type[BaseModel] | None:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _tuples(obj: Any) -> Any:
    """Lists (TOML arrays) as tuples, which strict validation takes for the vector fields."""
    if isinstance(obj, dict):
        return {k: _tuples(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return tuple(_tuples(v) for v in obj)
    return obj


def scenario_from_dict(data: dict[str, Any], source: str = "<dict>") -> Scenario:
    """Validate a nested dict into a Scenario; errors name the dotted key."""
    try:
        validated = _tuples(data)
        return Scenario.model_validate(validated)
    except ValidationError as err:
        raise ScenarioError(_format_errors(err, source, validated)) from None
    except RecursionError:
        raise ScenarioError(f"invalid scenario ({source}): values nested too deeply") from None


def builtin_names() -> list[str]:
    """Names of the built-in scenarios shipped in ``emfabric/config/scenarios``."""
    folder = resources.files("emfabric.config") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def builtin_text(name: str) -> str:
    folder = resources.files("emfabric.config") / "scenarios"
    path = folder / f"{name}.toml"
    if not path.is_file():
        names = builtin_names()
        starting = [n for n in names if len(name) >= 3 and n.startswith(name)]
        close = list(dict.fromkeys([*starting, *difflib.get_close_matches(name, names, n=3,
                                                                          cutoff=0.6)]))[:3]
        hint = f"did you mean {_or(close)}? " if close else ""
        raise ScenarioError(
            f"no built-in scenario named {name!r} and no such file; {hint}allowed: a .toml "
            f"file or a built-in name: {', '.join(names)} (emfabric scenarios)")
    return path.read_text(encoding="utf-8")


def _or(names: list[str]) -> str:
    """'a', 'b' or 'c'."""
    return _one_of([repr(n) for n in names])


def _no_file(path: Path) -> str:
    """Why a scenario path is not a file to read, and what is."""
    if path.is_dir():
        return (f"scenario {str(path)!r} is a folder, not a TOML file; allowed: a .toml file "
                "or a built-in name (emfabric scenarios)")
    msg = f"scenario file {str(path)!r} does not exist"
    if path.stem in builtin_names():
        return f"{msg}; {path.stem!r} is a built-in scenario: give its name without .toml"
    try:  # a file of a close name beside it
        stems = sorted(p.stem for p in path.parent.glob("*.toml") if p.is_file())
    except (OSError, ValueError):
        stems = []
    close = difflib.get_close_matches(path.stem, stems, n=1, cutoff=0.75)
    if close:
        return f"{msg}; did you mean {str(path.with_name(close[0] + '.toml'))!r}?"
    return msg


def load_scenario(source: str | Path, overrides: dict[str, Any] | None = None) -> Scenario:
    """Load a scenario from a TOML path or a built-in name, then apply dotted overrides.

    An empty file is the built-in defaults (the paper's field-on case) with a warning: it
    is rarely what was meant."""
    path = Path(source)
    # a folder named like a built-in (`emfabric run pack-field --out pack-field`, then the same
    # command again) does not hide the built-in: a folder is never a scenario
    builtin_folder = path.is_dir() and str(source) in builtin_names()
    if path.suffix == ".toml" or (path.exists() and not builtin_folder):
        if not path.is_file():
            raise ScenarioError(_no_file(path))
        raw = path.read_bytes()
        label = str(path)
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            raise ScenarioError(f"scenario file {label!r} is not UTF-8 text (byte "
                                f"{raw[err.start]:#04x} at offset {err.start}); save it as "
                                f"UTF-8") from None
    else:
        text = builtin_text(str(source))
        label = f"built-in {source!r}"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ScenarioError(f"invalid TOML in {label}: {err}") from None
    except RecursionError:
        raise ScenarioError(f"invalid TOML in {label}: arrays nested too deeply") from None
    if not data and label == str(path):
        what = "is empty" if not text.strip() else "has no keys (only comments)"
        logging.getLogger(__name__).warning(
            "scenario file %s %s: running the built-in defaults (the paper's field-on case)",
            label, what)
    data.setdefault("name", path.stem if label == str(path) else str(source))
    scenario = scenario_from_dict(data, label)
    return apply_overrides(scenario, overrides or {})


def parse_override(text: str) -> tuple[str, Any]:
    """Parse ``key.path=value`` (value as TOML, else a Python literal, else a string)."""
    if "=" not in text:
        raise ScenarioError(f"override {text!r} must look like section.key=value")
    key, raw = text.split("=", 1)
    key, raw = key.strip(), raw.strip()
    if not key or any(not part.strip() for part in key.split(".")):
        raise ScenarioError(f"override {text!r} must look like section.key=value")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        try:
            value = ast.literal_eval(raw)
        except (ValueError, SyntaxError, TypeError, MemoryError):
            value = raw
        except RecursionError:
            raise ScenarioError(f"override {key!r}: value nested too deeply") from None
    except RecursionError:
        raise ScenarioError(f"override {key!r}: value nested too deeply") from None
    return key, value


def _plain(value: Any) -> Any:
    """An override from Python as a scenario file would hold it: NumPy scalars and arrays
    (a seed from np.arange, nodes from an array) as Python numbers and lists."""
    if hasattr(value, "tolist") and type(value).__module__ == "numpy":
        return value.tolist()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def apply_overrides(scenario: Scenario, overrides: dict[str, Any]) -> Scenario:
    """Return a new validated Scenario with ``{"a.b.c": value}`` overrides applied."""
    if not overrides:
        return scenario
    data = copy.deepcopy(scenario.to_dict())
    if ("field.sources" in overrides and "field.B" not in overrides
            and "B" not in scenario.field.model_fields_set):
        # as in a file: with sources, the uniform B is only what is written (FieldSpec)
        data.setdefault("field", {}).pop("B", None)
    if ("solver.integrator" not in overrides
            and "integrator" not in scenario.solver.model_fields_set
            and any(k in overrides for k in (*(f"solver.{p}" for p in PHI_KEYS),
                                              "contact.placement"))):
        # as in a file: a key only the φ-scheme reads chooses it (SolverSpec)
        data.setdefault("solver", {}).pop("integrator", None)
    if any(k.startswith("fabric.") for k in overrides):
        # as in a file: what the library, a style or a datasheet key supplied is derived again
        # from the overridden scenario (only what the scenario wrote is kept)
        fab = scenario.fabric
        fd = data.setdefault("fabric", {})
        for key in DERIVED_FABRIC_KEYS:  # plies: from ply tables or ply_angles
            if key not in fab.model_fields_set:
                fd.pop(key, None)
        mat = fab.material
        fd["material"] = {k: v for k, v in fd.get("material", {}).items()
                          if k in mat.model_fields_set or k not in (*LIBRARY_KEYS, "name")}
        if "law" not in fab.damage.model_fields_set:
            fd.get("damage", {}).pop("law", None)
    for key, value in overrides.items():
        value = _plain(value)
        parts = key.split(".")
        node = data
        for i, part in enumerate(parts[:-1]):
            sub = node.get(part)
            if sub is None:
                sub = {}
                node[part] = sub
            if not isinstance(sub, dict):
                prefix = ".".join(parts[: i + 1])
                raise ScenarioError(f"override {key!r}: {prefix!r} is a value, not a section")
            node = sub
        node[parts[-1]] = value
    return scenario_from_dict(data, "overrides " + ", ".join(overrides))
