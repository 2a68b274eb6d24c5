"""Paths of the source tree and the package's command line run as a real subprocess (for tests)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BAGS = ROOT / "bags"
CONFIG = ROOT / "config" / "gearbox.yaml"
#: ``../shared`` beside the project (public real data with provenance); ROLLERGEAR_SHARED overrides
SHARED = Path(os.environ.get("ROLLERGEAR_SHARED", ROOT.parent / "shared"))
REALDATA = SHARED / "realdata"


def run_cli(*args: str, check: bool = True, timeout: float = 600, env: dict | None = None,
            cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``rollergear ARGS`` in a subprocess (the installed console script's code path)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", *args], capture_output=True, text=True,
                          timeout=timeout, env=full_env, cwd=cwd or ROOT)
    if check and proc.returncode != 0:
        raise AssertionError(f"rollergear {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc
