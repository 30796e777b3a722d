"""Numba kernels: arrays in, arrays written in place. Private; wrapped by the modules above.

Numba's on-disk cache checks only the source file of each cached function, not the files of the
kernels it calls (and may have inlined): after one kernel module changes, a cached caller would
run the old code — silently different numbers, or a crash. So the caches of this package are
keyed on a hash of all kernel sources and dropped together when any of them changes.
"""

import hashlib
from pathlib import Path


def _drop_stale_caches() -> None:
    here = Path(__file__).parent
    digest = hashlib.sha256()
    for src in sorted(here.glob("*.py")):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    cache = here / "__pycache__"
    stamp = cache / "emfabric-kernels.sha256"
    try:
        if stamp.read_text() == digest.hexdigest():
            return
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for old in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            old.unlink(missing_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:  # a read-only installation: Numba then caches elsewhere or not at all
        pass


_drop_stale_caches()
