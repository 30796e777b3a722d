"""Exit statuses (docs/errors.md, issue 25 item 3): 2 for every input error, 1 for every
runtime failure, 130 for an interrupt; I/O errors as one line, never a traceback."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from emfabric.io.lock import folder_lock

from conftest import run_demo

EXE = [sys.executable, "-m", "emfabric"]
TINY = ["--set=fabric.nodes=[11,11]", "--set=solver.end_time=2e-6", "-q"]


def _cli(*args, **kw):
    return subprocess.run([*EXE, *map(str, args)], capture_output=True, text=True, **kw)


@pytest.fixture(scope="module")
def done_run(tmp_path_factory):
    """A finished tiny run to draw."""
    return run_demo(tmp_path_factory.mktemp("done") / "run",
                    {"fabric.nodes": [11, 11], "solver.end_time": 2e-6})


def _one_error_line(r, *needles):
    """stderr is one `error:` line holding the needles (no traceback)."""
    assert "Traceback" not in r.stderr, r.stderr
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1, r.stderr
    for needle in needles:
        assert needle in errors[0], r.stderr
    return errors[0]


def _blocked(tmp_path):
    """A folder that cannot be created: under a plain file."""
    (tmp_path / "afile").write_text("not a folder")
    return tmp_path / "afile" / "sub"


def test_input_errors_exit_2(tmp_path, done_run):
    cases = {
        "unknown key": (["run", "demo-small", "--set", "fabric.bogus=1", "--out",
                         tmp_path / "a", *TINY], "fabric.bogus"),
        "bad value": (["validate", "demo-small", "--set", "fabric.nodes=[1,1]"],
                      "fabric.nodes"),
        "missing scenario file": (["run", tmp_path / "nope.toml"], "nope.toml"),
        "missing study file": (["sweep", tmp_path / "nope.toml", "--out", tmp_path / "s"],
                               "nope.toml"),
        "missing run folder": (["plot", tmp_path / "no-run"], "no-run"),
        "unknown option": (["run", "demo-small", "--bogus"], "bogus"),
        "option value": (["animate", done_run, "--no-mp4"], "--no-mp4"),
        "figure format": (["field", "demo-small", "--plot", tmp_path / "f.xyz"], ".png"),
        "resume without a checkpoint": (["run", "--resume", tmp_path / "empty"],
                                        "no checkpoint"),
        # --out naming a file: the user's input, for a run and for each study (a study
        # said "cannot write …: File exists", exit 1)
        "run --out a file": (["run", "demo-small", "--out", tmp_path / "afile", *TINY],
                             "afile is a file, not a folder"),
        "sweep --out a file": (["sweep", tmp_path / "s.toml", "--out", tmp_path / "afile"],
                               "afile is a file, not a folder"),
        "ballistic-limit --out a file": (["ballistic-limit", "rupture", "--out",
                                          tmp_path / "afile"], "afile is a file, not a folder"),
    }
    (tmp_path / "empty").mkdir()
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "s.toml").write_text('base = "demo-small"\n[axes]\n"field.B" = [[0, 0, 0]]\n')
    for name, (args, needle) in cases.items():
        r = _cli(*args)
        assert r.returncode == 2, (name, r.stderr)
        assert needle in r.stderr and "Traceback" not in r.stderr, (name, r.stderr)



@pytest.mark.parametrize("args, needle", [
    (["run", "demo-small", "--threads", "x"], "'--threads': 'x': allowed: a whole number ≥ 1"),
    (["run", "demo-small", "--threads", "0"], "'--threads': '0': allowed: a whole number ≥ 1"),
    (["sweep", "s.toml", "--out", "o", "--threads", "-1"], "'--threads': '-1': allowed"),
    (["sweep", "s.toml", "--out", "o", "--workers", "0"], "'--workers': '0': allowed"),
    (["field", "demo-small", "--time", "soon"], "'--time': 'soon': allowed: a finite number"),
    (["ballistic-limit", "rupture", "--out", "o", "--seeds", "-2"], "'--seeds': '-2': allowed"),
])
def test_option_values_are_refused_in_plain_words(args, needle):
    """A bad option value exits 2 naming the option, the value and what is allowed, in plain
    words (issue 25: never pydantic's vocabulary, "Input should be a valid integer")."""
    from typer.testing import CliRunner

    from emfabric.cli import app

    r = CliRunner().invoke(app, args, env={"COLUMNS": "200"})  # one line in the error box
    text = " ".join(r.output.split())
    assert r.exit_code == 2, r.output
    assert needle in text and "Input should" not in text, r.output

def test_unreadable_input_file_exits_2_in_one_line(tmp_path):
    run_dir = tmp_path / "garbage"
    run_dir.mkdir()
    (run_dir / "history.nc").write_text("not netCDF")
    r = _cli("plot", run_dir)
    assert r.returncode == 2
    _one_error_line(r, f"cannot read {run_dir / 'history.nc'}")
    # a netCDF file with nothing in it (what a kill at start-up once left): no KeyError 'time'
    import netCDF4

    (run_dir / "history.nc").unlink()
    netCDF4.Dataset(run_dir / "history.nc", "w").close()
    r = _cli("plot", run_dir)
    assert r.returncode == 2
    _one_error_line(r, "has no variable 'time'")
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe")
    r = _cli("validate", bad)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_folder_in_use_exits_2(tmp_path):
    out = tmp_path / "busy"
    for args in (["run", "demo-small", "--out", out, *TINY], ["run", "--resume", out],
                 ["sweep", tmp_path / "s.toml", "--out", out],
                 ["ballistic-limit", "rupture", "--out", out],
                 ["design-field", "demo-small", "--target-tilt", "0.1", "--by", "1e-4",
                  "--out", out]):
        (tmp_path / "s.toml").write_text('base = "demo-small"\n[axes]\n"field.B" = '
                                         '[[0, 0, 0]]\n')
        with folder_lock(out):
            r = _cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        _one_error_line(r, f"in use by emfabric pid {os.getpid()}")
        assert sorted(p.name for p in out.iterdir()) == [], args  # nothing written


def test_diverging_run_exits_1(tmp_path):
    out = tmp_path / "div"
    r = _cli("run", "demo-small", "--out", out, "--set=fabric.nodes=[11,11]",
             "--set=field.E=[1e12,0,0]", "--set=solver.end_time=2e-5", "-q")
    assert r.returncode == 1, r.stderr
    assert "diverged" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("where", ["read-only folder", "under a file"])
def test_plot_into_a_folder_that_cannot_be_written_exits_1_in_one_line(tmp_path, done_run,
                                                                      where):
    if where == "read-only folder":
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only folders")
        target = tmp_path / "ro"
        target.mkdir()
        target.chmod(0o555)
        why = "Permission denied"
    else:
        target, why = _blocked(tmp_path), "Not a directory"
    try:
        r = _cli("plot", done_run, "--out", target)
    finally:
        if where == "read-only folder":
            target.chmod(0o755)
    assert r.returncode == 1, r.stderr
    line = _one_error_line(r, "cannot write ", why)
    assert str(target) in line and r.stdout == ""


def test_field_plot_and_studies_that_cannot_write_exit_1(tmp_path):
    blocked = _blocked(tmp_path)
    r = _cli("field", "demo-small", "--plot", blocked / "field.png")
    assert r.returncode == 1, r.stderr
    _one_error_line(r, "cannot write ", str(blocked))
    (tmp_path / "s.toml").write_text('base = "demo-small"\n[axes]\n"field.B" = [[0, 0, 0]]\n')
    for args in (["sweep", tmp_path / "s.toml", "--out", blocked],
                 ["ballistic-limit", "rupture", "--out", blocked],
                 ["design-field", "demo-small", "--target-tilt", "0.1", "--by", "1e-4",
                  "--out", blocked]):
        r = _cli(*args)
        assert r.returncode == 1, (args, r.stderr)
        _one_error_line(r, f"cannot write {blocked}: Not a directory")


def test_help_lists_the_exit_statuses():
    r = _cli("--help")
    assert r.returncode == 0 and "Exit status" in r.stdout and "130" in r.stdout


def _status(path) -> str | None:
    """A case file's status, None while it is being written or unreadable."""
    try:
        return json.loads(path.read_text()).get("status")
    except (OSError, ValueError):
        return None


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_interrupted_sweep_prints_one_line_and_no_dask_noise(tmp_path):
    """Ctrl-C at the terminal (SIGINT to the whole process group) while a case runs: exit 130,
    one line saying what is kept and how to go on; no worker tracebacks, no "Port 8787 is
    already in use" (held here on purpose)."""
    pytest.importorskip("dask.distributed")
    study = tmp_path / "s.toml"
    # the second case cannot end early: no projectile (no stop rule), 0.5 s of a sheet at rest
    # (about 800 000 steps, minutes); the first ends at once
    study.write_text('base = "demo-small"\n[set]\n"fabric.nodes" = [11, 11]\n'
                     '"fabric.charge_per_node" = 0.0\n"field.B" = [0, 0, 0]\n'
                     '"projectile.shape" = "none"\n"output.paraview" = false\n'
                     '[axes]\n"solver.end_time" = [2e-6, 0.5]\n')
    port = socket.socket()
    try:
        port.bind(("", 8787))
        port.listen()
    except OSError:
        pass  # in use already: the same test
    # the kernels compiled first (a cold cache keeps the workers compiling for minutes, and
    # a worker finishes its compile before it sees the interrupt: a separate, known latency)
    subprocess.run([*EXE, "run", "demo-small", "--out", str(tmp_path / "warm"), "-q",
                    "--set", "fabric.nodes=[11,11]", "--set", "fabric.charge_per_node=0.0",
                    "--set", "field.B=[0,0,0]", "--set", "projectile.shape=none",
                    "--set", "output.paraview=false", "--set", "solver.end_time=2e-6"],
                   capture_output=True, check=True, timeout=1200)
    out = tmp_path / "out"
    # Ctrl-C as at a terminal: SIGINT's default disposition in the command (a suite started in
    # the background by a non-interactive shell inherits SIGINT ignored, and Python then
    # installs no KeyboardInterrupt handler: the signal would do nothing)
    proc = subprocess.Popen([*EXE, "sweep", str(study), "--out", str(out), "--workers", "2",
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=_default_sigint)
    try:
        deadline = time.monotonic() + 300
        while proc.poll() is None and time.monotonic() < deadline:
            if (out / "cases").is_dir() and any(
                    _status(p) == "complete" for p in (out / "cases").glob("*.json")):
                break  # the first case is finished and kept (not merely started)
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        port.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines == [f"interrupted: 1 of 2 cases finished and kept in {out / 'cases'}; run "
                     f"the same command again to do the rest"], stderr
    assert stdout == "" and not (out / ".emfabric.lock").exists()
    assert json.loads(next((out / "cases").glob("*.json")).read_text())["status"] == "complete"


@pytest.mark.parametrize("command", ["design-field", "ballistic-limit"])
@pytest.mark.parametrize("when, code", [("before any run", 2), ("after runs", 1),
                                        ("interrupted", 130)])
def test_study_search_errors(tmp_path, monkeypatch, command, when, code):
    """A search's error before any run is the input's (2), after runs the study's failure (1);
    Ctrl-C: 130 with one line saying what is kept. (The searches are stand-ins here: the
    real ones run in tests/test_study.py.)"""
    from typer.testing import CliRunner

    import emfabric.studies.ballistic as ballistic
    import emfabric.studies.design as design
    from emfabric.cli import app
    from emfabric.studies.sweep import StudyError

    def search(*args, progress=None, **kwargs):
        if when != "before any run":
            (tmp_path / "out" / "cases").mkdir(parents=True, exist_ok=True)
            (tmp_path / "out" / "cases" / "k.json").write_text("{}")
            progress(1)
        if when == "interrupted":
            raise KeyboardInterrupt
        raise StudyError("no bracket")

    monkeypatch.setattr(design, "design_field", search)
    monkeypatch.setattr(ballistic, "ballistic_limit", search)
    args = {"design-field": ["design-field", "demo-small", "--target-tilt", "0.1", "--by",
                             "1e-4"],
            "ballistic-limit": ["ballistic-limit", "rupture"]}[command]
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "out")])
    assert r.exit_code == code, r.output
    # the scenario's plausibility warning (demo-small's and rupture's charge) may come first
    lines = [line for line in r.output.splitlines()
             if line.strip() and not line.startswith("warning: ")]
    assert len(lines) == 1, r.output
    if code == 130:
        assert lines[0].startswith("interrupted: ") and "1 finished runs are kept" in lines[0]
    else:
        assert lines[0] == "error: no bracket"
    assert not (tmp_path / "out" / ".emfabric.lock").exists()


