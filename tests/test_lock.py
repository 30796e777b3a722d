"""An output folder belongs to one run at a time (issue 25 item 1): the lock file, refused
second runs (exit 2 naming the holder), stale locks taken over, the lock gone at any end."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading

import pytest

from emfabric.config.scenario import load_scenario
from emfabric.integrators import DivergenceError
from emfabric.io.lock import LOCK_NAME, FolderInUse, acquire, folder_lock, holder
from emfabric.runner.loop import resume, run

from conftest import interrupted_demo, run_demo

TINY = {"fabric.nodes": [11, 11], "solver.end_time": 2e-6}


def _dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _hold_elsewhere(folder):
    """Another process holding `folder`: (Popen, its pid); kill it to end the hold."""
    code = ("import sys, time\nfrom emfabric.io.lock import acquire\nacquire(sys.argv[1])\n"
            "print('held', flush=True)\ntime.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder)], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_run_into_a_held_folder_exits_2_naming_the_holder(tmp_path):
    """The command line refuses a folder another process holds before writing anything:
    exit 2, one line naming the holder's pid and host and what is allowed."""
    out = tmp_path / "x"
    with folder_lock(out):
        r = subprocess.run([sys.executable, "-m", "emfabric", "run", "demo-small", "--out",
                            str(out), "-q", *(f"--set={k}={json.dumps(v)}" for k, v in
                                              TINY.items())],
                           capture_output=True, text=True)
        assert (out / LOCK_NAME).is_file()
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert f"output folder {out} is in use by emfabric pid {os.getpid()} on host " \
           f"{socket.gethostname()} since " in lines[0]
    assert "allowed: another --out, or wait for it to finish" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == []  # nothing written, lock released


def test_the_api_is_refused_too_and_takes_over_when_the_holder_died(tmp_path, caplog):
    """emfabric.run into a folder another live process holds: FolderInUse naming it; once that
    process is killed (SIGKILL: no clean-up), the next run takes the stale lock over with a
    warning and the lock is gone after it."""
    out = tmp_path / "x"
    proc = _hold_elsewhere(out)
    try:
        with pytest.raises(FolderInUse, match=f"pid {proc.pid} on host"):
            run_demo(out, TINY)
        assert not (out / "history.nc").exists()
        assert holder(out)["pid"] == proc.pid
    finally:
        proc.kill()
        proc.wait()
    assert holder(out) is None  # stale: the pid no longer runs
    with caplog.at_level("WARNING", logger="emfabric.io.lock"):
        run_demo(out, TINY)
    assert f"pid {proc.pid} on this host" in caplog.text and "stale lock" in caplog.text
    assert (out / "history.nc").is_file() and not (out / LOCK_NAME).exists()


def test_a_holder_killed_and_not_yet_reaped_is_stale(tmp_path, caplog):
    """A holder killed with SIGKILL whose parent has not reaped it yet is a zombie: its pid
    still answers kill(pid, 0), but it holds nothing and never runs again. The next run takes
    the lock over (found by an audit: a resume right after `kill -9` was refused about one time
    in six, while the shell had not yet reaped the killed run)."""
    if not os.path.exists("/proc/self/stat"):
        pytest.skip("process states are read from Linux /proc")
    out = tmp_path / "x"
    proc = _hold_elsewhere(out)
    try:
        proc.send_signal(signal.SIGKILL)
        for _ in range(200):  # until the kernel has made it a zombie (not reaped: no wait())
            with open(f"/proc/{proc.pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    break
            threading.Event().wait(0.01)
        else:
            pytest.fail("the killed holder did not become a zombie")
        assert holder(out) is None
        with caplog.at_level("WARNING", logger="emfabric.io.lock"):
            with folder_lock(out):
                assert json.loads((out / LOCK_NAME).read_text())["pid"] == os.getpid()
        assert "taking over a stale lock" in caplog.text
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("content", ["dead pid", "unreadable", "pid reused"])
def test_stale_locks_are_taken_over(tmp_path, caplog, content):
    if content == "pid reused" and not os.path.exists("/proc/self/stat"):
        pytest.skip("process start times are read from Linux /proc")
    out = tmp_path / "x"
    out.mkdir()
    lock = out / LOCK_NAME
    if content == "dead pid":
        lock.write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname(),
                                    "started": "2025-01-01T00:00:00+00:00"}))
    elif content == "unreadable":
        lock.write_text("{not json")
        os.utime(lock, (1e9, 1e9))  # old: not a lock being written this instant
    else:  # a live pid (this process's parent) that started at another tick than recorded
        lock.write_text(json.dumps({"pid": os.getppid(), "host": socket.gethostname(),
                                    "start_tick": -1, "started": "x"}))
    with caplog.at_level("WARNING", logger="emfabric.io.lock"):
        with folder_lock(out):
            assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert "taking over a stale lock" in caplog.text
    assert not lock.exists()


