"""Powers and hyperbolic tangents that round a Python float exactly as an array element.

The node estimates sample by sample on Python floats; replay, calibration and the tracer estimate
arrays.  Their results must be the same to the last bit (a live recording replayed gives what the
node published).  Python's ``x ** p`` and ``math.tanh`` call the C library, numpy's ufuncs on arrays
its SIMD kernels: they round the last bit differently for a few percent of arguments.  The functions
here call numpy's ufunc for a float too -- the same kernel, whatever the length of the array (tested)
-- and give a float back for a float.
"""

from __future__ import annotations

import numpy as np

__all__ = ["power", "tanh"]


def power(base, exponent):
    """``base ** exponent``: a float for floats, an array for arrays (numpy's ``power`` for both)."""
    out = np.power(base, exponent)
    return float(out) if out.ndim == 0 else out


def tanh(x):
    """``tanh(x)``: a float for a float, an array for an array (numpy's ``tanh`` for both)."""
    out = np.tanh(x)
    return float(out) if out.ndim == 0 else out
