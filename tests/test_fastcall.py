"""fastcall.Direct: a kernel's compiled entry point is called only with arguments of the types
it was compiled for; anything else goes through Numba's dispatcher (a new specialisation, or
Numba's TypingError), never into the entry point, which would read the arguments as the old
types (a segfault for another ndim, wrong numbers for another layout)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from typing import NamedTuple

import numba
import numpy as np
import pytest
from numba.core.errors import TypingError

from emfabric.sim.fastcall import Direct, type_spec


@numba.njit
def weighted(x, w, k):
    """Σ x_i w_i k: a kernel cheap to compile for each new type."""
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] * w[i]
    return s * k


class Pair(NamedTuple):
    x: np.ndarray
    w: np.ndarray


@numba.njit
def weighted_pair(p, k):
    return weighted(p.x, p.w, k)


def _same(a, b) -> bool:
    """Bit for bit."""
    return np.asarray(a).tobytes() == np.asarray(b).tobytes()


def _outcome(call, *args):
    """The result's bytes, or the exception's type."""
    try:
        return np.asarray(call(*args)).tobytes()
    except Exception as err:  # noqa: BLE001 - compared, not handled
        return type(err)


X = np.linspace(0.1, 2.0, 50)
W = np.cos(np.arange(50.0))


def test_repeated_calls_take_the_entry_point():
    direct = Direct(weighted)
    for _ in range(5):
        assert _same(direct(None, X, W, 3), weighted(X, W, 3))
    assert direct.dispatched == 1
    sig = tuple(numba.typeof(a) for a in (X, W, 3))
    assert direct.entries[None][0].call is weighted.overloads[sig].entry_point


@pytest.mark.parametrize("case", ["float32", "view", "readonly", "fortran", "float for int",
                                  "bool for int", "int beyond int64"])
def test_another_type_is_dispatched_with_the_dispatchers_numbers(case):
    """A float32 array where float64 was compiled, a strided view or a read-only array where a
    contiguous writable one was, a float or bool where an int was, an int that Numba types
    uint64: each runs the dispatcher's specialisation for it (the entry point would misread
    it), and the old types still take the old entry point."""
    x, w, k = X, W, 3
    if case == "float32":
        x = X.astype(np.float32)
    elif case == "view":
        x = np.linspace(0.1, 2.0, 100)[::2]
    elif case == "readonly":
        x = X.copy()
        x.flags.writeable = False
    elif case == "fortran":
        x, w = np.asfortranarray(np.stack([X, X]))[0], W  # 1-D, not contiguous
    elif case == "float for int":
        k = 3.5
    elif case == "bool for int":
        k = True
    else:
        k = 2**63 + 1
    direct = Direct(weighted)
    direct(None, X, W, 3)
    for _ in range(2):
        # (for an int beyond int64 the dispatcher raises OverflowError: so must Direct)
        assert _outcome(direct, None, x, w, k) == _outcome(weighted, x, w, k)
        assert direct.dispatched == 2 or case == "int beyond int64"
        assert _same(direct(None, X, W, 3), weighted(X, W, 3))


def test_none_where_an_array_was_raises_numbas_typing_error():
    direct = Direct(weighted)
    direct(None, X, W, 3)
    with pytest.raises(TypingError):
        direct(None, None, W, 3)
    assert _same(direct(None, X, W, 3), weighted(X, W, 3))


def test_records_match_by_identity_or_by_their_arrays():
    """The same record, or a record built afresh of the same arrays (as StateArrays is per
    call), takes the entry point; a record holding an array of another type does not."""
    direct = Direct(weighted_pair)
    pair = Pair(X, W)
    direct(None, pair, 2)
    for _ in range(3):
        assert _same(direct(None, pair, 2), weighted_pair(pair, 2))
        assert _same(direct(None, Pair(X, W), 2), weighted_pair(pair, 2))
    fresh = Pair(X.copy(), W.copy())  # new arrays of the same types: checked, then known
    assert _same(direct(None, fresh, 2), weighted_pair(fresh, 2))
    assert direct.dispatched == 1
    other = Pair(X.astype(np.float32), W)
    assert _same(direct(None, other, 2), weighted_pair(other, 2))
    assert direct.dispatched == 2
    bad = Pair(X[:, None], W)  # another ndim inside the record
    with pytest.raises(TypingError):
        direct(None, bad, 2)


def test_arguments_that_change_every_call_are_still_checked():
    """Past a few new objects at one position (a view taken per call), every call compares
    what Numba reads of it; a wrong one is still refused."""
    base = np.linspace(0.1, 2.0, 200)
    direct = Direct(weighted)
    for start in range(10):
        x = base[start:start + 50]
        assert _same(direct(None, x, W, 3), weighted(x, W, 3))
    assert direct.dispatched == 1
    bad = np.linspace(0.1, 2.0, 400).reshape(4, 100)[0, ::2]  # a strided view
    assert _same(direct(None, bad, W, 3), weighted(bad, W, 3))
    assert direct.dispatched == 2


class Scalars(NamedTuple):
    t: float
    n: int
    ok: bool


@numba.njit
def scaled(x, s):
    return weighted(x, x, s.t * s.n) if s.ok else 0.0


def test_a_tuple_of_numbers_built_per_call_is_checked_inline():
    """A record of scalars rebuilt every call (the step's statistics) is matched by its class
    and its elements' types in the generated check, not by type_spec on every call; a float
    where the int was, an int beyond int64 or another class still go to the dispatcher."""
    direct = Direct(scaled)
    for k in range(8):
        s = Scalars(0.5 + k, 3 + k, True)
        assert _same(direct(None, X, s), scaled(X, s))
    assert direct.dispatched == 1
    (entry,) = direct.entries[None]
    assert "type_spec" not in entry.accepts.__code__.co_names
    assert not entry.accepts((X, Scalars(0.5, 3.0, True)))
    assert not entry.accepts((X, Scalars(0.5, 2**63, True)))
    assert not entry.accepts((X, (0.5, 3, True)))
    assert not entry.accepts((X, Scalars(0.5, 3, 1)))
    assert entry.accepts((X, Scalars(1e300, -(2**63), False)))
    # the dispatcher's own answer for the refused ones (a new specialisation or its error)
    for s in (Scalars(0.5, 3.0, True), (0.5, 3, True)):
        assert _outcome(direct, None, X, s) == _outcome(scaled, X, s)


VALUES = [X, X.astype(np.float32), X[::2], X.reshape(5, 10), np.asfortranarray(X.reshape(5, 10)),
          X.reshape(5, 10)[:, ::2], np.zeros(3, dtype=np.int64), np.zeros((1, 3)),
          np.zeros((3, 1)), 1.0, 2, True, None, 1j, np.float32(1.0), np.int64(3),
          (X, 1.0), (X[::2], 1.0), Pair(X, W), Pair(W, X), Pair(X, X.astype(np.float32))]


def test_type_spec_tells_what_numba_typeof_tells():
    """Equal specs only for equal Numba types (the spec may tell more: never less)."""
    ro = X.copy()
    ro.flags.writeable = False
    values = VALUES + [ro]
    for a in values:
        for b in values:
            if type_spec(a) == type_spec(b):
                assert numba.typeof(a) == numba.typeof(b), (a, b)
    assert type_spec(2**63) is None
    assert type_spec([1.0]) is None
    assert type_spec(np.datetime64("2020-01-01")) is None


REAL_KERNEL = textwrap.dedent("""
    import numpy as np
    from numba.core.errors import TypingError

    import emfabric
    from emfabric._kernels.diagnostics import COUNT, fabric_diagnostics
    from emfabric.sim.fastcall import Direct
    from emfabric.sim.state import initial_state

    model = emfabric.build_model(emfabric.load_scenario("demo-small"))
    s = initial_state(model)
    args = [model.physics, s.node_x, s.node_v, s.seg_alpha, s.body_x, model.flight_direction]
    direct = Direct(fabric_diagnostics)
    direct(None, *args, np.empty(COUNT))

    def run(call, args):
        out = np.full(COUNT, np.nan)
        try:
            call(*args, out)
        except TypingError:
            return "TypingError"
        return out.tobytes()

    for case, i, value in [("ndim", 2, np.ascontiguousarray(s.node_v.T)[None]),
                           ("float32", 2, s.node_v.astype(np.float32)),
                           ("None", 3, None)]:
        wrong = list(args)
        wrong[i] = value
        expected = run(fabric_diagnostics, wrong)
        got = run(lambda *a: direct(None, *a), wrong)
        print(case, "same" if got == expected else "DIFFERENT",
              "TypingError" if expected == "TypingError" else "result", flush=True)
""")


def test_wrong_arguments_to_a_real_kernel_never_reach_its_entry_point():
    """fabric_diagnostics given an array of another ndim (the entry point reads it with the
    wrong shape: garbage or a segfault), a float32 array where float64 was compiled, None where
    an array was: the same outcome as the plain dispatcher (its numbers or its TypingError).
    In a subprocess, so that a segfault fails this test instead of ending pytest."""
    done = subprocess.run([sys.executable, "-c", REAL_KERNEL], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    lines = done.stdout.split("\n")
    assert [ln.split()[:2] for ln in lines if ln] == [["ndim", "same"], ["float32", "same"],
                                                       ["None", "same"]], done.stdout


@pytest.fixture(scope="module")
def demo():
    import emfabric
    from emfabric.integrators.phi import Integrator
    from emfabric.sim.state import initial_state

    model = emfabric.build_model(emfabric.load_scenario("demo-small"))
    a = initial_state(model)
    b = a.copy()
    integ = Integrator(model)
    integ.step(a, b)
    return model, integ, a, b


def test_same_numbers_as_the_dispatcher_bit_for_bit(demo):
    """The diagnostics and energy kernels through Direct, the two states alternating as in a
    run, give the plain dispatcher's numbers bit for bit, and dispatch once."""
    from emfabric._kernels.diagnostics import COUNT, fabric_diagnostics
    from emfabric._kernels.energy import step_energy

    model, integ, a, b = demo
    diag, energy = Direct(fabric_diagnostics), Direct(step_energy)
    for s_in, s_out in [(a, b), (b, a), (a, b), (b, a)]:
        got, want = np.empty(COUNT), np.empty(COUNT)
        diag(None, model.physics, s_in.node_x, s_in.node_v, s_in.seg_alpha, s_in.body_x,
             model.flight_direction, got)
        fabric_diagnostics(model.physics, s_in.node_x, s_in.node_v, s_in.seg_alpha,
                           s_in.body_x, model.flight_direction, want)
        assert _same(got, want)
        got, want = s_out.energy.copy(), s_out.energy.copy()
        energy(None, model.physics, s_in.arrays, s_out.arrays, 0, integ.work, s_in.t,
               integ.solver.phi, 1e-7, got)
        step_energy(model.physics, s_in.arrays, s_out.arrays, 0, integ.work, s_in.t,
                    integ.solver.phi, 1e-7, want)
        assert _same(got, want)
    assert diag.dispatched == 1 and energy.dispatched == 1


HANDLED_INTERRUPT = textwrap.dedent("""
    import sys
    import numba, numpy as np
    from emfabric.sim.fastcall import Direct

    @numba.njit
    def total(x):
        return x.sum()

    def tracer(frame, event, arg):
        # a Ctrl-C (SIGHUP, SIGTERM) landing while Direct executes the check it generates:
        # the generated code's module frame, called from fastcall.py
        caller = frame.f_back
        if (event == "call" and frame.f_code.co_name == "<module>" and caller is not None
                and caller.f_code.co_filename.endswith("fastcall.py")):
            print("raised")
            raise KeyboardInterrupt
        return None

    total(np.ones(3))  # compiled before: only Direct's own code runs under the tracer
    direct = Direct(total)
    sys.settrace(tracer)
    try:
        direct(None, np.ones(3))
    except KeyboardInterrupt:
        print("handled")
    sys.settrace(None)
    sys.exit(130)
""")


def test_an_interrupt_handled_inside_a_generated_check_leaves_the_exit_status(tmp_path):
    """A run interrupted while Direct builds its argument check (the first steps: the states
    it learns) handles the KeyboardInterrupt and the command exits 130. Executed from a
    string, that check ran through CPython's PyRun_String path, which marks a KeyboardInterrupt
    raised inside it as unhandled for the whole process, handled or not, and the interpreter
    then ended by SIGINT (-2) under `python -m emfabric`: `python -m emfabric run` given
    SIGHUP exited -2 in about 1 run in 10 (tests/test_guards.py's SIGHUP case, flaky)."""
    (tmp_path / "interrupted.py").write_text(HANDLED_INTERRUPT)
    # as `python -m emfabric` runs (runpy): there the flag decides the exit status
    done = subprocess.run([sys.executable, "-m", "interrupted"], capture_output=True,
                          text=True, timeout=300, cwd=tmp_path)
    assert "raised" in done.stdout and "handled" in done.stdout, done.stderr
    assert done.returncode == 130, done.stderr