def test_a_lock_taken_on_another_host_is_respected(tmp_path):
    out = tmp_path / "x"
    out.mkdir()
    (out / LOCK_NAME).write_text(json.dumps({"pid": 1, "host": "elsewhere.example",
                                             "started": "2025-01-01T00:00:00+00:00"}))
    with pytest.raises(FolderInUse, match="pid 1 on host elsewhere.example since 2025-01-01"):
        acquire(out)


def test_lock_is_gone_after_a_normal_end_an_exception_and_ctrl_c(tmp_path):
    done = run_demo(tmp_path / "ok", TINY)
    assert (done / "history.nc").is_file() and not (done / LOCK_NAME).exists()

    def boom(state, info):
        raise ValueError("a bug in a progress callback")

    with pytest.raises(ValueError):
        run_demo(tmp_path / "exc", TINY, progress=boom)
    assert not (tmp_path / "exc" / LOCK_NAME).exists()

    with pytest.raises(DivergenceError):
        run_demo(tmp_path / "div", {**TINY, "field.E": [1e12, 0.0, 0.0],
                                    "solver.end_time": 20e-6})
    assert not (tmp_path / "div" / LOCK_NAME).exists()

    stopped = interrupted_demo(tmp_path / "int", {**TINY, "solver.end_time": 1e-4}, after=3)
    assert not (stopped / LOCK_NAME).exists()
    seen = []

    def look(state, info):  # a resumed run holds the folder while it goes
        seen.append(holder(stopped))

    resume(stopped, progress=look)
    assert seen and all(h is not None and h["pid"] == os.getpid() for h in seen)
    assert not (stopped / LOCK_NAME).exists()


def test_resume_into_a_held_folder_is_refused(tmp_path):
    out = interrupted_demo(tmp_path / "x", {**TINY, "solver.end_time": 1e-4}, after=3)
    proc = _hold_elsewhere(out)
    try:
        with pytest.raises(FolderInUse, match=f"pid {proc.pid}"):
            resume(out)
    finally:
        proc.kill()
        proc.wait()


def test_reentrant_in_a_thread_refused_in_another(tmp_path):
    """The command line holds the folder and the run it starts takes it again (same thread);
    another thread of the process is refused like another process."""
    out = tmp_path / "x"
    errors = []
    with folder_lock(out):
        with folder_lock(out):
            assert (out / LOCK_NAME).is_file()

        def other():
            try:
                acquire(out)
            except FolderInUse as err:
                errors.append(err)

        t = threading.Thread(target=other)
        t.start()
        t.join()
        assert (out / LOCK_NAME).is_file()  # the inner release kept it
    assert len(errors) == 1 and f"pid {os.getpid()}" in str(errors[0])
    assert not (out / LOCK_NAME).exists()


def test_two_processes_race_for_one_folder(tmp_path):
    """Started together, exactly one of several processes gets the folder."""
    code = ("import sys, time\nfrom emfabric.io.lock import acquire, FolderInUse\n"
            "try:\n    acquire(sys.argv[1])\nexcept FolderInUse:\n    print('refused')\n"
            "else:\n    print('held', flush=True)\n    time.sleep(3)\n")
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "x")],
                              stdout=subprocess.PIPE, text=True) for _ in range(4)]
    said = sorted(p.communicate(timeout=60)[0].strip() for p in procs)
    assert said == ["held", "refused", "refused", "refused"]


def test_sweep_holds_its_folder(tmp_path):
    """A study into a folder another process holds is refused before anything is written (no
    Dask cluster is started)."""
    pytest.importorskip("dask.distributed")
    from emfabric.studies.sweep import load_study, sweep

    (tmp_path / "s.toml").write_text('base = "demo-small"\n[axes]\n"field.B" = [[0, 0, 0]]\n')
    out = tmp_path / "study"
    proc = _hold_elsewhere(out)
    try:
        with pytest.raises(FolderInUse, match=f"pid {proc.pid}"):
            sweep(load_study(tmp_path / "s.toml"), out)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]  # the dead holder's


def test_run_in_a_read_only_folder_names_it(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match=str(out)):
            run(load_scenario("demo-small", TINY), out)
    finally:
        out.chmod(0o755)


def test_a_study_keeping_its_runs_locks_each_case_folder_apart(tmp_path):
    """keep_histories: each case's run holds its own runs/<key>/ on its worker while the study
    holds the top folder; the cases run side by side and every lock is gone at the end."""
    pytest.importorskip("dask.distributed")
    from emfabric.studies.sweep import load_study, sweep

    (tmp_path / "s.toml").write_text(
        'base = "demo-small"\nkeep_histories = true\n[set]\n"fabric.nodes" = [11, 11]\n'
        '"solver.end_time" = 2e-6\n[axes]\n"field.B" = [[0, 0, 0], [0.05, 0, 0]]\n')
    out = tmp_path / "study"
    outcome = sweep(load_study(tmp_path / "s.toml"), out, workers=2)
    assert outcome.ran == 2 and outcome.failed == 0
    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 2 and all((r / "history.nc").is_file() for r in runs)
    assert not list(out.rglob(LOCK_NAME))
