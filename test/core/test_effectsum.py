"""The enabled effects at a sample (:mod:`rollergear_ros.core.effectsum`): the load the laws in the load take."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.effects import EFFECTS, EffectInputs
from rollergear_ros.core.effectsum import output_load


@pytest.mark.parametrize("law", ["load_dependent", "backdrive", "load_speed"])
def test_the_load_a_law_takes_is_the_rigs_own_whatever_the_law_and_the_torque(law):
    """:func:`effectsum.output_load` (Newton, a fixed count of steps) against the simulated rig's bisection
    (``calibration.simulate``: another algorithm, to the last bit): exponents 0.3 … 2.5, coefficients up to a
    friction of 60 % of the load, drive torques from 1e-9 to 100 N·m driving and back-driven, with and without
    other losses.  Wherever the rig has a load the estimator finds the same one (the motoring branch near
    zero too, where a law steeper than the load also balances a spurious back-driven load), never NaN."""
    from rollergear_ros.calibration.simulate import _laws_at_true_load

    member = "p" if law == "load_speed" else "q"
    torque = np.concatenate([np.geomspace(1e-9, 100, 120), -np.geomspace(1e-9, 100, 120)])
    speed = np.full(len(torque), 10.0)
    found = 0
    for other_nm, direction in ((0.0, 1.0), (0.5, -1.0)):
        sign = np.full(len(torque), direction)
        x = EffectInputs(np.abs(torque), speed, direction * torque, sign, np.nan)
        other = np.full(len(torque), other_nm)
        for exponent in (0.3, 0.5, 0.8, 1.0, 1.5, 2.5):
            for c in (1e-3, 0.02, 0.1, 0.3, 0.6):
                laws = [(EFFECTS[law], {"c": c, member: exponent})]
                try:
                    truth = _laws_at_true_load(x, other, laws, np.ones(len(torque)))
                except Exception:  # the rig locks somewhere: compare where it does not
                    continue
                load, loss = output_load(x, other, laws)
                np.testing.assert_allclose(loss, truth, rtol=1e-12, atol=1e-300, err_msg=f"{law} c={c} e={exponent}")
                found += 1
    assert found > 25  # (load_speed at 10 rad/s locks the drive for the largest c·10^p)
    # a friction growing with the cube of the load locks a drive back-driven with 90 N·m: no load, NaN
    locked = EffectInputs(90.0, 100.0, -90.0, 1.0, np.nan)
    assert all(math.isnan(v) for v in output_load(locked, 0.3, [(EFFECTS["backdrive"], {"c": 3e-3, "q": 3.0})]))
