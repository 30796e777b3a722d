"""An output folder belongs to one run at a time: the lock file ``.emfabric.lock``.

A run (``emfabric.runner.loop.run`` and ``resume``, so the command line and the Python API
alike) and a study command hold their output folder while they write it. The lock is a file
created atomically (``O_CREAT | O_EXCL``: of two processes, exactly one creates it) holding, as
JSON, who holds the folder: process id, host name, start time, the command line, and on Linux
the boot id and the process's start tick (so a pid reused by an unrelated process, or a lock
from before a reboot, is not taken for its holder). It is removed when the holder ends in any
way Python sees (a normal end, an exception, Ctrl-C, SIGTERM or SIGHUP through the command
line's handlers).

A lock whose holder is gone (its pid no longer runs on this host or is a zombie, killed and
not yet reaped by its parent, or the file cannot be read) is stale: the next run takes it
over with a warning in the log. A lock held by a process on another host cannot be checked
from here and is respected.

In one process the lock is re-entrant for the thread that holds it (the command line holds
the folder, then the run it starts takes it again); another thread of the same process is
refused like another process.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import os
import socket
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

LOCK_NAME = ".emfabric.lock"
UNREADABLE_GRACE_S = 2.0
"""An unreadable lock younger than this is being written by its holder this instant: waited
for, not taken over."""

log = logging.getLogger(__name__)


class FolderInUse(RuntimeError):
    """The output folder is held by another live emfabric process (an input error: the
    command line exits with status 2)."""

    def __init__(self, folder: Path, holder: dict) -> None:
        self.folder = folder
        self.holder = holder
        since = str(holder.get("started", "?")).replace("T", " ")
        super().__init__(
            f"output folder {folder} is in use by emfabric pid {holder.get('pid', '?')} on host "
            f"{holder.get('host', '?')} since {since}; allowed: another --out, or wait for it "
            f"to finish (a lock left by a process that died is taken over automatically)")


@dataclass
class _Held:
    count: int
    thread: int
    token: str
    info: dict


_HELD: dict[Path, _Held] = {}
_GUARD = threading.Lock()


def _boot_id() -> str | None:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip() or None
    except OSError:
        return None


def _stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (Linux), or None: [0] the state,
    [19] the start time in clock ticks since boot."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat[stat.rindex(")") + 2:].split()
    except (OSError, ValueError):
        return None


def _start_tick(pid: int) -> int | None:
    """The process's start time in clock ticks since boot (Linux /proc), or None."""
    fields = _stat(pid)
    try:
        return int(fields[19]) if fields is not None else None
    except (ValueError, IndexError):
        return None


def _command() -> str:
    """The command line that took the lock (``python -m emfabric`` shown as ``emfabric``)."""
    if not sys.argv:
        return ""
    name = Path(sys.argv[0]).name
    if name == "__main__.py" or (name == "emfabric" and len(sys.argv) > 1):
        name = "emfabric"
    return " ".join([name, *sys.argv[1:]])


def _identity() -> dict:
    now = _dt.datetime.now().astimezone()
    return {"pid": os.getpid(), "host": socket.gethostname(),
            "started": now.isoformat(timespec="seconds"), "command": _command(),
            "boot_id": _boot_id(), "start_tick": _start_tick(os.getpid()),
            "token": uuid.uuid4().hex}


def _read(path: Path) -> tuple[bytes, dict | None]:
    """The lock file's bytes and its content (None: unreadable); FileNotFoundError if gone."""
    raw = path.read_bytes()
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return raw, None
    if not isinstance(data, dict) or not isinstance(data.get("pid"), int):
        return raw, None
    return raw, data


def holder_alive(holder: dict) -> bool:
    """Whether the process a lock names may still run: False only when that is known (same
    host and the pid is gone, reused, or from before a reboot)."""
    if holder.get("host") != socket.gethostname():
        return True  # another machine's process: cannot be checked from here
    pid = holder["pid"]
    boot = _boot_id()
    if holder.get("boot_id") and boot and holder["boot_id"] != boot:
        return False
    if pid == os.getpid():
        return False  # not in this process's registry (checked before): an earlier process
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # alive, another user's
    except OSError:
        return True
    fields = _stat(pid)
    if fields is not None and fields[0] in ("Z", "X", "x"):
        # a zombie: killed (SIGKILL, the OOM killer), not yet reaped by its parent; it holds
        # nothing any more and never runs again
        return False
    tick = holder.get("start_tick")
    now = _start_tick(pid)
    return not (tick is not None and now is not None and tick != now)


