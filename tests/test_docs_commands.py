"""Every shell command the README and docs/*.md print runs as printed (issue 25, item 7).

The commands are read from the documents themselves: fenced ```bash / ```sh / ```console /
```shell blocks, and indented (4+ spaces) lines that start with `emfabric`, `python` or `pip`;
a line ending in a backslash is joined to the next, `a && b` is two commands, `# ...` is a
comment, and `> FILE` writes the command's stdout to FILE. Each command is one test,
identified as file:line, so a failure names the line of the document to fix.

The commands of one document run in the order the document gives them, in one temporary
working directory (a later command may read what an earlier one wrote: `emfabric new
paper-field > my.toml` and then `emfabric run my.toml`). That directory holds symbolic links to
the repository's scripts/ and benchmarks/ and shrunk copies of studies/*.toml, as a clone's root
would. Run alone (`-k`), a command first replays the ones before it in its document.

`emfabric ...` runs in this process (the command-line app through typer's CliRunner, in the
working directory: no new interpreter per command), with the overrides of SHRINK appended
for the kinds of command that would run for minutes (options given later win, so these replace a
command's own end_time or tolerance). What cannot run in a test is listed in SKIP with the reason;
everything else must exit 0 (or the code in EXIT).
"""

from __future__ import annotations

import functools
import re
import shlex
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_FENCES = {"bash", "sh", "console", "shell"}
COMMAND_WORDS = ("emfabric", "python", "pip")
TIMEOUT = 300  # [s] per command: a shrunk study on a busy 2-core machine takes up to a minute

# --- what the test adds, and why ---------------------------------------------------------------

SMALL_RUN = ["--set", "solver.end_time=2e-6", "--set", "fabric.nodes=[11,11]"]

SHRINK: dict[str, tuple[list[str], str]] = {
    "run": (SMALL_RUN,
            "a full run takes 20 s (paper-field) to 20 min (paper-spin on a loaded machine); "
            "2 µs on an 11 x 11 sheet still builds the model, loads the kernels, steps, writes "
            "history.nc, snapshots, ParaView files, checkpoint and summary (and the figures "
            "with --plot) in a few seconds"),
    "design-field": (["--set", "fabric.nodes=[11,11]", "--tolerance", "0.5"],
                     "each probe is a run to --by; an 11 x 11 sheet and a bracket of 50 % "
                     "keep it to a few rounds of probes (one Dask cluster start)"),
    "ballistic-limit": (["--set", "fabric.nodes=[11,11]", "--set", "solver.end_time=1.5e-3",
                         "--tolerance", "20"],
                        "17-53 shots of 3 ms on 40 x 40 take minutes; on 11 x 11 and 1.5 ms a "
                        "shot takes about a second (shots still in contact then count as not "
                        "perforated within end_time, as documented: V_BL comes out rough, but "
                        "bracket, bisection, the shots above it, the fit and the files all run) "
                        "and a 20 m/s bracket needs few rounds"),
    "sweep": ([],
              "nothing appended: the working directory's studies/*.toml are copies of the "
              "repository's with solver.end_time = 2e-6, fabric.nodes = [11, 11] and every axis "
              "cut to its first two values (see shrink_study)"),
    "script": (["--help"],
               "scripts/ and benchmarks/ run studies and benchmarks for minutes to an hour and "
               "write into docs/img; the test runs SCRIPT --help instead (it imports and parses) "
               "and checks that every --option the document gives is one the script accepts"),
}

