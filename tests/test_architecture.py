"""The seams of docs/architecture.md: no import cycles, one definition per concept, a recorder
that computes nothing."""

import ast
import re
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "emfabric"
KERNELS = SRC / "_kernels"


def _module(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(("emfabric", *parts)).removesuffix(".__init__")


def _imports(path: Path, modules: set[str]) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("emfabric"):
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                out.add(full if full in modules else node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("emfabric"))
    return out


def test_no_import_cycles():
    """scenario → builder → model/state → integrator → recorder/io: no module imports, even
    lazily inside a function, a module that imports it back."""
    files = {_module(p): p for p in SRC.rglob("*.py")}
    graph = {m: {d for d in _imports(p, set(files)) if d in files and d != m}
             for m, p in files.items()}
    graph.pop("emfabric", None)  # the package façade imports the public functions
    for deps in graph.values():
        deps.discard("emfabric")
    state: dict[str, int] = {}
    cycle: list[str] = []

    def visit(m: str, path: list[str]) -> bool:
        state[m] = 1
        for d in graph.get(m, ()):
            if state.get(d) == 1:
                cycle.extend(path[path.index(d):] + [d] if d in path else [m, d])
                return True
            if d not in state and visit(d, path + [d]):
                return True
        state[m] = 2
        return False

    for m in sorted(graph):
        if m not in state and visit(m, [m]):
            break
    assert not cycle, " -> ".join(cycle)


def _defs(pattern: str) -> list[str]:
    """Kernel files (records excepted) whose code, comments and docstrings aside, matches."""
    hits = []
    for p in sorted(set(KERNELS.glob("*.py")) - {KERNELS / "records.py"}):
        code = "\n".join(line.split("#")[0] for line in p.read_text(encoding="utf-8").splitlines())
        code = re.sub(r'"""(.|\n)*?"""', "", code)
        if re.search(pattern, code):
            hits.append(p.name)
    return hits


def test_each_concept_has_one_definition():
    # the field: its region test and components are read in fields.py only
    assert _defs(r"REGION_HALF_SPACE|\.z0\b|\bfld\.E\b|\bfld\.B\b") == ["fields.py"]
    # the body's shape: its size is read by shapes.py only
    assert _defs(r"\.radius\b") == ["shapes.py"]
    # the contact law: the friction coefficients are read by contact.py only
    assert _defs(r"static_friction|dynamic_friction") == ["contact.py"]
    # the material law: damage exponential, stress laws, stored energy
    assert _defs(r"critical_stretch|damage_rate") == ["materials.py"]
    assert _defs(r"fung_h\s*\*\s*e") == ["materials.py"]
    assert _defs(r"expm1") == ["materials.py"]
    # the stretch: |d|²/L0² only in stretch_sq
    assert _defs(r"dz\s*\*\s*dz\)\s*\*") == ["materials.py"]
    # world inertia and tilt: R I Rᵀ and atan2 only in vec3.py
    assert _defs(r"atan2") == ["vec3.py"]
    assert _defs(r"mat_t_vec\(") == ["vec3.py"]
    # the body-row layout: numeric rows of the body state nowhere outside records.py
    assert _defs(r"b_(in|out|state)\[\s*\d") == []


def test_recorder_computes_no_physics():
    """io/history stores the rows emfabric.diagnostics fills; it imports no kernel."""
    text = (SRC / "io" / "history.py").read_text(encoding="utf-8")
    assert "_kernels" not in text
    assert "emfabric.diagnostics import" in text


def test_optional_dependencies_stay_optional():
    """magpylib (the "magnets" extra), Dask and SciPy (the "studies" extra) are imported only
    inside the functions that need them: the tests' environment has them, a user's without the
    extras must not (an undeclared SciPy once broke every new install)."""
    allowed = {("emfabric.source_grid", "magnet_fields"),
               ("emfabric.source_grid", "import_magpylib"),
               ("emfabric.ballistic", "fit_lambert_jonas"), ("emfabric.ballistic", "fit_v50"),
               ("emfabric.study", "connect"), ("emfabric.study", "run_cases")}
    for path in SRC.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        owner = {}
        for fn in ast.walk(tree):
            if isinstance(fn, ast.FunctionDef):
                for node in ast.walk(fn):
                    owner.setdefault(node, fn.name)
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                if name.split(".")[0] in ("scipy", "magpylib", "dask", "distributed"):
                    where = (_module(path), owner.get(node))
                    assert where in allowed, f"{path.name} imports {name} in {where[1]}"
