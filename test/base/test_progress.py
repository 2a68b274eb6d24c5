"""Progress bars that move by time, and the commands that draw them on a terminal."""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
import time

from rollergear_ros.base.progress import TimedProgress

from helpers import BAGS, ROOT

DEADLINE_S = 60.0  # generous: every wait below ends on a condition, this only bounds a defect


def _wait_for(condition, what: str) -> None:
    end = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


def test_the_bar_redraws_and_follows_its_counter_without_updates(capsys):
    """No update() call: the thread redraws from read() (elapsed time moves, then the count)."""
    count = [0]
    text = []

    def drawn() -> str:
        text.append(capsys.readouterr().err)
        return "".join(text)

    with TimedProgress("work", 10, "msg", read=lambda: count[0], enabled=True, unit_scale=False) as bar:
        _wait_for(lambda: drawn().count("0/10") >= 3, "three redraws of an unchanged count")
        count[0] = 7
        bar.stage = "step 2"
        _wait_for(lambda: "7/10" in drawn() and "step 2" in drawn(), "the new count and stage")
    assert "10" in drawn()


def test_a_disabled_bar_draws_nothing_and_starts_no_thread(capsys):
    with TimedProgress("work", 10, enabled=False) as bar:
        bar.update(3)
        assert bar._thread is None
    assert capsys.readouterr().err == ""


def _run_on_a_terminal(*args: str) -> tuple[int, str]:
    """``rollergear ARGS`` with stderr on a pseudo-terminal (the bars are drawn on a terminal only)."""
    main, sub = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "rollergear_ros", *args], stdout=subprocess.DEVNULL,
                            stderr=sub, stdin=subprocess.DEVNULL, cwd=ROOT)
    os.close(sub)
    chunks = []
    while True:
        try:
            data = os.read(main, 65536)
        except OSError:  # the terminal's other end closed: the command has ended
            break
        if not data:
            break
        chunks.append(data)
    os.close(main)
    return proc.wait(timeout=DEADLINE_S), b"".join(chunks).decode(errors="replace")


def test_calibrate_on_a_terminal_shows_the_replay_and_the_analysis_with_its_stage(tmp_path):
    rc, err = _run_on_a_terminal("calibrate", str(BAGS / "rig_map_drag.mcap"), "--out", str(tmp_path / "c.yaml"))
    assert rc == 0, err
    assert re.search(r"replay: 100%", err), err
    # the bar is redrawn at most 10 times a second; on closing it shows its last stage
    assert "analysis" in err and "changes inside the recordings" in err, err


def test_simulate_on_a_terminal_counts_the_samples_written(tmp_path):
    rc, err = _run_on_a_terminal("simulate", "--out", str(tmp_path / "s.mcap"), "--duration", "5")
    assert rc == 0, err
    assert re.search(r"simulate: 100%.*1\.00k/1\.00k", err), err
