"""Field design's one operation on a scenario: every magnetic source scaled by one factor, and
the field this gives at the sheet's centre (emfabric.studies.design searches over the factor)."""

from __future__ import annotations

from emfabric.config.scenario import Scenario, scenario_from_dict
from emfabric.sources.build import build_field
from emfabric.sources.evaluate import fields_at


def scale_field(scenario: Scenario, s: float) -> Scenario:
    """The scenario with every magnetic source scaled by s: the uniform B, the uniform
    sources' B, the loops' and solenoids' currents (tables too), the magnets' polarization and
    the maps' scale (E of a map scales with it; a uniform E does not)."""
    data = scenario.to_dict()
    fld = data.setdefault("field", {})
    fld["B"] = [s * c for c in scenario.field.B]
    sources = []
    for src in scenario.field.sources:
        d = src.model_dump(exclude_none=True)
        if src.kind == "uniform":
            d["B"] = [s * c for c in src.B]
        elif src.kind in ("loop", "solenoid"):
            if src.table is not None:
                d["table"] = [[t, s * i] for t, i in src.table]
            else:
                d["current"] = s * src.current
        elif src.kind == "magnet":
            d["polarization"] = [s * c for c in src.polarization]
        elif src.kind == "map":
            d["scale"] = s * src.scale
        sources.append(d)
    fld["sources"] = sources
    return scenario_from_dict(data, f"{scenario.name} with the field × {s:g}")


def field_at_centre(scenario: Scenario, t: float) -> list[float]:
    """B [T] at the sheet's centre (the origin) at time t."""
    return [float(c) for c in fields_at(build_field(scenario), [[0.0, 0.0, 0.0]], t)[1][0]]