def _steal(path: Path, raw: bytes) -> bool:
    """Remove the stale lock whose bytes are `raw`; False if it changed meanwhile (another
    process took it over first: the caller looks again)."""
    aside = path.with_name(f"{LOCK_NAME}.{os.getpid()}.{uuid.uuid4().hex[:8]}.stale")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return False
    try:
        if aside.read_bytes() != raw:  # a fresh lock of another process: put it back
            with contextlib.suppress(OSError):
                os.link(aside, path)
            return False
        return True
    finally:
        aside.unlink(missing_ok=True)


def _create(path: Path, info: dict) -> bool:
    """Create the lock file with `info`; False if it exists."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    try:
        data = json.dumps(info, indent=1).encode("utf-8")
        while data:
            data = data[os.write(fd, data):]
    except BaseException:
        os.close(fd)
        path.unlink(missing_ok=True)
        raise
    os.close(fd)
    return True


def _take(folder: Path) -> dict:
    path = folder / LOCK_NAME
    info = _identity()
    deadline = time.monotonic() + 10.0
    while True:
        try:
            if _create(path, info):
                return info
        except OSError as err:  # a folder that cannot be written: say which
            raise OSError(err.errno, err.strerror, str(folder)) from None
        try:
            raw, holder = _read(path)
            age = time.time() - path.stat().st_mtime
        except FileNotFoundError:
            continue  # released meanwhile
        except OSError:
            raw, holder, age = b"", None, UNREADABLE_GRACE_S
        if holder is None:
            if age < UNREADABLE_GRACE_S and time.monotonic() < deadline:
                time.sleep(0.05)  # its holder is writing it
                continue
            why = "its lock file cannot be read"
        elif holder_alive(holder):
            raise FolderInUse(folder, holder)
        else:
            why = (f"emfabric pid {holder['pid']} on this host, which took it at "
                   f"{holder.get('started', '?')}, no longer runs")
        if _steal(path, raw):
            log.warning("output folder %s: taking over a stale lock (%s)", folder, why)
        elif time.monotonic() > deadline:
            raise FolderInUse(folder, holder or {})


@dataclass
class FolderLock:
    """A held output folder (see the module docstring); release() once."""

    folder: Path
    key: Path
    token: str
    released: bool = False

    def release(self) -> None:
        if self.released:
            return
        self.released = True
        with _GUARD:
            held = _HELD.get(self.key)
            if held is None or held.token != self.token:
                return
            held.count -= 1
            if held.count > 0:
                return
            del _HELD[self.key]
            path = self.folder / LOCK_NAME
            try:
                _raw, data = _read(path)
            except OSError:
                return
            if data is not None and data.get("token") == self.token:
                path.unlink(missing_ok=True)


def acquire(folder: str | Path) -> FolderLock:
    """Hold `folder` (created if missing) for this process: FolderInUse if another live
    process holds it; OSError (naming the folder) if it cannot be written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    key = folder.resolve()
    with _GUARD:
        held = _HELD.get(key)
        if held is not None:
            if held.thread != threading.get_ident():
                raise FolderInUse(folder, held.info)
            held.count += 1
            return FolderLock(folder, key, held.token)
        info = _take(folder)
        _HELD[key] = _Held(1, threading.get_ident(), info["token"], info)
        return FolderLock(folder, key, info["token"])


@contextlib.contextmanager
def folder_lock(folder: str | Path) -> Iterator[FolderLock]:
    """Hold `folder` while the block runs (acquire; released at any exit)."""
    lock = acquire(folder)
    try:
        yield lock
    finally:
        lock.release()


def holder(folder: str | Path) -> dict | None:
    """Who holds `folder` (the lock's content), or None if nobody does (no lock, or a stale
    one)."""
    path = Path(folder) / LOCK_NAME
    try:
        _raw, data = _read(path)
    except OSError:
        return None
    if data is None:
        return None
    key = Path(folder).resolve()
    with _GUARD:
        if key in _HELD and _HELD[key].token == data.get("token"):
            return data
    return data if holder_alive(data) else None


def drop_foreign(folder: str | Path) -> None:
    """Remove a lock that a process on another host left in `folder` (a study case that Dask
    reruns elsewhere after its worker was lost: the case's folder is the study's to give)."""
    path = Path(folder) / LOCK_NAME
    try:
        raw, data = _read(path)
    except OSError:
        return
    if data is not None and data.get("host") != socket.gethostname() and _steal(path, raw):
        log.warning("output folder %s: taking over the lock of emfabric pid %s on host %s "
                    "(the case is run again here)", folder, data.get("pid"), data.get("host"))
