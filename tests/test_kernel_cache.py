"""Where the compiled kernels live: a folder per kernel-source digest, never the package;
chosen when a kernel first asks, not when the package is imported; Numba's private caching
names that this relies on are checked."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numba
import pytest

import emfabric._kernels as kernels

PROBE = ("import numpy as np, emfabric._kernels as k; from emfabric._kernels.sums import fsum; "
         "assert fsum(np.array([1e16, 1.0, -1e16]), 3) == 1.0; "
         "print(k.cache_dir()); print(k.cache_persistent())")


def _env(env_extra: dict) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES")}
    env.update(env_extra)
    return env


def _run(code: str, env_extra: dict) -> str:
    return subprocess.run([sys.executable, "-c", code], env=_env(env_extra), capture_output=True,
                          text=True, check=True).stdout


def _probe(env_extra: dict) -> tuple[Path, bool]:
    out = _run(PROBE, env_extra).split()
    return Path(out[0]), out[1] == "True"


def test_digest_changes_with_any_kernel_source(tmp_path):
    """Editing any one kernel module gives another cache folder (Numba alone would keep a
    cached caller with the old callee inlined)."""
    pkg = tmp_path / "_kernels"
    shutil.copytree(kernels.KERNEL_DIR, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    before = kernels.source_digest(pkg)
    assert before == kernels.source_digest(kernels.KERNEL_DIR)
    (pkg / "materials.py").write_text((pkg / "materials.py").read_text() + "\n# edited\n")
    assert kernels.source_digest(pkg) != before


def test_cache_honours_numba_cache_dir_and_never_writes_the_package(tmp_path):
    """NUMBA_CACHE_DIR is the base; the kernels land in its digest folder, not in the package."""
    folder, persistent = _probe({"NUMBA_CACHE_DIR": str(tmp_path)})
    assert persistent
    assert folder == tmp_path / "emfabric" / f"kernels-{kernels.source_digest()}"
    assert list(folder.glob("sums.fsum-*.nbi"))
    assert not list(kernels.KERNEL_DIR.glob("__pycache__/*.nbi"))


def test_cache_defaults_to_the_users_cache_directory(tmp_path):
    """Without NUMBA_CACHE_DIR the kernels go to the user's cache directory (XDG on Linux)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("XDG_CACHE_HOME is the Linux convention")
    folder, persistent = _probe({"XDG_CACHE_HOME": str(tmp_path)})
    assert persistent and folder.parent == tmp_path / "emfabric"
    assert list(folder.glob("sums.fsum-*.nbi"))


def test_unwritable_cache_falls_back_to_a_temporary_folder():
    """No writable cache folder (a read-only home, say): the kernels still compile and run."""
    folder, persistent = _probe({"NUMBA_CACHE_DIR": "/dev/null/not-a-folder"})
    assert not persistent
    assert "emfabric-kernels-" in folder.name


