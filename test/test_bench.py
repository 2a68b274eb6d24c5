"""The bench scripts run on small data: a script the README's figures come from must not break
silently when the code under it changes (their timings are not asserted here, see bench/)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from helpers import ROOT

SMALL = [
    ("bench_import.py", ["--minutes", "0.05"]),
    ("bench_calibrate.py", ["--minutes", "0.5"]),
    ("bench_replay.py", ["--minutes", "0.1"]),
    ("bench_replay.py", ["--minutes", "0.1", "--memory"]),
    ("bench_model.py", ["--samples", "100000"]),
    ("bench_node.py", ["--estimator-only", "--memory", "--repeat", "1"]),
    ("bench_trace.py", ["--rate", "200", "--repeat", "1"]),
]


@pytest.mark.slow
@pytest.mark.parametrize(("script", "args"), SMALL)
def test_a_bench_script_runs_to_its_end(script, args, tmp_path):
    args = args + ([] if script in ("bench_model.py", "bench_node.py", "bench_trace.py") else ["--keep", str(tmp_path)])
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / script), *args], capture_output=True, text=True,
                          cwd=ROOT / "bench", timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and proc.stdout.strip(), proc.stderr[-3000:]
