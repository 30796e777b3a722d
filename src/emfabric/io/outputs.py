"""The files a run writes into its folder: whether a folder holds a run, and clearing one."""

from __future__ import annotations

import shutil
from pathlib import Path

RUN_FILES = ("history.nc", "snapshots.nc", "checkpoint.nc", "fabric.pvd", "projectile.pvd")
"""Files of a run (emfabric.runner.loop)."""
RUN_FOLDERS = ("vtk", "figures")
"""Folders of a run: ParaView pieces, and the figures `plot` draws."""


def run_in(folder: Path) -> str | None:
    """A description of the run the folder holds ("scenario 'x', status"), or None."""
    if not any((folder / name).exists() for name in RUN_FILES):
        return None
    from emfabric.io.history import history_status

    status = history_status(folder / "history.nc")
    if status is None:
        return "a run whose history.nc cannot be read"
    return f"scenario {status[2]!r}, {status[0]}"


def clear_run(folder: Path) -> None:
    """Remove the files and folders of a previous run (nothing else in the folder)."""
    for name in RUN_FILES:
        (folder / name).unlink(missing_ok=True)
    for name in RUN_FOLDERS:
        shutil.rmtree(folder / name, ignore_errors=True)
