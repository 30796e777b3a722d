"""Calling a compiled kernel without Numba's per-call type dispatch — and without trusting it.

A Numba dispatcher types every argument on every call to pick the compiled specialisation; for
the model's records (named tuples of arrays) that is most of the cost of a cheap kernel call
(the step, energy and diagnostics kernels are called every step). ``Direct(kernel)`` calls
through the dispatcher once, then calls the specialisation's compiled entry point directly.
That entry point converts its arguments to the types it was compiled for without checking them:
an array of another ndim is read with the wrong shape (a segfault), one of another layout with
the wrong strides (wrong numbers), a float where an int was is truncated. So every call is first
matched against the arguments the entry point was recorded with, position by position:

* an object seen before at that position (the same Physics, Solver or Work record, the same
  array) matches by identity (``is``);
* a tuple built afresh from objects seen before (StateArrays is rebuilt per call from the same
  arrays, of one state or the other) matches by the identity of its elements;
* a number, bool or None matches by type (an int also by fitting int64, as Numba types it);
* anything else is compared by what numba.typeof reads: for an array its dtype, ndim, C/F
  contiguity and writeability, for a tuple its class and its elements'. An object that passes
  is remembered (a few per position; past that, a position whose objects keep changing — a
  view taken per call, say — is compared this way on every call).

A call that matches no recorded entry goes through the dispatcher — it compiles or loads the
specialisation for the new types, or raises Numba's own TypingError — and its entry point is
recorded beside the others. Arguments whose Numba type the above does not fix (lists, strings,
datetimes, structured arrays, ints beyond int64, ndarray subclasses) always go through the
dispatcher. The numbers are the plain dispatcher's: the same compiled code runs on the same
arguments.

The matching must cost far less than the dispatch it replaces (about 10–15 µs for these kernels,
more for larger records), so each entry compiles its checks into one Python expression (the
technique of collections.namedtuple and dataclasses), regenerated only when it learns an object.

What identity trusts: that an array already seen is not re-typed in place between calls
(``a.shape = ...``, ``a.dtype = ...``, ``a.flags.writeable = ...``, none of which the package
does); an array or record with new properties is a new object, and is checked.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
_SCALARS = frozenset({float, int, bool, complex, type(None)})

# how a position is matched (see the module docstring)
_TYPE, _INT, _SAME, _TUPLE, _SPEC = "type", "int", "same", "tuple", "spec"


def type_spec(a: Any) -> Any:
    """What numba.typeof reads of `a` (equal specs, equal Numba types); None where that is more
    than type(), the array flags and a tuple's elements (then only the dispatcher can tell)."""
    t = type(a)
    if t is np.ndarray:
        if a.dtype.names is not None:  # a record dtype: Numba also reads its alignment
            return None
        f = a.flags
        return a.dtype, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable
    if t in _SCALARS:
        # a Python int is int64 unless it does not fit (then uint64, or no type at all)
        return t if t is not int or INT64_MIN <= a <= INT64_MAX else None
    if issubclass(t, tuple):
        items = tuple(map(type_spec, a))
        return None if any(x is None for x in items) else (t, items)
    if issubclass(t, np.number | np.bool_) and not issubclass(t, np.timedelta64):
        return t
    return None


def _scalar_items(spec: Any) -> tuple | None:
    """The element types of a tuple's spec whose elements are all numbers, bools or None
    (their specs are their types), else None."""
    if (isinstance(spec, tuple) and len(spec) == 2 and isinstance(spec[0], type)
            and issubclass(spec[0], tuple) and isinstance(spec[1], tuple)
            and all(isinstance(x, type) for x in spec[1])):
        return spec[1]
    return None


def _same_items(a: tuple, known: Any) -> bool:
    """Whether tuple `a` is of the class of `known` and holds its very objects."""
    return (type(a) is type(known) and len(a) == len(known)
            and all(x is y for x, y in zip(a, known, strict=True)))


