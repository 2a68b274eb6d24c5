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
    assert minimum_effect(0.5, rep, None, 0.1, 5.0, False, 0.25).source == "user"
    by_rep = minimum_effect(None, rep, None, 0.1, 5.0, False, 0.25)
    assert by_rep.source == "repeatability" and by_rep.delta_nm == pytest.approx(0.03)
    by_sensors = minimum_effect(None, rep, 0.2, 0.1, 5.0, False, 0.25)
    assert by_sensors.source == "sensors" and by_sensors.delta_nm == 0.2 and "sensors" in by_sensors.text
    no_rep = minimum_effect(None, Repeatability(math.nan, 0, 0), None, 0.004, 5.0, False, 0.25)
    assert no_rep.source == "noise" and no_rep.delta_nm == pytest.approx(0.012)
    assert minimum_effect(None, rep, None, 0.1, 2.0, True, 0.25).source == "table"
    # a block mean that scatters more than 2 % of the loss: an effect of 2 % of the loss is material
    share = minimum_effect(None, rep, None, 0.1, 1.0, False, 0.25)
    assert share.source == "loss share" and share.delta_nm == pytest.approx(0.02) and "0.03" in share.text
    assert minimum_effect(None, rep, 0.025, 0.1, 1.0, False, 0.25).source == "sensors"  # never below the sensors'
    assert minimum_effect(None, rep, None, 0.1, 1.0, True, 0.25).delta_nm == share.delta_nm  # a table's alike


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


@pytest.mark.parametrize("load_nm", [0.3, 30.0])
def test_operating_points_visited_again_are_told_by_speed_and_load_not_by_the_loss_measured(load_nm):
    """A back-and-forth drive (one 0.25 s block per visit to one of 30 speeds, 100 Hz) under a constant
    load: the repeatability of a block mean is the samples' noise over a block (σ = 0.25 N·m over 25
    samples: 0.05 N·m), also where the load is small against the loss (0.3 N·m beside ~1 N·m): there
    the drive torque is mostly the loss measured, and cells told by it would pair only blocks whose
    measured loss happened to agree (their scatter then ~0.01 N·m: δ far below what the data tell)."""
    from rollergear_ros.calibration.blocks import make_blocks
    from rollergear_ros.calibration.samples import SampleData

    rng = np.random.default_rng(4)
    visits, per_block = 600, 25
    speed = np.repeat(20.0 + 10.0 * (np.arange(visits) * 7 % 30), per_block)  # rad/s, each visit one block
    n = len(speed)
    loss = 1.0 + 0.001 * speed + rng.normal(0, 0.25, n)
    torque = load_nm + loss
    t_ns = np.arange(n, dtype=np.int64) * 10_000_000
    z = np.zeros(n)
    data = SampleData(t_ns, np.zeros(n, dtype=np.int64), torque, speed, np.full(n, np.nan), loss, z, z,
                      out_torque=np.full(n, load_nm), out_speed=speed)
    rep = make_blocks(data).repeat
    assert rep.cells and rep.pairs > 400
    assert rep.se_block_nm == pytest.approx(0.05, rel=0.2)
