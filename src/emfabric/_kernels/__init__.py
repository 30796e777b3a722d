"""Numba kernels: arrays in, arrays written in place. Private; wrapped by the modules above.
Imports nothing of emfabric outside this folder: every other layer may import it.

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

When the folder is chosen
-------------------------
Importing this package touches no file: the folder is chosen (created, marked used, old digests
pruned) the first time Numba asks a kernel for its cache path — when the first kernel module is
imported — or at the first cache_dir(), cache_persistent(), is_compiled() or mark_compiled().
So importing a record type (records.py) or the package from a read-only, sandboxed or
short-lived process does no I/O. ``CACHE_DIR`` and ``CACHE_PERSISTENT`` remain as lazy module
attributes for old callers; new code calls cache_dir() and cache_persistent().

How Numba is told
-----------------
Numba picks a function's cache locator from a private class list
(``numba.core.caching.CacheImpl._locator_classes``); the kernels' locator must be in front of
it before the first kernel module is decorated, i.e. when this package is imported. Numba's
public alternative, NUMBA_CACHE_LOCATOR_CLASSES (``numba.config.CACHE_LOCATOR_CLASSES``),
replaces that list for every cache implementation in the process (other targets' and other
libraries' locators included), and Numba resets it to the environment's value at the next
compile after any NUMBA_* variable changes, so it is no safe substitute. It is used only where
the user has set it, since Numba then ignores the class list: the kernels' locator is put in
front of the user's list, which still decides for all other code.
Both hooks live in install_kernel_locator(), which checks the private names it relies on before
touching them and raises RuntimeError naming the installed Numba version otherwise.
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import inspect
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

KERNEL_DIR = Path(__file__).resolve().parent
UNUSED_DAYS = 30
LOCATOR_PATH = f"{__name__}.KernelCacheLocator"
"""How NUMBA_CACHE_LOCATOR_CLASSES names the kernels' locator (Numba imports it by this path)."""


def source_digest(folder: Path = KERNEL_DIR) -> str:
    """sha256 over the kernel sources in `folder` and the Numba version, first 16 hex digits."""
    import numba

    digest = hashlib.sha256(numba.__version__.encode())
    for src in sorted(folder.glob("*.py")):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    return digest.hexdigest()[:16]


@functools.cache
def _kernel_digest() -> str:
    """source_digest() of this package, read once per process (every kernel asks for it)."""
    return source_digest()


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
    folder = root / f"kernels-{_kernel_digest()}"
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


_chosen: tuple[Path, bool] | None = None
_choosing = threading.Lock()


def cache_location() -> tuple[Path, bool]:
    """(folder, persistent): where this process caches its kernels and whether that outlives
    it. Chosen on the first call (see the module docstring), then fixed for the process."""
    global _chosen
    if _chosen is None:
        with _choosing:  # a kernel imported in a thread, or is_compiled beside it
            if _chosen is None:
                _chosen = _choose_cache_dir()
    return _chosen


def cache_dir() -> Path:
    """The folder this process caches its kernels in (chosen on first use)."""
    return cache_location()[0]


def cache_persistent() -> bool:
    """Whether cache_dir() outlives the process (False: a temporary folder, every run
    compiles)."""
    return cache_location()[1]


def __getattr__(name: str):
    """CACHE_DIR and CACHE_PERSISTENT, computed when first read (PEP 562), so that importing
    the package chooses no folder."""
    if name == "CACHE_DIR":
        return cache_dir()
    if name == "CACHE_PERSISTENT":
        return cache_persistent()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def is_compiled(variant: str) -> bool:
    """Whether a process has already compiled (and cached) the step kernels of `variant`."""
    folder, persistent = cache_location()
    return persistent and (folder / f"compiled-{variant}").exists()


def mark_compiled(variant: str) -> None:
    """Record that the step kernels of `variant` are in the cache."""
    folder, persistent = cache_location()
    if persistent:
        try:
            (folder / f"compiled-{variant}").touch()
        except OSError:
            pass


# ---------------------------------------------------------------------------------------------
# The one place that relies on Numba's private caching names.

LOCATOR_METHODS = ("from_function", "get_cache_path", "get_source_stamp", "get_disambiguator",
                   "ensure_cache_path")
"""What Numba calls on a cache locator (caching.CacheImpl and caching.Cache): the kernels'
locator overrides the first four and inherits ensure_cache_path."""


