"""Numba kernels: arrays in, arrays written in place. Private; wrapped by the modules above.

Where the compiled kernels are cached
-------------------------------------
Numba's on-disk cache checks only the source file of each cached function, not the files of the
kernels it calls (and may have inlined): after one kernel module changes, a cached caller would
run the old code — silently different numbers, or a crash. So every kernel of this package is
cached in one folder named by a digest of all kernel sources (and the Numba version):

    $NUMBA_CACHE_DIR/emfabric/kernels-<digest>/   if NUMBA_CACHE_DIR is set, else
    <user cache>/kernels-<digest>/                the user's cache directory for emfabric

(platformdirs: ~/.cache/emfabric on Linux, ~/Library/Caches/emfabric on macOS, the local
application data folder on Windows). A change to any kernel source gives a new folder; folders
of other digests unused for 30 days are removed.
Nothing is written into the installed package, so a read-only installation works; where no
cache folder is writable at all, the kernels are compiled into a temporary folder for the
process (correct, but every run compiles). Only this package's kernels are redirected: other
code using Numba in the same process keeps Numba's own cache placement.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

KERNEL_DIR = Path(__file__).resolve().parent
UNUSED_DAYS = 30


def source_digest(folder: Path = KERNEL_DIR) -> str:
    """sha256 over the kernel sources in `folder` and the Numba version, first 16 hex digits."""
    import numba

    digest = hashlib.sha256(numba.__version__.encode())
    for src in sorted(folder.glob("*.py")):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    return digest.hexdigest()[:16]


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
        return True
    except OSError:
        return False


def _prune(root: Path, keep: Path) -> None:
    """Remove kernel folders of other digests that no process has used for UNUSED_DAYS."""
    cutoff = time.time() - UNUSED_DAYS * 86400
    for old in root.glob("kernels-*"):
        try:
            if old != keep and old.is_dir() and old.stat().st_mtime < cutoff:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass


def _choose_cache_dir() -> tuple[Path, bool]:
    """(folder, persistent): the digest folder under the first writable base."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        root = Path(env) / "emfabric"
    else:
        import platformdirs

        root = Path(platformdirs.user_cache_dir("emfabric", appauthor=False))
    folder = root / f"kernels-{source_digest()}"
    if _writable(folder):
        try:
            os.utime(folder)  # marks it used, for _prune elsewhere
        except OSError:
            pass
        _prune(root, folder)
        return folder, True
    folder = Path(tempfile.mkdtemp(prefix="emfabric-kernels-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder, False


CACHE_DIR, CACHE_PERSISTENT = _choose_cache_dir()
"""The folder this process caches its kernels in, and whether it outlives the process."""


def is_compiled(variant: str) -> bool:
    """Whether a process has already compiled (and cached) the step kernels of `variant`."""
    return CACHE_PERSISTENT and (CACHE_DIR / f"compiled-{variant}").exists()


def mark_compiled(variant: str) -> None:
    """Record that the step kernels of `variant` are in the cache."""
    if CACHE_PERSISTENT:
        try:
            (CACHE_DIR / f"compiled-{variant}").touch()
        except OSError:
            pass


def _install_locator() -> None:
    """Put a cache locator for this package's kernels in front of Numba's own."""
    from numba.core import caching

    # CacheImpl is public from Numba 0.62 on (_CacheImpl before)
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl

    class KernelCacheLocator(caching._CacheLocator):
        """Caches the functions defined in emfabric/_kernels/*.py in CACHE_DIR."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno

        def get_cache_path(self):
            return str(CACHE_DIR)

        def get_source_stamp(self):
            # the folder's digest, not the file's mtime: the folder holds one version of every
            # kernel source already, so a file saved again with the same content (an editor,
            # `git checkout` back and forth) keeps its cached kernels instead of dropping them
            # while their cached callers in other files stay
            return CACHE_DIR.name

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if Path(py_file).resolve().parent != KERNEL_DIR:
                return None
            return cls(py_func, py_file)

    impl._locator_classes.insert(0, KernelCacheLocator)


_install_locator()