def test_a_v50_not_found_keeps_v_bl_and_exits_1(tmp_path, monkeypatch):
    """`ballistic-limit --seeds` whose seeded shots never bring both outcomes: the V_BL found
    and every shot are written (ballistic.json, .nc, .png), then exit 1 with the reason on one
    line. (The search is a stand-in returning what studies.ballistic returns then.)"""
    from typer.testing import CliRunner

    import emfabric.studies.ballistic as ballistic
    from emfabric.cli import app

    why = ("V50: every one of the 66 decided seeded shots from 23.7 to 120 m/s perforated, the "
           "deterministic V_BL being 100 m/s; a V50 needs shots of both outcomes")

    def search(*args, progress=None, **kwargs):
        progress(1)
        shots = [{"speed": v, "seed": None, "perforated": int(v > 99.0), "residual_speed":
                  max(v - 99.0, 0.0), "status": "complete", "key": f"k{v}"}
                 for v in (50.0, 98.0, 100.0, 105.0, 110.0, 120.0, 135.0)]
        return {"v_bl": 99.0, "v_bl_bracket": [98.0, 100.0], "tolerance": 2.0,
                "lambert_jonas": {"a": 1.0, "p": 2.0, "v_bl": 99.0, "rms_residual": 0.0},
                "seeds": 2, "v50_error": why, "shots": shots, "runs": len(shots),
                "scenario": "rupture", "non_monotone": []}

    monkeypatch.setattr(ballistic, "ballistic_limit", search)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["ballistic-limit", "rupture", "--seeds", "2", "--out",
                                 str(out)], env={"COLUMNS": "400"})
    assert r.exit_code == 1, r.output
    lines = [line for line in r.output.splitlines()
             if line.strip() and not line.startswith("warning: ")]
    assert lines == [f"error: {why} (V_BL and every shot are in {out})"], r.output
    res = json.loads((out / "ballistic.json").read_text())
    assert res["v_bl"] == 99.0 and "v50" not in res and res["v50_error"] == why
    assert (out / "ballistic.nc").is_file() and (out / "ballistic.png").is_file()
    assert not (out / ".emfabric.lock").exists()
