"""The command-line application object and its output helpers, shared by the command modules
(emfabric.cli: run, validate, scenarios; emfabric.cli.plot: plot, animate), and the exit
statuses every command keeps (docs/errors.md): 0 done, 1 a runtime failure (a diverged or
failed run, an error while writing, a study that found no answer), 2 an input error (a bad
scenario, option or input file, an output folder in use), 130 interrupted."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
"""The exit statuses (docs/errors.md)."""

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="Simulate a rigid projectile striking electromagnetically sensitive fabric.",
    epilog="Exit status: 0 done; 1 a runtime failure (diverged or failed run, write error, "
           "failed study); 2 an input error (bad scenario, option or input file; output "
           "folder in use); 130 interrupted. See docs/errors.md.",
)
console = Console(stderr=True)
"""Messages, progress and the summary table: stderr."""
out_console = Console()
"""Tables meant for reading on stdout (`scenarios`); machine-readable output uses emit()."""


def number(kind: type, minimum: float | None = None):
    """An option's parser: the value as `kind` (int or float), at least `minimum`; a bad
    value is a usage error (exit 2) that says what is allowed, in plain words."""
    import math

    allowed = "a whole number" if kind is int else "a finite number"
    if minimum is not None:
        allowed += f" ≥ {minimum:g}"

    def parse(value):
        if value is None or isinstance(value, bool):
            return value
        try:
            v = kind(value) if not isinstance(value, str) else kind(value.strip())
        except (TypeError, ValueError):
            raise typer.BadParameter(f"{value!r}: allowed: {allowed}") from None
        if (kind is float and not math.isfinite(v)) or (minimum is not None and v < minimum):
            raise typer.BadParameter(f"{value!r}: allowed: {allowed}")
        return v

    return parse


def error(message: str) -> None:
    """An error line on stderr: user text is never read as console markup, and long lines
    are not wrapped (a piped message stays one line)."""
    console.print("[bold red]error:[/] " + escape(str(message)), highlight=False,
                  soft_wrap=True)


def emit(text: str) -> None:
    """Machine-readable output (JSON, file paths, TOML) on stdout, exactly as given."""
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    sys.stdout.flush()


def _version(value: bool) -> None:
    if value:
        from emfabric import __version__

        emit(f"emfabric {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option(
        "--version", callback=_version, is_eager=True, help="Print the version and exit")] = False,
) -> None:
    """Simulate a rigid projectile striking electromagnetically sensitive fabric."""


def show_messages() -> None:
    """Send emfabric's log messages (compiling kernels, incomplete runs, ...) to stderr."""
    import logging

    from rich.logging import RichHandler

    class Prefixed(logging.Formatter):
        """A warning reads "warning: …", as the command's own warnings do (cli.run.warn)."""

        def format(self, record: logging.LogRecord) -> str:
            text = super().format(record)
            return f"warning: {text}" if record.levelno == logging.WARNING else text

    logger = logging.getLogger("emfabric")
    if not any(isinstance(h, RichHandler) for h in logger.handlers):
        handler = RichHandler(console=console, show_time=False, show_path=False,
                              show_level=False, markup=False)
        handler.setFormatter(Prefixed())
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)


def load_or_exit(scenario: str, overrides: list[str] | None):
    """The scenario with its --set overrides, or a clear error and exit status 2."""
    from emfabric.config.scenario import ScenarioError, load_scenario, parse_override

    try:
        pairs = dict(parse_override(o) for o in (overrides or []))
        return load_scenario(scenario, pairs)
    except ScenarioError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    except OSError as err:  # a file that exists but cannot be read (permissions, I/O)
        error(f"cannot read {err.filename or scenario}: {err.strerror or err}")
        raise typer.Exit(EXIT_INPUT) from None


def hold_folder(folder: Path) -> None:
    """Hold the output folder for the rest of the command (emfabric.io.lock): exit 2 with the
    holder named if another emfabric process holds it, exit 1 if it cannot be written. The
    lock is released when the command ends, however it ends. A file where the folder should
    be is the user's input: exit 2."""
    from emfabric.io.lock import FolderInUse, acquire

    if folder.exists() and not folder.is_dir():
        error(f"{folder} is a file, not a folder; allowed: --out a folder (new, empty or one "
              "emfabric wrote)")
        raise typer.Exit(EXIT_INPUT)
    try:
        lock = acquire(folder)
    except FolderInUse as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    except OSError as err:
        error(f"cannot write {folder}: {err.strerror or err}")
        raise typer.Exit(EXIT_FAILED) from None
    ctx = _command_context()
    if ctx is not None:
        ctx.call_on_close(lock.release)
    else:  # pragma: no cover - called outside a command
        import atexit

        atexit.register(lock.release)


def _command_context():
    """The running command's context, closed when the command ends however it ends (typer
    vendors click since 0.2x as typer._click; older ones use click itself)."""
    import importlib

    for name in ("typer._click.globals", "click"):
        try:
            ctx = importlib.import_module(name).get_current_context(silent=True)
        except (ImportError, AttributeError):
            continue
        if ctx is not None:
            return ctx
    return None


def _within(path: Path, roots: tuple[Path, ...]) -> bool:
    """Whether `path` is one of `roots`, inside one, or a folder above one."""
    p = path.resolve()
    for root in roots:
        r = root.resolve()
        if p == r or r in p.parents or p in r.parents:
            return True
    return False


@contextlib.contextmanager
def writing(*outputs: Path) -> Iterator[None]:
    """Operating-system errors in the block as one line, never a traceback: writing one of
    `outputs` (a file or folder, and anything in it) "cannot write X: why", exit 1; any other
    file "cannot read X: why", exit 2; a missing input that emfabric describes itself (a
    FileNotFoundError with a message only), exit 2."""
    try:
        yield
    except OSError as err:
        from emfabric.runner.loop import OutputError, target_of

        if isinstance(err, OutputError):
            error(str(err))
            raise typer.Exit(EXIT_FAILED) from None
        if err.errno is None and not err.filename:
            error(str(err))
            raise typer.Exit(EXIT_INPUT) from None
        why = err.strerror or str(err)
        name = target_of(err.filename) if err.filename else None
        if name is None or _within(name, outputs):
            error(f"cannot write {name or outputs[0]}: {why}")
            raise typer.Exit(EXIT_FAILED) from None
        error(f"cannot read {name}: {why}")
        raise typer.Exit(EXIT_INPUT) from None


_RUN_FILE_HOLDS = {"history.nc": "time", "snapshots.nc": "time"}
"""The variable a run's file has from its first record on (a netCDF file without it, such as an
empty one a crash left, is not one emfabric wrote)."""


def check_readable(*paths: Path) -> None:
    """Exit 2 with one line if one of the netCDF files given (those that exist) cannot be
    opened, or is a run's history.nc or snapshots.nc without its `time`: an input the command
    would otherwise fail on with a library's traceback."""
    import netCDF4

    for path in paths:
        if not path.is_file():
            continue
        needed = _RUN_FILE_HOLDS.get(path.name)
        try:
            with netCDF4.Dataset(path, "r") as nc:
                lacking = needed is not None and needed not in nc.variables
        except (OSError, RuntimeError, ValueError) as err:
            why = getattr(err, "strerror", None) or str(err)
            error(f"cannot read {path}: {why} (not a netCDF file emfabric wrote?)")
            raise typer.Exit(EXIT_INPUT) from None
        if lacking:
            error(f"cannot read {path}: it has no variable '{needed}' (not a run's file "
                  "emfabric wrote, or one cut short before its first record)")
            raise typer.Exit(EXIT_INPUT)