SKIP: list[tuple[str, str]] = [
    (r"^pip install\b", "installs packages (needs the network); the tests run in the installed "
                        "environment"),
    (r"^python -m pytest\b", "the test suite itself"),
    (r"^emfabric \S+ (SCENARIO|STUDY\.toml)\b",
     "a synopsis with placeholders (SCENARIO, DIR, X Y Z, [options]), not a command"),
    (r"^emfabric ballistic-limit .*--seeds\b",
     "53-90 runs of 3 ms (2-14 minutes): too long for the suite. Shrunk (11 x 11, 1.5 ms), "
     "every seeded shot gave the same outcome in the first band (0.8-1.2 x a rough V_BL); "
     "the bands that widen until both outcomes are in are tested with a stand-in "
     "(tests/test_study.py::test_seeded_shots_widen_until_both_outcomes_are_in), a V50 not "
     "found in tests/test_exit_codes.py; the same command without --seeds runs above"),
    (r"^emfabric run --resume\b",
     "continues a stopped or killed run: the shrunk runs before it end complete, and a "
     "complete run is refused by design (nothing to resume); resuming is tested in "
     "tests/test_checkpoint.py"),
]

KNOWN_FAILURES: list[tuple[str, str]] = [
]
"""Command (regex) -> why it fails today for a reason outside this file's reach; strict xfail,
so the test says when it starts to pass and the entry can go."""

EXIT: dict[str, int] = {}
"""Command (regex) -> the exit code its document says it gives, where that is not 0."""


# --- extraction -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Command:
    doc: str          # path relative to the repository
    line: int         # 1-based line of the document where the command starts
    text: str         # the command, continuation lines joined, comments kept
    section: str      # the heading it stands under
    part: str = ""    # "#1", "#2" for the sides of `a && b`

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}{self.part}"


def _is_command(text: str) -> bool:
    return text.split(" ", 1)[0] in COMMAND_WORDS


def extract(path: Path) -> list[Command]:
    """The shell commands of one markdown file, in document order."""
    lines = path.read_text(encoding="utf-8").splitlines()
    doc = path.relative_to(ROOT).as_posix()
    out: list[Command] = []
    fence: str | None = None
    section = ""
    i = 0
    while i < len(lines):
        raw = lines[i]
        stripped = raw.strip()
        if stripped.startswith("```"):
            fence = None if fence is not None else (stripped[3:].strip().lower() or "text")
            i += 1
            continue
        if fence is None and raw.startswith("#"):
            section = raw.lstrip("#").strip()
        in_shell = fence in SHELL_FENCES
        indented = fence is None and raw.startswith("    ") and _is_command(stripped)
        if (in_shell and stripped and not stripped.startswith("#")) or indented:
            start = i
            text = stripped.removeprefix("$ ")
            while text.endswith("\\") and i + 1 < len(lines):
                i += 1
                text = text[:-1].rstrip() + " " + lines[i].strip()
            parts = [p.strip() for p in re.split(r"\s&&\s", _strip_comment(text))]
            for k, part in enumerate(parts):
                out.append(Command(doc, start + 1, part, section,
                                   f"#{k + 1}" if len(parts) > 1 else ""))
        i += 1
    return out


def _strip_comment(text: str) -> str:
    """The command without a trailing `# ...` comment (quotes respected)."""
    quote = None
    for j, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (j == 0 or text[j - 1] == " "):
            return text[:j].rstrip()
    return text.strip()


COMMANDS: list[Command] = [c for doc in DOCS for c in extract(doc)]
BY_DOC: dict[str, list[Command]] = {}
for _c in COMMANDS:
    BY_DOC.setdefault(_c.doc, []).append(_c)


# --- what runs --------------------------------------------------------------------------------

@dataclass
class Plan:
    argv: list[str] | None = None     # None: skipped
    reason: str = ""                  # why skipped, or the shrink rules applied
    stdout: str | None = None         # `> FILE`
    rc: int = 0
    script_flags: tuple[str, ...] = ()  # for scripts run as --help: the options to look for


def skip_reason(cmd: Command) -> str | None:
    for pattern, reason in SKIP:
        if re.search(pattern, cmd.text):
            return reason
    return None


