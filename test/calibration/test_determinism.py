"""The same recording gives the same decisions on any CPU: changes, segments, accepted effects and the
verdict do not hinge on the BLAS kernel (``OPENBLAS_CORETYPE``), its threads or a last-bit change of
the inputs.

The case: a rig's map and the same operating points with a drag that appeared, one recording after the
other -- the change-point test between and within recordings, on designs of a drag per rad/s beside a
level (condition ~1e9, whose ``xᵀx`` lost every digit: three kernels once gave three answers)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from helpers import BAGS

#: one calibration, its decisions printed as JSON (run in a fresh process: a kernel is chosen at load)
WORKER = r"""
import json, sys
import numpy as np
from rollergear_ros.calibration.calibrate import calibrate
from rollergear_ros.calibration.samples import load_samples
from rollergear_ros.core.params import load_config

bags, ulp = sys.argv[1:3], sys.argv[3] == "ulp"
config = load_config(None)
data = load_samples(bags, config)
if ulp:  # every other sample's torque and measured loss one ulp up
    for name in ("torque", "measured_loss"):
        a = getattr(data, name).copy()
        a[::2] = np.nextafter(a[::2], np.inf)
        setattr(data, name, a)
r = calibrate(data, config).to_json()
print(json.dumps({
    "changes": [(c["t_s"], c["between_recordings"]) for c in r["changes"]],
    "effects": [e["name"] for e in r["effects"]],
    "accepted": sorted(d["name"] for d in r["decisions"] if d["accepted"]),
    "verdict": r["verdict"], "written": r["written"],
}))
"""


def _kernels() -> list[str]:
    """The OpenBLAS kernels this CPU can run: SkylakeX only where it has AVX-512."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    return ["Prescott", "Sandybridge", "Haswell"] + (["SkylakeX"] if " avx512f" in flags else [])


def _decisions(bags: list[str], kernel: str, threads: int, ulp: bool) -> dict:
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": str(threads)}
    proc = subprocess.run([sys.executable, "-c", WORKER, *bags, "ulp" if ulp else "exact"], env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_decisions_do_not_depend_on_the_cpu_kernel_threads_or_one_ulp(tmp_path):
    from bagtools import shifted_copy

    # the map ends before the one with the drag starts (the bundled two share one epoch)
    bags = [str(shifted_copy(BAGS / "rig_map.mcap", tmp_path / "rig_map.mcap", -300)),
            str(BAGS / "rig_map_drag.mcap")]
    kernels = _kernels()
    cases = [(k, 1, False) for k in kernels] + [(kernels[-1], 2, False), ("Prescott", 2, True)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda case: _decisions(bags, *case), cases))
    first = results[0]
    for case, result in zip(cases, results):
        assert result["changes"] == first["changes"], (case, result, first)
        assert result == first, (case, result, first)
    # and the decision itself is the right one: the change between the two recordings, the latest calibrated
    [(t_s, between)] = first["changes"]
    assert between and 51 < t_s < 52, first
    assert sorted(first["effects"]) == ["drag_constant", "drag_speed"], first



def test_decisions_do_not_depend_on_the_order_the_recordings_are_given_in(tmp_path):
    """Three runs of a worm drive, each at other speeds, calibrated as one in two orders, with and
    without the search for changes: the recordings are taken in an order of their own (first stamp,
    length, content), so the changes found, which dwells are held out together, every candidate's
    held-out errors, the decisions and the file are the same to the bit; a change names its recording
    by its place in the list given.
    In the order given, a change between recordings was found in one order only, and folds counted
    in the order given moved the held-out errors by 1.5 %."""
    from helpers import run_cli
    from rigs import worm_drive

    runs = [worm_drive(tmp_path, None, rpms=rpms, seed=seed, name=f"worm{seed}")
            for seed, rpms in enumerate([(1, 4, 15, 50, 140), (2, 8, 30, 70, 200), (3, 10, 20, 100, 160)])]

    def calibrate(order, segments: str) -> dict:
        return json.loads(run_cli("calibrate", *(str(runs[i][0]) for i in order), "--channels", str(runs[0][1]),
                                  "--segments", segments, "--json", check=False).stdout)

    orders = [0, 1, 2], [2, 0, 1]
    for segments in ("off", "latest"):
        given, other = (calibrate(order, segments) for order in orders)
        if segments == "off":  # every recording calibrated: effects to compare
            held_out = [d for d in given["decisions"] if d["heldout_rmse_nm"] is not None]
            assert len(held_out) >= 5 and given["effects"], given["decisions"]
        for key in ("decisions", "effects", "verdict", "error_before", "error_after", "stretch"):
            assert other[key] == given[key], (segments, key)
        # the same changes, each naming the same recording by its place in its own list
        assert [(c["t_ns"], orders[1][c["recording"]]) for c in other["changes"]] == \
            [(c["t_ns"], orders[0][c["recording"]]) for c in given["changes"]]