def test_cached_kernels_do_not_depend_on_file_times(tmp_path):
    """A kernel file saved again with the same content (an editor, `git checkout` back and
    forth) keeps every cached kernel: the cache stamp is the folder's content digest, not the
    file's mtime (Numba's default would drop that file's kernels and keep their callers)."""
    from numba.core.caching import FunctionCache

    from emfabric._kernels.sums import fsum

    cache = FunctionCache(fsum.py_func)
    stamp = cache._impl.locator.get_source_stamp()
    src = Path(fsum.py_func.__code__.co_filename)
    before = src.stat()
    try:
        os.utime(src, (before.st_atime, before.st_mtime + 1000))
        assert FunctionCache(fsum.py_func)._impl.locator.get_source_stamp() == stamp
    finally:
        os.utime(src, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert stamp == f"kernels-{kernels.source_digest()}"
    if kernels.cache_persistent():
        assert stamp == kernels.cache_dir().name


def test_parallel_kernels_are_not_cached_on_their_own():
    """A parallel kernel loaded from the cache must never be linked into a caller that is then
    cached (the caller crashed when loaded in a later process): every parallel=True kernel that
    another kernel calls compiles with its caller instead
    (emfabric._kernels.nodes.fused_iterate_threads); one called from Python only (the source
    grid's coils.loop_values_on_grid) may be cached."""
    import importlib

    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher

    sources = {src: src.read_text(encoding="utf-8")
               for src in sorted(kernels.KERNEL_DIR.glob("*.py")) if src.stem != "__init__"}
    parallel, cached = set(), set()
    for src in sources:
        # (not the package itself: importing "__init__" would run it a second time)
        module = importlib.import_module(f"emfabric._kernels.{src.stem}")
        for obj in vars(module).values():
            if isinstance(obj, CPUDispatcher) and obj.targetoptions.get("parallel"):
                parallel.add(obj.py_func.__name__)
                if not isinstance(obj._cache, NullCache):
                    cached.add(obj.py_func.__name__)
    assert parallel == {"_iterate_rows_threads", "fill_node_fields_threads",
                        "_drift_threads", "_kick_threads", "loop_values_on_grid"}
    for name in cached:
        callers = [src.name for src, text in sources.items()
                   if f"{name}(" in text.replace(f"def {name}(", "")]
        assert not callers, f"the cached parallel kernel {name} is called from {callers}"


LEAK_CHECK = textwrap.dedent("""
    import json, sys
    import emfabric
    from emfabric.config.scenario import load_scenario
    from numba.core.runtime import rtsys
    out = []
    for name, over, threads in json.loads(sys.argv[1]):
        emfabric.run(load_scenario(name, over), None, threads=threads)  # compile or load
        s0 = rtsys.get_allocation_stats()
        emfabric.run(load_scenario(name, over), None, threads=threads)
        s1 = rtsys.get_allocation_stats()
        out.append([name, s1.alloc - s0.alloc, s1.free - s0.free,
                    s1.mi_alloc - s0.mi_alloc, s1.mi_free - s0.mi_free])
    print(json.dumps(out))
""")


def test_kernels_called_without_reference_counts_leak_nothing():
    """The step kernels run without reference counts (emfabric._kernels.explicit says why):
    an array a callee of theirs allocated and handed back would never be freed. Numba's own
    allocation counters balance over whole runs of each path: central differences with node,
    segment and ply contact (an FSP into a pack), threaded, and the φ-scheme with loops'
    fields."""
    cases = [["pack-fsp", {"fabric.nodes": [15, 15], "solver.end_time": 2e-6}, None],
             ["demo-small", {"solver.end_time": 5e-6}, 2],
             ["coil-pulse", {"fabric.nodes": [20, 20], "solver.end_time": 5e-6,
                             "solver.integrator": "phi"}, None]]
    env = {**os.environ, "NUMBA_NRT_STATS": "1"}
    res = subprocess.run([sys.executable, "-c", LEAK_CHECK, json.dumps(cases)], env=env,
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-2000:]
    for name, alloc, free, mi_alloc, mi_free in json.loads(res.stdout.splitlines()[-1]):
        assert alloc > 0 and alloc == free and mi_alloc == mi_free, (name, alloc, free)


def test_importing_the_package_touches_no_file(tmp_path):
    """Importing emfabric._kernels (a record type, say) chooses, creates and prunes nothing;
    the first kernel module imported does, and prunes digest folders unused for 30 days."""
    root = tmp_path / "emfabric"
    old = root / "kernels-0000000000000000"
    old.mkdir(parents=True)
    month = time.time() - 40 * 86400
    os.utime(old, (month, month))
    code = textwrap.dedent("""
        import os, sys
        import emfabric._kernels as k
        import emfabric._kernels.records
        root = sys.argv[1]
        print(sorted(os.listdir(root)), k._chosen is None)
        import emfabric._kernels.sums
        print(sorted(os.listdir(root)), k.CACHE_DIR == k.cache_dir(), k.CACHE_PERSISTENT)
    """)
    out = subprocess.run([sys.executable, "-c", code, str(root)],
                         env=_env({"NUMBA_CACHE_DIR": str(tmp_path)}), capture_output=True,
                         text=True, check=True).stdout.splitlines()
    assert out[0] == "['kernels-0000000000000000'] True"
    assert out[1] == f"['kernels-{kernels.source_digest()}'] True True"


def test_a_users_locator_setting_still_caches_the_kernels_by_digest(tmp_path):
    """NUMBA_CACHE_LOCATOR_CLASSES makes Numba ignore its class list: the kernels' locator is
    then put in front of the user's setting."""
    folder, persistent = _probe({"NUMBA_CACHE_DIR": str(tmp_path),
                                 "NUMBA_CACHE_LOCATOR_CLASSES": "UserProvidedCacheLocator"})
    assert persistent
    assert folder == tmp_path / "emfabric" / f"kernels-{kernels.source_digest()}"
    assert list(folder.glob("sums.fsum-*.nbi"))


OTHER = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    if sys.argv[2] == "with":
        import emfabric._kernels
    import numba
    import other
    assert other.twice(2.0) == 4.0
""")


@pytest.mark.parametrize("numba_cache_dir", [True, False])
def test_other_code_caches_where_numba_puts_it(tmp_path, numba_cache_dir):
    """A cache=True function outside the kernels is cached where Numba alone puts it (with
    NUMBA_CACHE_DIR in its folder, else in __pycache__ beside the source), emfabric imported
    or not."""
    src = tmp_path / "src"  # one source folder: Numba's cache subfolder names its path
    src.mkdir()
    (src / "other.py").write_text(
        "import numba\n\n\n@numba.njit(cache=True)\ndef twice(x):\n    return 2 * x\n")
    placed = {}
    for run in ("without", "with"):
        cache = tmp_path / f"cache-{run}"
        env = {"NUMBA_CACHE_DIR": str(cache)} if numba_cache_dir else {}
        subprocess.run([sys.executable, "-c", OTHER, str(src), run], env=_env(env),
                       capture_output=True, text=True, check=True)
        placed[run] = sorted(str(p.relative_to(tmp_path)).replace(f"cache-{run}", "cache")
                             for p in tmp_path.rglob("*.nbi"))
        shutil.rmtree(src / "__pycache__", ignore_errors=True)
        shutil.rmtree(cache, ignore_errors=True)
    assert placed["with"] == placed["without"]
    assert len(placed["with"]) == 1
    assert placed["with"][0].startswith("cache/" if numba_cache_dir else "src/__pycache__/")


@pytest.mark.parametrize("remove", ["_CacheLocator", "get_source_stamp", "_locator_classes",
                                    "CompileResultCacheImpl"])
def test_missing_private_numba_names_fail_loudly(monkeypatch, remove):
    """The private names of numba.core.caching the locator relies on are checked before use:
    a Numba release without one raises RuntimeError naming the Numba version and the name."""
    from numba.core import caching

    if remove == "get_source_stamp":
        monkeypatch.delattr(caching._CacheLocator, remove)
    elif remove == "_locator_classes":
        monkeypatch.setattr(caching.CacheImpl, remove, tuple(caching.CacheImpl._locator_classes))
    else:
        monkeypatch.delattr(caching, remove)
    with pytest.raises(RuntimeError, match=f"Numba {numba.__version__}.*{remove}"):
        kernels.check_numba_cache_hooks()
    with pytest.raises(RuntimeError, match=remove):
        kernels.install_kernel_locator()


def test_installed_numba_has_the_names_and_installing_again_replaces(monkeypatch):
    """Against the installed Numba: the check passes, the locator is first in Numba's list
    exactly once (installing again replaces it), and Numba picks it for a kernel file only."""
    from numba.core import caching

    base, impl = kernels.check_numba_cache_hooks()
    assert base is caching._CacheLocator
    monkeypatch.setattr(impl, "_locator_classes", list(impl._locator_classes))
    monkeypatch.setattr(kernels, "KernelCacheLocator", kernels.KernelCacheLocator)
    again = kernels.install_kernel_locator()
    assert impl._locator_classes[0] is again
    assert sum(getattr(c, "emfabric_kernels", False) for c in impl._locator_classes) == 1

    def elsewhere():
        pass

    assert not isinstance(caching.CompileResultCacheImpl(elsewhere).locator, again)


PACK_FSP = {"fabric.plies": 2, "fabric.nodes": [21, 21], "solver.end_time": 2e-7}
"""A pack struck by an FSP: ply and segment contact, so every precompile target."""

PRECOMPILED_RUN = """
import json, logging, sys
from numba.core import event
rec = event.RecordingListener()
event.register("numba:compile", rec)
from emfabric import load_scenario, run
from emfabric.integrators import make_integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import blank_state
logging.disable(logging.WARNING)
sc = load_scenario("pack-fsp", json.loads(sys.argv[1]))
model = build_model(sc, writes=False)
targets = {k.py_func.__qualname__
           for k, _a in make_integrator(model, threads=1).precompile_targets(blank_state(model))}
run(sc, threads=1)
starts = [ev.data["dispatcher"].py_func.__qualname__ for _ts, ev in rec.buffer if ev.is_start]
here = set(starts)
import gc
from numba.core.registry import CPUDispatcher
print(json.dumps(sorted(d.py_func.__qualname__ for d in gc.get_objects()
                        if isinstance(d, CPUDispatcher) and len(d.signatures) > 1)))
print(json.dumps({name: starts.count(name) for name in ROW_KERNELS}))
print(json.dumps(sorted(targets)))
print(json.dumps(sorted(targets & here)))
"""
ROW_KERNELS = ("_kick_block", "_drift_block", "_row_block", "kick_rows", "drift_rows",
               "fused_iterate", "_tensions")
PRECOMPILED_RUN = PRECOMPILED_RUN.replace("ROW_KERNELS", repr(ROW_KERNELS))


@pytest.mark.parametrize("integrator, expected, tensions", [
    ("central-difference", {"_drift_block", "_node_contact", "ply_contact", "segment_contact",
                            "_mid_rotation", "_friction_work", "_body_field_work",
                            "_travel_from_rows", "stable_step", "travel_step"}, 1),
    ("phi", {"_row_block", "travel_step", "ply_forces", "ply_update", "node_contact",
             "segment_contact", "body_update", "step_energy"}, 0),
])
def test_a_second_process_compiles_what_the_step_kernel_then_loads(tmp_path, integrator,
                                                                   expected, tensions):
    """On a cold cache a run has a second process compile the step kernel's largest callees
    (runner.precompile) into the cache. Their argument types must be the ones the run
    passes, or the run compiles them again: after the second process has finished, a run of a
    pack struck by an FSP (ply and segment contact: every target) compiles none of them, for
    either scheme, the kick's row block once, and no kernel twice."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path), "EMFABRIC_PRECOMPILE": "0"}
    keys = json.dumps({**PACK_FSP, "solver.integrator": integrator})
    text = subprocess.run(
        [sys.executable, "-c", "import json, sys; from emfabric import load_scenario; "
         "print(load_scenario('pack-fsp', json.loads(sys.argv[1])).to_toml())", keys],
        env=_env(env), capture_output=True, text=True, check=True).stdout
    subprocess.run([sys.executable, "-m", "emfabric.runner.precompile"], input=text,
                   env=_env(env), capture_output=True, text=True, check=True)
    out = subprocess.run([sys.executable, "-c", PRECOMPILED_RUN, keys], env=_env(env),
                         capture_output=True, text=True, check=True).stdout.splitlines()
    twice, counts, targets, compiled_again = (json.loads(line) for line in out[-4:])
    assert set(targets) == expected
    assert compiled_again == []
    # the loops over row blocks are inlined into the step kernel, never compiled on their own
    # in a run (each would re-optimise and emit its whole row block again); the initial
    # forces (sim.state.update_forces) call the kick's row block with the very types the
    # central-difference step kernel passes it: one compile of it in all. The yarn law
    # (_tensions) is one specialisation for every caller: compiled once under the kick's row
    # block, or loaded where the second process compiled it under the φ-update's
    assert counts == {"_kick_block": 1, "_drift_block": 0, "_row_block": 0, "kick_rows": 0,
                      "drift_rows": 0, "fused_iterate": 0, "_tensions": tensions}
    # and no kernel of the run compiled for two argument types: a constant argument is typed
    # as a literal (and a variable can be, while its type is still inferred), and each
    # literal value is a compile of its own (_tensions, _yarn_stats, _pass, _hot_union and
    # _clear_boxes were, 1.5 s of a cold start)
    assert twice == []


def test_the_second_process_is_started_only_where_it_can_help(monkeypatch):
    """Not with EMFABRIC_PRECOMPILE=0, not on one core, not inside a Dask worker (a study's
    other cases use the cores)."""
    import types

    from emfabric.runner import precompile

    monkeypatch.delenv("EMFABRIC_PRECOMPILE", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    outside = types.SimpleNamespace(get_worker=lambda: (_ for _ in ()).throw(ValueError()))
    monkeypatch.setitem(sys.modules, "distributed", outside)
    assert precompile.wanted()
    monkeypatch.setitem(sys.modules, "distributed", types.SimpleNamespace(get_worker=object))
    assert not precompile.wanted()
    monkeypatch.setitem(sys.modules, "distributed", outside)
    monkeypatch.setenv("EMFABRIC_PRECOMPILE", "0")
    assert not precompile.wanted()
    monkeypatch.delenv("EMFABRIC_PRECOMPILE")
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert not precompile.wanted()
