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
            cwd: Path | None = None, max_file_bytes: int | None = None) -> subprocess.CompletedProcess:
    """Run ``rollergear ARGS`` in a subprocess (the installed console script's code path).
    ``max_file_bytes``: no file may grow past this size (RLIMIT_FSIZE; a write beyond it fails with
    EFBIG as one on a full disk fails with ENOSPC)."""
    full_env = dict(os.environ)
    full_env.update(env or {})

    def limit_files() -> None:
        import resource
        import signal

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails instead of the process
        resource.setrlimit(resource.RLIMIT_FSIZE, (max_file_bytes, max_file_bytes))

    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", *args], capture_output=True, text=True,
                          timeout=timeout, env=full_env, cwd=cwd or ROOT,
                          preexec_fn=limit_files if max_file_bytes is not None else None)
    if check and proc.returncode != 0:
        raise AssertionError(f"rollergear {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def preempted_catch_up(seed: int) -> list[tuple[str, int, float, int | None]]:
    """The input messages a loaded node takes across a burst loss, as ``(channel, taken at [ns],
    value, sent at [ns] or None)``; sample k is torque ``10 + k/1000`` and speed ``50 + k/1000``.

    200 samples paced at 1 kHz; then, while the node stalls for 50 ms, torque 200..500 and speed
    200..400 are lost (one placeholder each, taken just before the next message of its topic, no
    send time) and the rest is taken round-robin; then speed 1401..1500, and 200 paced samples.
    The node is preempted before one take in ten for 0.2-1 ms.  The publisher sent each sample's
    messages 5-15 µs apart."""
    import numpy as np

    from rollergear_ros.core.pairing import SPEED, TORQUE
    from rollergear_ros.core.lostmarks import LOST_VALUE

    rng = np.random.default_rng(seed)
    sent, clock = {}, 10**15
    for k in range(1701):
        for channel in (TORQUE, SPEED):
            sent[channel, k] = clock
            clock += 5_000 if k < 200 or k > 1500 else 15_000
        clock += 1_000_000 if k < 200 or k > 1500 else 0
    taken = 2 * 10**15
    events: list[tuple[str, int, float, int | None]] = []

    def take(channel: str, k: int, lost: int = 0) -> None:
        nonlocal taken
        taken += 12_000 + (int(rng.uniform(0.2e6, 1e6)) if rng.random() < 0.1 else 0)
        events.extend((channel, taken - lost + i, LOST_VALUE, None) for i in range(lost))
        events.append((channel, taken, (10.0 if channel == TORQUE else 50.0) + k * 1e-3, sent[channel, k]))

    for k in range(200):
        take(TORQUE, k)
        take(SPEED, k)
        taken += 1_000_000
    taken += 50_000_000
    for i, (k_torque, k_speed) in enumerate(zip(range(501, 1501), range(401, 1401))):
        take(TORQUE, k_torque, 301 if i == 0 else 0)
        take(SPEED, k_speed, 201 if i == 0 else 0)
    for k in range(1401, 1501):
        take(SPEED, k)
    for k in range(1501, 1701):
        take(TORQUE, k)
        take(SPEED, k)
        taken += 1_000_000
    return events


def with_effect(config, name: str, params: dict):
    """``config`` with the effect ``name`` on at ``params`` (its short names, as ``simulate --effect``
    and ``calibrate --json`` give them)."""
    from rollergear_ros.core.effects import EFFECTS

    return config.with_values({f"effects.{name}.enabled": True}
                              | {f"effects.{name}.{q.key}": params[q.short] for q in EFFECTS[name].parameters})


def partial_files(path: str | Path) -> list[Path]:
    """The files an atomic writer of ``path`` is writing (``.NAME.<random>.partial`` beside it)."""
    p = Path(path)
    return sorted(p.parent.glob(f".{p.name}.*.partial")) if p.parent.exists() else []


#: a parameter file with accepted effects of every kind but memory (the operating points' and the map's tests)
CALIBRATED = {
    "effects.drag_speed.enabled": True, "effects.drag_speed.c": 2e-4, "effects.drag_speed.p": 1.5,
    "effects.load_dependent.enabled": True, "effects.load_dependent.c": 1e-3, "effects.load_dependent.q": 1.2,
    "effects.viscosity_temperature.enabled": True, "effects.viscosity_temperature.B_k": 900.0,
    "effects.torque_offset.enabled": True, "effects.torque_offset.offset_nm": 0.3,
    "effects.torque_gain.enabled": True, "effects.torque_gain.gain": 0.02,
}


def damaged_copy(src: Path, out: Path, every: int) -> tuple[Path, int]:
    """``src`` with one byte of every ``every``-th chunk's compressed data flipped (its CRC kept), and
    how many chunks it has."""
    from mcap.reader import make_reader

    with src.open("rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    raw = bytearray(src.read_bytes())
    for ci in chunks[::every]:
        raw[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0x01
    out.write_bytes(bytes(raw))
    return out, len(chunks)
