"""The layers and seams of docs/architecture.md: imports between layers only downwards (by
folder), no import cycles, every compiled function under _kernels/, one definition per concept,
a recorder that computes nothing."""

import ast
import re
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "emfabric"
KERNELS = SRC / "_kernels"

LAYERS = {
    # layer (folder under src/emfabric): the layers it may import (itself always)
    "config": set(),
    "_kernels": set(),
    "sources": {"config", "_kernels"},
    "sim": {"config", "sources", "_kernels"},
    "integrators": {"sim", "_kernels"},
    "io": {"sim", "config", "_kernels"},
    "runner": {"integrators", "io", "sim", "config", "_kernels"},
    "viz": {"io", "config"},
    "studies": {"runner", "sources", "sim", "io", "viz", "config"},
    "cli": {"studies", "runner", "integrators", "viz", "io", "sim", "sources", "config",
            "_kernels"},
}
"""The package's own top-level modules (__init__, __main__) are the façade: they may import
any layer, and every layer may import the package itself (for __version__)."""


def _module(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(("emfabric", *parts)).removesuffix(".__init__")


def _layer(module: str) -> str | None:
    """The layer of a module name (None for the package façade)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in LAYERS) else None


def _type_checking_nodes(tree: ast.AST) -> set[ast.AST]:
    """Nodes under `if TYPE_CHECKING:` (annotations only: no import at run time)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                out.update(ast.walk(child))
    return out


def _imported(path: Path) -> list[str]:
    """Every emfabric module a file imports, at module level or inside a function; a relative
    import (`from ..runner import x`) by the absolute name it resolves to."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _type_checking_nodes(tree)
    # the file's package, dotted: src/emfabric/sim/state.py -> emfabric.sim
    package = ".".join(path.relative_to(SRC.parent).with_suffix("").parts)
    if path.name != "__init__.py":
        package = package.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(tree):
        if node in skip:
            continue
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            module = f"{base}.{node.module}" if node.module else base
            out.append(module)
            out.extend(f"{module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and \
                node.module.startswith("emfabric"):
            out.append(node.module)
            out.extend(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.extend(a.name for a in node.names if a.name.startswith("emfabric"))
    return out


def test_every_module_belongs_to_a_layer():
    """src/emfabric holds only the façade files and the layer folders of LAYERS."""
    top = {p.name for p in SRC.iterdir() if p.suffix == ".py"}
    assert top == {"__init__.py", "__main__.py"}
    folders = {p.name for p in SRC.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert folders == set(LAYERS)


def test_layers_import_only_downwards():
    """A module imports only its own layer, the layers LAYERS allows it, and the package itself;
    imports inside functions count (a lazy import is still a dependency)."""
    modules = {_module(p) for p in SRC.rglob("*.py")}
    wrong = []
    for path in sorted(SRC.rglob("*.py")):
        layer = _layer(_module(path))
        if layer is None:
            continue
        for target in _imported(path):
            if target not in modules and target.rsplit(".", 1)[0] in modules:
                target = target.rsplit(".", 1)[0]  # a name imported from a module
            other = _layer(target)
            if other is not None and other != layer and other not in LAYERS[layer]:
                wrong.append(f"{_module(path)} imports {target}")
    assert not wrong, "\n".join(wrong)


def test_compiled_code_only_under_kernels():
    """Every Numba-compiled function lives in _kernels/ (cached by the digest of those sources:
    a compiled function elsewhere that inlines a kernel would run stale code after an edit)."""
    numba_decorators = {"njit", "jit", "vectorize", "guvectorize", "cfunc", "generated_jit"}
    hits = []
    for path in sorted(SRC.rglob("*.py")):
        if path.parent == KERNELS:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names]
                mod = getattr(node, "module", None) or ""
                if mod.startswith("numba") and set(names) & numba_decorators:
                    hits.append(f"{path.relative_to(SRC)} imports {names}")
            if isinstance(node, ast.FunctionDef):
                for dec in node.decorator_list:
                    name = ast.unparse(dec).split("(")[0].split(".")[-1]
                    if name in numba_decorators:
                        hits.append(f"{path.relative_to(SRC)}: {node.name}")
    assert not hits, hits


def test_no_import_cycles():
    """No module imports, even lazily inside a function, a module that imports it back."""
    files = {_module(p): p for p in SRC.rglob("*.py")}
    graph = {}
    for m, p in files.items():
        deps = set()
        for d in _imported(p):
            d = d if d in files else d.rsplit(".", 1)[0]
            if d in files and d != m:
                deps.add(d)
        graph[m] = deps
    graph.pop("emfabric", None)  # the package façade imports the public functions
    for deps in graph.values():
        deps.discard("emfabric")
        # a package's __init__ re-exports its modules: importing a module of a package runs it
        deps.difference_update({d for d in list(deps) if files[d].name == "__init__.py"
                                and any(x.startswith(d + ".") for x in deps)})
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
    """io/history stores the rows emfabric.sim.diagnostics fills; it imports no kernel."""
    text = (SRC / "io" / "history.py").read_text(encoding="utf-8")
    assert "_kernels" not in text
    assert "emfabric.sim.diagnostics import" in text


def test_optional_dependencies_stay_optional():
    """magpylib (the "magnets" extra), Dask and SciPy (the "studies" extra) are imported only
    inside the functions that need them: the tests' environment has them, a user's without the
    extras must not (an undeclared SciPy once broke every new install)."""
    allowed = {("emfabric.sources.grid", "magnet_fields"),
               ("emfabric.sources.grid", "import_magpylib"),
               ("emfabric.studies.ballistic", "fit_lambert_jonas"),
               ("emfabric.studies.ballistic", "fit_v50"),
               ("emfabric.studies.sweep", "connect"), ("emfabric.studies.sweep", "run_cases")}
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


def test_compiled_functions_take_at_most_twelve_parameters():
    """A kernel that takes more than 12 loose arguments is missing a record (DESIGN.md)."""
    long = []
    for path in sorted(KERNELS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef) and any(
                    ast.unparse(d).split("(")[0].split(".")[-1] in ("njit", "jit", "overload")
                    for d in node.decorator_list):
                if len(node.args.args) > 12:
                    long.append(f"{path.name}: {node.name} ({len(node.args.args)})")
    assert not long, long


def test_no_class_name_defined_twice():
    """One name, one concept: no two classes of the package share a name (the scenario's
    [contact] table is ContactSpec, the kernels' record Contact)."""
    seen: dict[str, str] = {}
    twice = []
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                where = str(path.relative_to(SRC))
                if node.name in seen:
                    twice.append(f"{node.name}: {seen[node.name]} and {where}")
                seen[node.name] = where
    assert not twice, twice


def test_layer_docstrings_say_what_the_test_allows():
    """Each layer's __init__ docstring names, after "May import:", exactly the layers LAYERS
    allows it (config and _kernels: none; cli: all)."""
    names = "|".join(sorted(LAYERS, key=len, reverse=True))
    for layer, allowed in LAYERS.items():
        doc = ast.get_docstring(ast.parse((SRC / layer / "__init__.py").read_text("utf-8")))
        assert doc, f"{layer}/__init__.py has no docstring"
        if layer == "cli":
            assert "May import every other layer" in doc
            continue
        if not allowed:
            assert re.search(r"[Ii]mports? (nothing|only)", doc), f"{layer}: {doc[:80]}"
            continue
        said = doc.split("May import:")[1].split(".")[0]
        named = {m for m in re.findall(rf"(?<![\w.])({names})(?![\w])", said)}
        assert named == allowed, f"{layer}: the docstring names {named}, the test {allowed}"


def test_relative_imports_are_seen_by_their_absolute_names(tmp_path, monkeypatch):
    """The layer and cycle tests read every import: `from ..runner import loop` in sim/ is
    emfabric.runner (and .loop), as `from emfabric.runner import loop` would be."""
    import sys

    here = sys.modules[__name__]
    root = tmp_path / "emfabric"
    (root / "sim").mkdir(parents=True)
    f = root / "sim" / "x.py"
    f.write_text("from ..runner import loop\nfrom . import state\nfrom .model import M\n")
    monkeypatch.setattr(here, "SRC", root)
    assert _imported(f) == ["emfabric.runner", "emfabric.runner.loop", "emfabric.sim",
                            "emfabric.sim.state", "emfabric.sim.model", "emfabric.sim.model.M"]


def _kernel_functions() -> dict[tuple[str, str], tuple[ast.FunctionDef, dict[str, str]]]:
    """Every compiled function of _kernels/ by (module, name): its definition and its
    decorator's keywords as source text."""
    out = {}
    for path in sorted(KERNELS.glob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if not isinstance(node, ast.FunctionDef):
                continue
            for dec in node.decorator_list:
                if ast.unparse(dec).split("(")[0] == "njit":
                    kw = ({k.arg: ast.unparse(k.value) for k in dec.keywords}
                          if isinstance(dec, ast.Call) else {})
                    out[(path.stem, node.name)] = (node, kw)
    return out


def _kernel_names(stem: str) -> dict[str, tuple[str, str]]:
    """The names module _kernels/<stem>.py can call a kernel function by: its own functions
    and those it imports from the other kernel modules."""
    tree = ast.parse((KERNELS / f"{stem}.py").read_text(encoding="utf-8"))
    names = {n.name: (stem, n.name) for n in tree.body if isinstance(n, ast.FunctionDef)}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "emfabric._kernels."):
            for a in node.names:
                names[a.asname or a.name] = (node.module.rsplit(".", 1)[1], a.name)
    return names


def test_functions_called_without_reference_counts_set_their_own():
    """A kernel compiled with `_nrt=False` (the step kernels, the row kernels) passes the flag
    on to every function it compiles that does not set one: that function then compiles
    without reference counts or not at all where it allocates — and with the flags of
    whichever caller compiled it first in a process, or in the cache. So each function such a
    kernel calls directly (looking through those inlined into it) sets `_nrt` itself
    (emfabric._kernels.explicit's docstring)."""
    kernels = _kernel_functions()
    names = {stem: _kernel_names(stem) for stem in {k[0] for k in kernels}}
    unset = []

    def walk(key, root, seen):
        fn, _kw = kernels[key]
        for node in ast.walk(fn):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)):
                continue
            callee = names[key[0]].get(node.func.id)
            if callee is None or callee not in kernels or callee in seen:
                continue
            seen.add(callee)
            kw = kernels[callee][1]
            if kw.get("inline") == "'always'":
                walk(callee, root, seen)
            elif "_nrt" not in kw:
                unset.append(f"{'.'.join(callee)} (called by {'.'.join(root)})")

    roots = [k for k, (_fn, kw) in kernels.items() if kw.get("_nrt") == "False"]
    assert ("explicit", "central_step") in roots and ("step", "attempt_step") in roots
    for key in roots:
        walk(key, key, set())
    assert not unset, unset