def plan(cmd: Command) -> Plan:
    why = skip_reason(cmd)
    if why is not None:
        return Plan(None, why)
    tokens = shlex.split(cmd.text)
    stdout = None
    if ">" in tokens:
        k = tokens.index(">")
        stdout = tokens[k + 1]
        tokens = tokens[:k] + tokens[k + 2:]
    rc = next((code for pattern, code in EXIT.items() if re.search(pattern, cmd.text)), 0)
    if tokens[0] == "python" and len(tokens) > 1 and tokens[1].endswith(".py"):
        flags = tuple(t.split("=")[0] for t in tokens[2:] if t.startswith("--"))
        return Plan([sys.executable, tokens[1], *SHRINK["script"][0]], "script", stdout, rc,
                    flags)
    if tokens[:3] == ["python", "-m", "emfabric"]:
        tokens = ["emfabric", *tokens[3:]]
    assert tokens[0] == "emfabric", f"{cmd.id}: no rule for {cmd.text!r}: add one to SKIP"
    sub = tokens[1] if len(tokens) > 1 else ""
    extra: list[str] = []
    rules = []
    if sub in SHRINK and sub not in ("script",):
        extra += SHRINK[sub][0]
        rules.append(sub)
    return Plan([sys.executable, "-m", "emfabric", *tokens[1:], *extra], ", ".join(rules),
                stdout, rc)


def shrink_study(text: str) -> str:
    """A study file cut to a test's size: tiny runs, two values per axis (SHRINK['sweep'])."""
    study = tomllib.loads(text)
    study.setdefault("set", {}).update({"solver.end_time": 2e-6, "fabric.nodes": [11, 11]})
    for key, values in study.get("axes", {}).items():
        study["axes"][key] = values[:2]
    if "lhs" in study:
        study["lhs"]["samples"] = 2
    return _to_toml(study)


def _to_toml(study: dict) -> str:
    def value(v) -> str:
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{value(k)} = {value(x)}" for k, x in v.items()) + "}"
        return repr(v)

    top = [f"{k} = {value(v)}" for k, v in study.items() if not isinstance(v, dict)]
    tables = [f"[{k}]\n" + "\n".join(f"{value(kk)} = {value(vv)}" for kk, vv in v.items())
              for k, v in study.items() if isinstance(v, dict)]
    return "\n".join(top) + "\n\n" + "\n\n".join(tables) + "\n"


def make_workdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    for name in ("scripts", "benchmarks"):
        (path / name).symlink_to(ROOT / name, target_is_directory=True)
    (path / "studies").mkdir()
    for f in sorted((ROOT / "studies").glob("*.toml")):
        (path / "studies" / f.name).write_text(shrink_study(f.read_text(encoding="utf-8")))
    return path


@functools.cache
def _script_help(argv: tuple[str, ...]) -> subprocess.CompletedProcess:
    """SCRIPT --help, once per script (performance.md names bench.py eleven times)."""
    return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)


def _in_process(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """`emfabric ARGS` run in this process (typer's CliRunner, in cwd): the same command-line
    app as the console script, without a new interpreter that imports the package and loads
    the compiled kernels again for each of the ~50 commands (minutes of the suite). What a
    command changes in the process is put back: Numba's thread count, the signal handlers.
    The console script itself is run as a subprocess by tests/test_cli.py and .ci/run."""
    import contextlib
    import signal

    import numba
    from typer.testing import CliRunner

    from emfabric.cli import app

    threads = numba.get_num_threads()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM,
                                                        signal.SIGHUP)}
    try:
        with contextlib.chdir(cwd):
            res = CliRunner().invoke(app, args, catch_exceptions=True)
    finally:
        numba.set_num_threads(threads)
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    stderr = res.stderr
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        import traceback

        stderr += "".join(traceback.format_exception(res.exception))
    return subprocess.CompletedProcess(["emfabric", *args], res.exit_code, res.stdout, stderr)


