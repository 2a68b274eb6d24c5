"""What the data can tell: the noise of a block mean at one operating point, and δ with its source."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.calibration.noise import Repeatability, minimum_effect, repeatability


def test_consecutive_blocks_of_a_dwell_give_the_standard_error_of_a_block_mean():
    """Dwells of 20 whole blocks (100 samples each) at levels far apart, white noise σ = 0.5 on the
    samples: the standard error of a block mean, 0.05, within 15 % -- the levels themselves (what a
    model would still lack between operating points) do not enter."""
    rng = np.random.default_rng(0)
    blocks = 400
    dwell = np.repeat(np.arange(blocks // 20), 20)
    level = 10.0 * rng.normal(size=blocks // 20)[dwell]
    measured = level + rng.normal(0, 0.5 / math.sqrt(100), blocks)
    rep = repeatability(measured, dwell, np.full(blocks, 100), 100.0)
    assert rep.se_block_nm == pytest.approx(0.05, rel=0.15) and rep.pairs == blocks - blocks // 20


def test_without_dwells_the_operating_point_visited_again_gives_it():
    """Blocks one per dwell, but the same operating points visited again (labels of cells): each visit
    against the one before it, scaled to whole blocks."""
    rng = np.random.default_rng(1)
    cells = np.tile(np.arange(30), 10)
    measured = 5.0 * np.sin(cells) + rng.normal(0, 0.02, len(cells))
    rep = repeatability(measured, np.arange(len(cells)), np.full(len(cells), 50), 50.0, cells)
    assert rep.cells and rep.se_block_nm == pytest.approx(0.02, rel=0.2)


def test_delta_says_where_it_came_from():
    rep = Repeatability(0.01, 100, 20)
    assert minimum_effect(0.5, rep, None, 0.1, 1.0, False, 0.25).source == "user"
    by_rep = minimum_effect(None, rep, None, 0.1, 1.0, False, 0.25)
    assert by_rep.source == "repeatability" and by_rep.delta_nm == pytest.approx(0.03)
    by_sensors = minimum_effect(None, rep, 0.2, 0.1, 1.0, False, 0.25)
    assert by_sensors.source == "sensors" and by_sensors.delta_nm == 0.2 and "sensors" in by_sensors.text
    no_rep = minimum_effect(None, Repeatability(math.nan, 0, 0), None, 0.004, 1.0, False, 0.25)
    assert no_rep.source == "noise" and no_rep.delta_nm == pytest.approx(0.012)
    assert minimum_effect(None, rep, None, 0.1, 2.0, True, 0.25).source == "table"


def test_the_sensors_stated_accuracy_sets_delta_where_it_says_more(tmp_path):
    """A rig whose torque sensors are stated at 0.5 % of 200 N·m full scale: δ from their propagated
    uncertainty (beyond the repeatability), said."""
    import json

    from helpers import run_cli
    from rigs import Rig, loaded_rig, params

    csv, cmap, _ = loaded_rig(tmp_path, Rig(drag_nm=0.2))
    stated = params(tmp_path / "p.yaml", "    sensors: {input_torque_full_scale_nm: 200.0, input_torque_fs_pct: 0.5, "
                                         "output_torque_full_scale_nm: 800.0, output_torque_fs_pct: 0.5}\n")
    result = json.loads(run_cli("calibrate", str(csv), "--channels", str(cmap), "--params", str(stated),
                                "--json").stdout)
    # u(T_in) = 1 N·m/√3, u(T_out)/ratio = 4/4 N·m/√3: the loss's u = 0.816 N·m, expanded 1.63 N·m
    assert result["delta"]["source"] == "sensors" and result["delta"]["delta_nm"] == pytest.approx(1.633, rel=0.01)
    assert result["verdict"] == "no_missing_effect"  # a 0.2 N·m drag is below what such sensors can tell
