"""The files a run writes into its folder: whether a folder holds a run, and clearing one."""

from __future__ import annotations

import shutil
from pathlib import Path

RUN_FILES = ("history.nc", "snapshots.nc", "checkpoint.nc", "fabric.pvd", "projectile.pvd")
"""Files of a run (emfabric.runner.loop)."""
RUN_FOLDERS = ("vtk", "figures")
"""Folders of a run: ParaView pieces, and the figures `plot` draws."""


def has_run_files(folder: Path) -> bool:
    """Whether the folder holds any file of a run (RUN_FILES)."""
    return any((folder / name).exists() for name in RUN_FILES)


def run_in(folder: Path) -> str | None:
    """A description of the run the folder holds ("scenario 'x', status"), or None: also for
    a run stopped before its first step, whose history holds no record and which has no
    checkpoint (nothing to keep, nothing to resume)."""
    if not has_run_files(folder):
        return None
    from emfabric.io.history import history_records, history_status

    status = history_status(folder / "history.nc")
    if status is None:
        return "a run whose history.nc cannot be read"
    if (status[0] == "partial" and not (folder / "checkpoint.nc").exists()
            and history_records(folder / "history.nc") == 0):
        return None
    return f"scenario {status[2]!r}, {status[0]}"


def clear_run(folder: Path) -> None:
    """Remove the files and folders of a previous run (nothing else in the folder), and the
    temporary files of a write it was killed in (io.atomic: .NAME.*.partial.EXT)."""
    for name in RUN_FILES:
        (folder / name).unlink(missing_ok=True)
        stem, ext = name.rsplit(".", 1)
        for tmp in folder.glob(f".{stem}.*.partial.{ext}"):
            tmp.unlink(missing_ok=True)
    for name in RUN_FOLDERS:
        shutil.rmtree(folder / name, ignore_errors=True)