def execute(cmd: Command, cwd: Path) -> None:
    """Run one planned command in cwd; fail with its output if it does not do what is said."""
    p = plan(cmd)
    if p.argv is None:
        pytest.skip(p.reason)
    if p.script_flags or p.reason == "script":
        res = _script_help(tuple(p.argv))
    elif p.argv[1:3] == ["-m", "emfabric"]:
        res = _in_process(p.argv[3:], cwd)
    else:
        res = subprocess.run(p.argv, cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT)
    shown = " ".join(shlex.quote(a) for a in p.argv)
    assert res.returncode == p.rc, (
        f"{cmd.id}: `{cmd.text}` exited {res.returncode} (expected {p.rc})\n"
        f"ran: {shown}\nstderr:\n{res.stderr[-3000:]}\nstdout:\n{res.stdout[-1500:]}")
    if p.stdout is not None:
        (cwd / p.stdout).write_text(res.stdout)
    missing = [f for f in p.script_flags if f not in res.stdout]
    assert not missing, f"{cmd.id}: `{cmd.text}`: {missing} not in the script's --help"


class _Docs:
    """One working directory per document; the commands before a given one run first."""

    def __init__(self, base: Path):
        self.base = base
        self.dirs: dict[str, Path] = {}
        self.outcome: dict[Command, BaseException | None] = {}

    def workdir(self, doc: str) -> Path:
        if doc not in self.dirs:
            self.dirs[doc] = make_workdir(self.base / doc.replace("/", "_"))
        return self.dirs[doc]

    def run(self, cmd: Command) -> None:
        """Run cmd once (the earlier commands of its document first, if they have not run);
        a second call repeats the first call's outcome without running it again."""
        for c in BY_DOC[cmd.doc][:BY_DOC[cmd.doc].index(cmd) + 1]:
            if c not in self.outcome:
                try:
                    execute(c, self.workdir(c.doc))
                    self.outcome[c] = None
                except (AssertionError, subprocess.TimeoutExpired, pytest.skip.Exception) as e:
                    self.outcome[c] = e
        if self.outcome[cmd] is not None:
            raise self.outcome[cmd]


@pytest.fixture(scope="module")
def docs(tmp_path_factory):
    return _Docs(tmp_path_factory.mktemp("docs-commands"))


# --- the tests --------------------------------------------------------------------------------

def test_readme_quick_start_runs_in_order(docs):
    """README's "Quick start", command by command in a fresh directory (with the shrinking),
    writes what the text after it promises: runs/paper-field/ with history.nc, snapshots.nc,
    ParaView files and figures/. It runs first: the README's per-line tests below continue in
    the same directory (as a reader does) and reuse these commands' outcomes."""
    quick = [c for c in BY_DOC["README.md"] if c.section == "Quick start"]
    assert quick, "README.md has no Quick start commands"
    for cmd in quick:
        if plan(cmd).argv is not None:
            docs.run(cmd)
    run = docs.workdir("README.md") / "runs" / "paper-field"
    for name in ("history.nc", "snapshots.nc", "fabric.pvd", "figures/spin.png"):
        assert (run / name).exists(), f"the quick start did not write runs/paper-field/{name}"


def test_the_documents_hold_commands_and_every_skip_rule_is_used():
    assert len(COMMANDS) > 40, [c.id for c in COMMANDS]
    for pattern, _reason in SKIP:
        assert any(re.search(pattern, c.text) for c in COMMANDS), f"SKIP rule {pattern!r} unused"


def _param(cmd: Command):
    known = [why for pattern, why in KNOWN_FAILURES if re.search(pattern, cmd.text)]
    marks = [pytest.mark.xfail(reason=why, strict=True, raises=AssertionError) for why in known]
    return pytest.param(cmd, id=cmd.id, marks=marks)


@pytest.mark.parametrize("cmd", [_param(c) for c in COMMANDS])
def test_documented_command_runs(cmd, docs):
    docs.run(cmd)


