"""The rig's nuisances (rollergear_ros.calibration.nuisance): a channel's lag is claimed only within
the range a parameter file may hold for it."""

from __future__ import annotations

import pytest

from rollergear_ros.calibration.nuisance import lag_from_fit, lag_range_s
from rollergear_ros.core.params import load_config


def test_a_lag_within_the_files_range_is_applied_and_written_as_a_valid_file():
    lag = lag_from_fit("lag:output_torque", 0.030, 0.001, 0.01)
    assert lag.applied and not lag.why_not and lag.lag_s == pytest.approx(0.030)
    load_config().with_values({"estimator.output_torque_lag_s": lag.lag_s})  # a file may hold it


@pytest.mark.parametrize("fitted_s", [7.35, -1.21, 1.09])
def test_a_lag_beyond_the_files_range_is_not_claimed_and_the_reason_is_said(fitted_s):
    """Mixed-rate recordings (a speed at 5 Hz, an output torque at 10 Hz) fitted lags of 7.35 s,
    -1.21 s and 1.09 s, clearly there by their standard errors; calibrate aligned by them and then
    refused the file it wrote ("estimator.output_speed_lag_s … is invalid").  Beyond ±1 s none is
    applied and the sentence says why."""
    assert lag_range_s() == 1.0
    lag = lag_from_fit("lag:output_speed", fitted_s, 0.01, 0.1)
    assert not lag.applied
    assert "beyond the ±1 s a parameter file may hold for estimator.output_speed_lag_s" in lag.why_not
    assert lag.sentence().startswith(f"output_speed: a lag of {1e3 * fitted_s:.4g} ms fitted")
    assert lag.to_json()["why_not"] == lag.why_not
    with pytest.raises(Exception, match="output_speed_lag_s"):
        load_config().with_values({"estimator.output_speed_lag_s": fitted_s})  # what it would have written
