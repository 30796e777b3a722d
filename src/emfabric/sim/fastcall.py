"""Calling a compiled kernel without Numba's per-call type dispatch.

A Numba dispatcher types every argument on every call to pick the compiled specialisation; for
the model's records (named tuples of arrays) that costs about 100 µs per call — as much as a
third of a paper-field step went to it for the step, energy and diagnostics kernels.
``Direct(kernel)`` calls through the dispatcher once per key, then looks the specialisation up
and calls its entry point directly. The key is the caller's promise that the argument types
are the same as the first time (one Integrator, one kind of row buffer; one Model): the
arguments are then unboxed by the same compiled wrapper as before, and the numbers are the
same.
"""

from __future__ import annotations

from typing import Any

import numba


class Direct:
    """`kernel(*args)` through the compiled entry point of the specialisation for `key`."""

    def __init__(self, kernel: Any):
        self.kernel = kernel
        self.entries: dict[Any, Any] = {}

    def __call__(self, key: Any, *args: Any) -> Any:
        entry = self.entries.get(key)
        if entry is not None:
            return entry(*args)
        result = self.kernel(*args)  # compiles or loads it, as any first call
        overload = self.kernel.overloads.get(tuple(numba.typeof(a) for a in args))
        # not found (a type the dispatcher resolves differently): keep dispatching
        self.entries[key] = overload.entry_point if overload is not None else self.kernel
        return result


__all__ = ["Direct"]