def check_numba_cache_hooks() -> tuple[type, type]:
    """(locator base class, cache implementation class): the private names of
    numba.core.caching that install_kernel_locator() relies on, checked for the shape it
    expects. RuntimeError, naming the installed Numba version and what is missing, otherwise —
    a Numba release that renames them must fail at import, not silently cache the kernels per
    file (the stale-callee problem of the module docstring)."""
    import numba
    from numba.core import caching

    missing = []
    base = getattr(caching, "_CacheLocator", None)
    if not isinstance(base, type):
        missing.append("the class numba.core.caching._CacheLocator")
    else:
        for method in LOCATOR_METHODS:
            if not callable(getattr(base, method, None)):
                missing.append(f"_CacheLocator.{method}")
        # a new abstract method would make the kernels' locator impossible to instantiate
        abstract = set(getattr(base, "__abstractmethods__", ())) - set(LOCATOR_METHODS[:4])
        if abstract:
            missing.append(f"no abstract _CacheLocator methods beyond the four the kernels' "
                           f"locator overrides (also {', '.join(sorted(abstract))})")
        if callable(getattr(base, "from_function", None)):
            params = list(inspect.signature(base.from_function).parameters)
            if params != ["py_func", "py_file"]:
                missing.append(f"_CacheLocator.from_function(py_func, py_file) (it takes "
                               f"{', '.join(params)})")
    # CacheImpl is public from Numba 0.62 on (_CacheImpl before)
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if not isinstance(impl, type):
        missing.append("the class numba.core.caching.CacheImpl")
    else:
        classes = impl.__dict__.get("_locator_classes")
        if not isinstance(classes, list):
            missing.append(f"the list CacheImpl._locator_classes (found "
                           f"{type(classes).__name__})")
        elif isinstance(base, type) and not all(
                isinstance(c, type) and issubclass(c, base) for c in classes):
            missing.append("_CacheLocator subclasses in CacheImpl._locator_classes")
    if not isinstance(getattr(caching, "CompileResultCacheImpl", None), type):
        missing.append("the class numba.core.caching.CompileResultCacheImpl")
    if missing:
        raise RuntimeError(
            f"emfabric cannot place its compiled kernels with Numba {numba.__version__}: "
            f"missing {'; '.join(missing)}. emfabric's kernel cache (emfabric/_kernels/"
            f"__init__.py) needs updating for this Numba version; until then install a Numba "
            f"release this emfabric was tested with.")
    return base, impl


def _make_locator_class(base: type) -> type:
    """The kernels' cache locator, a subclass of Numba's locator base class `base`."""

    class KernelCacheLocator(base):
        """Caches the functions defined in emfabric/_kernels/*.py in cache_dir()."""

        emfabric_kernels = True  # marks it in Numba's list: installing again replaces it

        def __init__(self, py_func, py_file):
            self._py_file = py_file  # read by Numba for its "cannot cache" warning
            self._lineno = py_func.__code__.co_firstlineno

        def get_cache_path(self):
            # asked by Numba when a kernel is decorated: the first kernel chooses the folder
            return str(cache_dir())

        def get_source_stamp(self):
            # the digest of all kernel sources, not the file's mtime: the folder holds one
            # version of every kernel source already, so a file saved again with the same
            # content (an editor, `git checkout` back and forth) keeps its cached kernels
            # instead of dropping them while their cached callers in other files stay
            return f"kernels-{_kernel_digest()}"

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if Path(py_file).resolve().parent != KERNEL_DIR:
                return None  # not a kernel: Numba's next locator decides
            return cls(py_func, py_file)

    # the path NUMBA_CACHE_LOCATOR_CLASSES imports it by (LOCATOR_PATH), and a plain repr
    KernelCacheLocator.__module__ = __name__
    KernelCacheLocator.__qualname__ = KernelCacheLocator.__name__
    return KernelCacheLocator


def _kernel_file_probe() -> None:
    """A function of a kernel file, for the check that Numba picks the kernels' locator."""


def install_kernel_locator() -> type:
    """Make Numba cache every function of emfabric/_kernels/*.py in cache_dir(); returns the
    locator class. Called once, when this package is imported: before any kernel module is
    decorated (Numba asks for a function's locator at decoration). Touches no file.

    Puts the locator first in Numba's private CacheImpl._locator_classes (checked by
    check_numba_cache_hooks first), replacing one installed before (a reloaded module). Where
    the user has set NUMBA_CACHE_LOCATOR_CLASSES Numba ignores that list, so the locator is put
    in front of the user's setting instead. Then checks that Numba now picks it for a kernel
    file and raises RuntimeError if not."""
    import numba
    from numba.core import caching, config

    base, impl = check_numba_cache_hooks()
    locator = _make_locator_class(base)
    classes = impl._locator_classes
    classes[:] = [c for c in classes if not getattr(c, "emfabric_kernels", False)]
    classes.insert(0, locator)
    setting = getattr(config, "CACHE_LOCATOR_CLASSES", "")
    if setting and LOCATOR_PATH not in [s.strip() for s in setting.split(",")]:
        config.CACHE_LOCATOR_CLASSES = f"{LOCATOR_PATH},{setting}"
    globals()["KernelCacheLocator"] = locator  # the name the setting imports
    picked = caching.CompileResultCacheImpl(_kernel_file_probe).locator
    if not isinstance(picked, locator):
        raise RuntimeError(
            f"emfabric installed its kernel cache locator, but Numba {numba.__version__} picks "
            f"{type(picked).__qualname__} for a kernel file: the kernels would be cached per "
            f"file (stale callees after an edit). emfabric/_kernels/__init__.py needs updating "
            f"for this Numba version.")
    return locator


KernelCacheLocator = install_kernel_locator()
