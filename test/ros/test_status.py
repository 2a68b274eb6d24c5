"""The node's ``/diagnostics`` status over DDS: it stays true -- WARN for as long as the residual stays
beyond its threshold, OK once it returns, STALE when the inputs go idle -- and carries the measured
efficiency with the figure a rig engineer computes by hand."""

from __future__ import annotations

import csv
import io
import threading
import time

import pytest

from rollergear_ros.core.model import LossModel
from rollergear_ros.core.params import load_config
from rollergear_ros.recordings.messages import TopicMap

from helpers import CONFIG
from rostools import NodeProcess, WatchProcess, ros_context, wait_for

pytestmark = [pytest.mark.ros, pytest.mark.slow]

T = TopicMap()
TORQUE_NM, SPEED_RAD_S = 20.0, 100.0
EXTRA_NM = 0.1  #: the loss that appears (input-referred), five times the detector's threshold


class Rig:
    """Publishes a steady operating point (drive torque and speed, output torque and speed) at ~200 Hz
    from a thread: the output torque is the model's (residual 0) plus ``extra_nm`` of loss, which the
    test switches; :meth:`stop` makes the inputs idle."""

    def __init__(self, probe) -> None:
        from std_msgs.msg import Float64

        config = load_config(CONFIG)
        self.ratio = config.gearbox.ratio_effective
        model = LossModel(config.gearbox, config.estimator.min_torque_for_efficiency_nm,
                          config.estimator.min_speed_for_efficiency_rad_s, config.estimator.paper_model)
        self.loss_nm = float(model.loss_magnitude_scalar(TORQUE_NM, SPEED_RAD_S, 1.0))
        self.extra_nm = 0.0
        self._msg = Float64
        self.pubs = [probe.create_publisher(Float64, topic, 100)
                     for topic in (T.motor_torque, T.motor_speed, T.output_torque, T.output_speed)]
        assert wait_for(lambda: all(p.get_subscription_count() > 0 for p in self.pubs), 60)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            out = (TORQUE_NM - self.loss_nm - self.extra_nm) * self.ratio
            for pub, value in zip(self.pubs, (TORQUE_NM, SPEED_RAD_S, out, SPEED_RAD_S / self.ratio)):
                pub.publish(self._msg(data=value))
            time.sleep(0.005)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)


def _reports(msgs: list) -> list[tuple[int, str, dict]]:
    """(level, message, values) of the node's own status in each /diagnostics message received."""
    out = []
    for m in list(msgs):
        for s in m.status:
            if s.name.endswith("roller gearbox losses"):
                level = int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level)
                out.append((level, s.message, {kv.key: kv.value for kv in s.values}))
    return out


def test_the_status_stays_warn_while_the_residual_stays_ok_after_it_returns_and_stale_when_idle():
    from diagnostic_msgs.msg import DiagnosticArray

    # a steady rate the reports cannot call slow; reliable inputs: nothing lost on a loaded machine
    node = NodeProcess("node.expected_rate_hz:=10.0", "node.learn_input_rate:=false", "node.input_qos:=reliable",
                       "estimator.change_block_samples:=50", "node.trace:=false", "node.efficiency_window_s:=2.0")
    try:
        with ros_context() as probe:
            msgs: list = []
            probe.create_subscription(DiagnosticArray, "/diagnostics", msgs.append, 50)
            rig = Rig(probe)
            try:
                # 1. the model's loss: OK, with the measured efficiency (T − L)/T over the window
                def calm_ok():
                    return any(lv == 0 and v.get("measured efficiency", "").startswith("0.")
                               for lv, _, v in _reports(msgs))
                assert wait_for(calm_ok, 120), _reports(msgs)[-3:]
                level, message, values = next(r for r in _reports(msgs) if r[0] == 0 and "measured efficiency" in
                                              r[1])
                expected = (TORQUE_NM - rig.loss_nm) / TORQUE_NM
                assert float(values["measured efficiency"]) == pytest.approx(expected, rel=1e-9)
                assert values["residual beyond threshold"] == "no"
                assert f"measured efficiency {100 * expected:.2f} %" in message
                # what a logger takes from watch --csv: the same figure, the status
                watcher = WatchProcess("--csv", "--period", "0.5")
                try:
                    assert wait_for(lambda: any(",OK," in line and line.count(",") > 8 for line in watcher.lines[1:]),
                                    60), watcher.lines
                finally:
                    watcher.stop()
                row = next(r for r in csv.DictReader(io.StringIO("\n".join(watcher.lines))) if r["level"] == "OK")
                assert float(row["efficiency_measured"]) == pytest.approx(expected, rel=1e-9)
                # 2. a loss appears and stays: WARN from the alarm on, in every report while it stays
                rig.extra_nm = EXTRA_NM
                seen = len(_reports(msgs))

                def warned():
                    return [r for r in _reports(msgs)[seen:] if "stays beyond" in r[1]]
                assert wait_for(lambda: len(warned()) >= 1, 120), _reports(msgs)[seen:]
                first = _reports(msgs).index(warned()[0])
                assert wait_for(lambda: len(_reports(msgs)) >= first + 5, 60)  # four more reports, the loss still on
                held = _reports(msgs)[first:first + 5]
                rig.extra_nm = 0.0
                for level, message, values in held:
                    assert level == 1 and "the residual changed" in message and "stays beyond" in message, message
                    assert values["residual beyond threshold"] == "yes"
                # 3. the loss goes: OK again once the residual has returned
                seen = len(_reports(msgs))
                assert wait_for(lambda: any(r[0] == 0 for r in _reports(msgs)[seen:]), 120), _reports(msgs)[-3:]
                back = next(r for r in _reports(msgs)[seen:] if r[0] == 0)
                assert back[2]["residual beyond threshold"] == "no" and back[2]["residual change alarms"] == "1"
            finally:
                rig.stop()
            # 4. the inputs go idle: STALE, not ERROR
            seen = len(_reports(msgs))
            assert wait_for(lambda: any(r[0] == 3 for r in _reports(msgs)[seen:]), 60), _reports(msgs)[-3:]
            idle = next(r for r in _reports(msgs)[seen:] if r[0] == 3)
            assert "idle" in idle[1] and not any(r[0] == 2 for r in _reports(msgs)), idle
    finally:
        assert node.stop() == 0, node.stderr
    assert "Traceback" not in node.stderr
