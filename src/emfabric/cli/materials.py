"""The materials command: ``emfabric materials [--json]``, the material and fabric-style
library (emfabric.config.library; docs/materials.md) with units and sources."""

from __future__ import annotations

from typing import Annotated, Any

import typer
from rich import box
from rich.table import Table

from emfabric.cli.app import app, emit, out_console
from emfabric.io import jsontext


def _library() -> dict[str, Any]:
    """The library as plain data, SI units named in the keys."""
    from emfabric.config.library import CITATIONS, MATERIALS, STYLES

    materials = [{
        "name": m.name, "title": m.title,
        "density_kg_m3": m.density, "youngs_modulus_pa": m.youngs_modulus,
        "tensile_strength_pa": m.tensile_strength, "failure_strain": m.failure_strain,
        "weibull_shape": m.weibull_shape,
        "sources": dict(m.sources),
        "published": {k: {"value": v, "unit": u} for k, (v, u) in m.published.items()},
    } for m in MATERIALS.values()]
    styles = [{
        "name": s.name, "title": s.title, "material": s.material, "weave": s.weave,
        "linear_density_tex": s.linear_density_tex, "denier": s.linear_density_tex * 9.0,
        "thread_count_per_cm": list(s.thread_count),
        "areal_density_kg_m2": s.areal_density,
        "yarn_area_m2": s.yarn_area, "yarn_radius_m": s.yarn_radius,
        "spacing_m": list(s.spacing),
        "sources": dict(s.sources),
        "published": {k: {"value": v, "unit": u} for k, (v, u) in s.published.items()},
    } for s in STYLES.values()]
    return {"materials": materials, "styles": styles, "citations": dict(CITATIONS)}


def _by_source(sources: dict[str, str]) -> str:
    """"density, failure_strain: key-a; youngs_modulus: key-b" from field -> key."""
    groups: dict[str, list[str]] = {}
    for field, key in sources.items():
        groups.setdefault(key, []).append(field)
    return "; ".join(f"{', '.join(fields)}: {key}" for key, fields in groups.items())


@app.command(short_help="List the material and fabric-style library.")
def materials(
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print the library as JSON (SI units named in the keys)")] = False,
) -> None:
    """List the material and fabric-style library (fabric.material.name, fabric.style): fibre
    properties, fabric constructions, the yarn network each style gives, and the source of
    every number (docs/materials.md)."""
    lib = _library()
    if as_json:
        emit(jsontext.dumps(lib, indent=2))
        return
    mats = Table(title="Materials (fabric.material.name)", box=box.SIMPLE_HEAD)
    mats.add_column("name", no_wrap=True)
    for head in ("density\nkg/m³", "E\nGPa", "strength\nGPa", "failure\nstrain %",
                 "Weibull\nshape"):
        mats.add_column(head, justify="right")
    for m in lib["materials"]:
        shape = m["weibull_shape"]
        mats.add_row(m["name"], f"{m['density_kg_m3']:.0f}",
                     f"{m['youngs_modulus_pa'] / 1e9:.1f}",
                     f"{m['tensile_strength_pa'] / 1e9:.2f}",
                     f"{m['failure_strain'] * 100:.2f}",
                     "-" if shape is None else f"{shape:g}")
    out_console.print(mats)
    styles = Table(title="Fabric styles (fabric.style)", box=box.SIMPLE_HEAD, pad_edge=False,
                   padding=0)
    styles.add_column("name", no_wrap=True)
    styles.add_column("material", no_wrap=True)
    for head, width in (("yarn\ntex", 5), ("\nden", 4), ("ends×picks\nper cm", 11),
                        ("areal\ng/m²", 5), ("r\nµm", 3), ("spacing\nmm", 11)):
        styles.add_column(head, justify="right", overflow="fold", min_width=width)
    for s in lib["styles"]:
        ends, picks = s["thread_count_per_cm"]
        sx, sy = s["spacing_m"]
        styles.add_row(s["name"], s["material"],
                       f"{s['linear_density_tex']:.1f}", f"{s['denier']:.0f}",
                       f"{ends:.2f}×{picks:.2f}", f"{s['areal_density_kg_m2'] * 1e3:.1f}",
                       f"{s['yarn_radius_m'] * 1e6:.0f}", f"{sx * 1e3:.3f}×{sy * 1e3:.3f}")
    out_console.print(styles)
    out_console.print("[bold]Where each value comes from[/]")
    for entry in lib["materials"] + lib["styles"]:
        out_console.print(f"  {entry['name']}: " + _by_source(entry["sources"]),
                          markup=False, highlight=False)
    out_console.print("[bold]Sources[/]")
    for key, ref in lib["citations"].items():
        out_console.print(f"[bold]{key}[/]: ", end="")
        out_console.print(ref, markup=False, highlight=False)
