"""rollergear_ros.core.floatops: a Python float rounded as an element of an array."""

from __future__ import annotations

import math

import numpy as np

from rollergear_ros.core.floatops import power, tanh


def test_a_float_is_rounded_as_the_same_value_in_an_array():
    """Over many arguments (where the C library's ``**`` and ``tanh`` and numpy's array kernels may
    round the last bit apart), a float gives exactly its element of the array's result."""
    rng = np.random.default_rng(0)
    bases = rng.uniform(0.0, 400.0, 20_000)
    for exponent in (0.47, 0.66, 1.33, 5.0 / 3.0, 1.4, 2.0, 0.5):
        whole = power(bases, exponent)
        assert isinstance(whole, np.ndarray)
        one_by_one = [power(b, exponent) for b in bases.tolist()]
        assert all(type(v) is float for v in one_by_one[:10])
        np.testing.assert_array_equal(np.array(one_by_one), whole, err_msg=str(exponent))
    exponents = rng.uniform(-3.0, 3.0, 20_000)
    np.testing.assert_array_equal(np.array([power(math.e, y) for y in exponents.tolist()]), power(math.e, exponents))
    np.testing.assert_array_equal(np.array([tanh(y) for y in exponents.tolist()]), tanh(exponents))
    assert power(0.0, 0.47) == 0.0 and tanh(0.0) == 0.0 and math.isnan(power(math.nan, 2.0))
