"""Where the compiled kernels live: a folder per kernel-source digest, never the package."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import emfabric._kernels as kernels

PROBE = ("import numpy as np, emfabric._kernels as k; from emfabric._kernels.sums import fsum; "
         "assert fsum(np.array([1e16, 1.0, -1e16]), 3) == 1.0; "
         "print(k.CACHE_DIR); print(k.CACHE_PERSISTENT)")


def _probe(env_extra: dict) -> tuple[Path, bool]:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
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
    assert stamp == kernels.CACHE_DIR.name


def test_parallel_kernels_are_not_cached_on_their_own():
    """A parallel kernel loaded from the cache must never be linked into a caller that is then
    cached (the caller crashed when loaded in a later process): every parallel=True kernel
    compiles with its caller instead (emfabric._kernels.nodes.fused_iterate_threads)."""
    import importlib

    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher

    parallel = []
    for src in sorted(kernels.KERNEL_DIR.glob("*.py")):
        module = importlib.import_module(f"emfabric._kernels.{src.stem}")
        for obj in vars(module).values():
            if isinstance(obj, CPUDispatcher) and obj.targetoptions.get("parallel"):
                parallel.append(obj.py_func.__name__)
                assert isinstance(obj._cache, NullCache), obj.py_func.__name__
    # (imported by step.py too)
    assert set(parallel) == {"fused_iterate_threads", "fill_node_fields_threads"}
