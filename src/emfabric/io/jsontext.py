"""JSON text that any JSON reader accepts (RFC 8259: no NaN or Infinity).

Python's json.dumps writes a non-finite float as the bare words NaN or Infinity, which jq,
JavaScript's JSON.parse and most other readers refuse. The CLI's --json output and the study
files a user reads write such a value as null instead (a diverged run's figures, a charge whose
surface field overflows a double).
"""

from __future__ import annotations

import math
from typing import Any


def finite_or_null(obj: Any) -> Any:
    """obj with every non-finite float (NumPy's too) replaced by None, NumPy scalars and arrays
    turned into Python numbers and lists; dicts, lists and tuples are copied, the rest kept."""
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if type(obj).__module__ == "numpy" and hasattr(obj, "tolist"):
        # a NumPy array or scalar (NumPy is not imported for this: the CLI starts without it);
        # a long double's tolist() is a long double again: a float then
        value = obj.tolist()
        if type(value).__module__ == "numpy":
            value = float(value)
        return finite_or_null(value)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj: Any, **kwargs: Any) -> str:
    """json.dumps with non-finite numbers written as null (finite_or_null)."""
    import json

    return json.dumps(finite_or_null(obj), allow_nan=False, **kwargs)


__all__ = ["dumps", "finite_or_null"]