class _Entry:
    """One compiled entry point and what its arguments must be, position by position."""

    SEEN = 4
    """Objects remembered per position (two alternating states need two)."""

    def __init__(self, args: tuple, specs: list, call: Any):
        self.call = call
        self.specs = specs
        self.modes = [_INT if s is int else _TYPE if isinstance(s, type) else _SAME
                      for s in specs]
        # held, so that `is` keeps meaning the object that was checked
        self.known: list[list] = [[a] if m == _SAME else [] for a, m in zip(args, self.modes,
                                                                               strict=True)]
        self.accepts = self._compile()

    def _compile(self):
        """accepts(args) -> bool: the checks of every position as one expression."""
        n = len(self.modes)
        ns: dict[str, Any] = {"type_spec": type_spec}
        terms = []
        for i, (mode, spec, known) in enumerate(zip(self.modes, self.specs, self.known,
                                                    strict=True)):
            a = f"a{i}"
            if mode == _TYPE:
                ns[f"s{i}"] = spec
                terms.append(f"type({a}) is s{i}")
            elif mode == _INT:
                terms.append(f"(type({a}) is int and {INT64_MIN} <= {a} <= {INT64_MAX})")
            elif mode == _SAME:
                ns.update((f"k{i}_{j}", k) for j, k in enumerate(known))
                terms.append("(" + " or ".join(f"{a} is k{i}_{j}" for j in range(len(known)))
                             + ")")
            elif mode == _TUPLE:
                ns[f"c{i}"] = type(known[0])
                size = len(known[0])
                alts = []
                for j, k in enumerate(known):
                    ns.update((f"k{i}_{j}_{m}", x) for m, x in enumerate(k))
                    alts.append("(" + " and ".join([f"{a}[{m}] is k{i}_{j}_{m}"
                                                    for m in range(size)] or ["True"]) + ")")
                terms.append(f"(type({a}) is c{i} and len({a}) == {size} and "
                             f"({' or '.join(alts)}))")
            elif _scalar_items(spec) is not None:
                # a tuple of numbers rebuilt per call (a record of the step's scalars): the
                # class and each element's type, as type_spec would compare them, inline
                items = _scalar_items(spec)
                ns[f"c{i}"] = spec[0]
                checks = [f"type({a}) is c{i}", f"len({a}) == {len(items)}"]
                for m, t in enumerate(items):
                    if t is int:
                        checks.append(f"(type({a}[{m}]) is int and "
                                      f"{INT64_MIN} <= {a}[{m}] <= {INT64_MAX})")
                    else:
                        ns[f"t{i}_{m}"] = t
                        checks.append(f"type({a}[{m}]) is t{i}_{m}")
                terms.append("(" + " and ".join(checks) + ")")
            else:
                ns[f"s{i}"] = spec
                terms.append(f"type_spec({a}) == s{i}")
        unpack = f"    {', '.join(f'a{i}' for i in range(n))}, = args\n" if n else ""
        src = (f"def accepts(args):\n    if len(args) != {n}:\n        return False\n{unpack}"
               f"    return {' and '.join(terms) or 'True'}\n")
        # the source holds position numbers and names only, no values. Compiled first: exec
        # of a string runs it through CPython's PyRun_String path, which records a
        # KeyboardInterrupt that lands inside it as unhandled for the whole process even when
        # the run then handles it, and the interpreter then exits by SIGINT (-2) instead of
        # the command's 130 (a SIGHUP around a run's second step did, 1 run in 10); exec of a
        # code object does not
        exec(compile(src, "<emfabric.sim.fastcall>", "exec"), ns)
        return ns["accepts"]

    def _matches(self, i: int, a: Any) -> bool:
        """The check of position i, as accepts() has it."""
        mode, spec, known = self.modes[i], self.specs[i], self.known[i]
        if mode == _TYPE:
            return type(a) is spec
        if mode == _INT:
            return type(a) is int and INT64_MIN <= a <= INT64_MAX
        if mode == _SAME:
            return any(a is k for k in known)
        if mode == _TUPLE:
            return any(_same_items(a, k) for k in known)
        return type_spec(a) == spec

    def admit(self, args: tuple) -> bool:
        """Whether `args`, which accepts() refused, match this entry after all: a position holds
        an object not seen before, of the same Numba type. The new objects are remembered."""
        if len(args) != len(self.modes):
            return False
        new = []
        for i, a in enumerate(args):
            if self._matches(i, a):
                continue
            if self.modes[i] not in (_SAME, _TUPLE):
                return False  # a type, an int or a compared spec: no other object can match
            if not (isinstance(a, tuple) and any(_same_items(a, k) for k in self.known[i])):
                if type_spec(a) != self.specs[i]:
                    return False
            new.append((i, a))
        for i, a in new:
            self._learn(i, a)
        self.accepts = self._compile()
        return True

    def _learn(self, i: int, a: Any) -> None:
        """Remember the object `a` that matched position i: by identity while few objects come
        there; a tuple built afresh from known objects by those objects; past SEEN objects by
        what Numba would read of it, on every call."""
        known = self.known[i]
        if isinstance(a, tuple) and any(_same_items(a, k) for k in known):
            if self.modes[i] == _SAME:  # rebuilt per call: one tuple per set of objects
                self.modes[i] = _TUPLE
                known[:] = [k for j, k in enumerate(known)
                            if not any(_same_items(k, u) for u in known[:j])]
        elif len(known) < self.SEEN:
            known.append(a)
        else:
            self.modes[i] = _SPEC
            known.clear()


class Direct:
    """`kernel(*args)` through the compiled entry point of the matching specialisation.

    ``direct(key, *args)``: `key` names the caller's kind of call (serial or threaded step,
    say) and only groups the recorded entry points, so that a key's own are tried first; the
    arguments are checked whatever the key (see the module docstring)."""

    ENTRIES = 8
    """Entry points kept per key (a new one beyond drops the oldest)."""

    def __init__(self, kernel: Any):
        self.kernel = kernel
        self.entries: dict[Any, list[_Entry]] = {}
        self.dispatched = 0
        """Calls that went through the dispatcher (the first, and each new kind of argument)."""

    def __call__(self, key: Any, *args: Any) -> Any:
        entries = self.entries.get(key)
        if entries:
            for entry in entries:
                if entry.accepts(args):
                    return entry.call(*args)
            for entry in entries:
                if entry.admit(args):
                    return entry.call(*args)
        return self._dispatch(key, args)

    def _dispatch(self, key: Any, args: tuple) -> Any:
        """Call the dispatcher (it compiles, loads or raises TypingError as any call would),
        then record the entry point of the specialisation it ran."""
        self.dispatched += 1
        result = self.kernel(*args)
        specs = [type_spec(a) for a in args]
        if any(s is None for s in specs):
            return result  # nothing cheap identifies these types: always dispatch them
        overload = self.kernel.overloads.get(tuple(numba.typeof(a) for a in args))
        # not found (the dispatcher converted a type to an existing specialisation): keep
        # dispatching these types
        call = overload.entry_point if overload is not None else self.kernel
        entries = self.entries.setdefault(key, [])
        entries.insert(0, _Entry(args, specs, call))
        del entries[self.ENTRIES:]
        return result


__all__ = ["Direct", "type_spec"]
