"""Atomic file writes: write beside the target under a hidden name, then rename over it.

Every file emfabric writes (history, snapshots, ParaView files, figures' movies) goes through
here, so a reader never sees a half-written file and an interrupted write leaves the previous
version (or nothing). The data are flushed to disk (fsync) before the rename, and the file gets
the permissions any new file gets under the user's umask (not mkstemp's owner-only 0600), so
runs can be shared.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

_UMASK: int | None = None


def _file_mode() -> int:
    """0o666 less the process umask (read once: os.umask can only be read by setting it)."""
    global _UMASK
    if _UMASK is None:
        _UMASK = os.umask(0o022)
        os.umask(_UMASK)
    return 0o666 & ~_UMASK


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path` (same suffix, so writers that go by the extension
    work); when the block ends without an exception the file is synced and renamed onto `path`,
    otherwise removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".partial{path.suffix}",
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, _file_mode())
        _fsync(tmp_path)
        os.replace(tmp_path, path)
        if hasattr(os, "O_DIRECTORY"):  # the rename itself, on POSIX
            dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
    finally:
        tmp_path.unlink(missing_ok=True)


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> None:
    """Call writer(tmp_path) and move the result onto `path` in one rename."""
    with atomic_path(path) as tmp:
        writer(tmp)
