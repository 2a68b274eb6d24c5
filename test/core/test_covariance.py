"""``calibration.covariance``: what calibrate writes of its fit, validated with the parameter file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rollergear_ros.base.errors import ParameterError
from rollergear_ros.core.covariance import ParameterCovariance
from rollergear_ros.core.params import load_config, validate

from helpers import run_cli


def test_the_text_round_trips_to_the_last_digit():
    cov = ParameterCovariance(("effects.drag_speed.c", "effects.drag_speed.p"),
                              np.array([[1.9868495323132318e-11, -1.2e-08], [-1.2e-08, 7.3739094395956275e-06]]))
    back = ParameterCovariance.from_text(cov.to_text())
    assert back.keys == cov.keys and (back.matrix == cov.matrix).all()
    assert ParameterCovariance.from_text("") is None


@pytest.mark.parametrize(("text", "message"), [
    ("[1, 2", "not JSON"),
    ('{"keys": ["effects.drag_speed.c"]}', '"keys" and "matrix"'),
    ('{"keys": ["effects.drag_speed.c", "effects.drag_speed.c"], "matrix": [[1, 0], [0, 1]]}', "each once"),
    ('{"keys": ["effects.drag_speed.c"], "matrix": [[1, 2]]}', "1 rows of 1 numbers"),
    ('{"keys": ["effects.drag_speed.c"], "matrix": [[NaN]]}', "finite numbers"),
    ('{"keys": ["effects.drag_speed.c"], "matrix": [[' + "9" * 400 + ']]}', "finite numbers"),  # no float holds it
    ('{"keys": ["effects.drag_speed.c", "effects.drag_speed.p"], "matrix": [[1, 0.5], [0.2, 1]]}', "not symmetric"),
    ('{"keys": ["effects.drag_speed.c", "effects.drag_speed.p"], "matrix": [[1, 2], [2, 1]]}', "not a covariance"),
    ('{"keys": ["node.record_mcap"], "matrix": [[1]]}', "no numeric parameter"),
    ('{"keys": ["effects.drag_speed.enabled"], "matrix": [[1]]}', "no numeric parameter"),
])
def test_a_covariance_that_is_none_is_refused_with_the_reason(text, message):
    with pytest.raises(ParameterError, match="calibration.covariance") as err:
        validate({"calibration.covariance": text})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_calibrate_writes_the_joint_covariance_of_what_it_fitted(tmp_path):
    """A speed drag's c and p trade against each other: their correlation is strongly negative, and
    each one's spread is the one its own 95 % interval (profiled) says."""
    rig = tmp_path / "rig.mcap"
    run_cli("simulate", "--out", str(rig), "--profile", "bidirectional_map", "--rate", "50",
            "--effect", "drag_speed:c=3e-4,p=1.4")
    out = tmp_path / "cal.yaml"
    found = json.loads(run_cli("calibrate", str(rig), "--out", str(out), "--json").stdout)
    cov = ParameterCovariance.from_text(load_config(out).calibration.covariance)
    assert cov.keys == ("effects.drag_speed.c", "effects.drag_speed.p")
    drag = next(e for e in found["effects"] if e["name"] == "drag_speed")
    for k, short in enumerate(("c", "p")):
        lo, hi = drag["ci95"][short]
        assert np.sqrt(cov.matrix[k, k]) == pytest.approx((hi - lo) / 2 / 1.96, rel=0.25), short
    assert cov.matrix[0, 1] / np.sqrt(cov.matrix[0, 0] * cov.matrix[1, 1]) < -0.9
