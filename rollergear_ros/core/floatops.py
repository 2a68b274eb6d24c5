"""Powers and hyperbolic tangents that round a Python float exactly as an array element.

The node estimates sample by sample on Python floats; replay, calibration and the tracer estimate
arrays.  Their results must be the same to the last bit (a live recording replayed gives what the
node published).  Python's ``x ** p`` and ``math.tanh`` call the C library, numpy's ufuncs on arrays
its SIMD kernels: they round the last bit differently for a few percent of arguments.  The functions
here call numpy's ufunc for a float too -- the same kernel, whatever the length of the array (tested)
-- and give a float back for a float.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

__all__ = ["power", "shared_powers", "tanh"]

_SHARED: list[dict] = []  #: while :func:`shared_powers` is open: (id of the base, exponent) -> powers


def power(base, exponent):
    """``base ** exponent``: a float for floats, an array for arrays (numpy's ``power`` for both)."""
    if _SHARED and isinstance(base, np.ndarray) and base.size > 1:
        memo = _SHARED[-1]
        key = (id(base), float(exponent))
        hit = memo.get(key)
        if hit is not None and hit[0] is base:
            return hit[1]
        out = np.power(base, exponent)
        memo[key] = (base, out)
        return out
    out = np.power(base, exponent)
    return float(out) if out.ndim == 0 else out


@contextmanager
def shared_powers():
    """Within it, the powers of one array to one exponent are computed once (several laws of one input
    at one exponent: a drag and its difference between directions); the arrays are freed after."""
    _SHARED.append({})
    try:
        yield
    finally:
        _SHARED.pop()


def tanh(x):
    """``tanh(x)``: a float for a float, an array for an array (numpy's ``tanh`` for both)."""
    out = np.tanh(x)
    return float(out) if out.ndim == 0 else out
