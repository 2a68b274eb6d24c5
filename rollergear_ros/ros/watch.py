"""The watcher behind ``rollergear watch`` (:mod:`cli.watch`): a running ``loss_estimator``'s estimates and
status, one line per second.

Stands in for ``ros2 topic echo`` (the ``ros2`` CLI has no PyPI wheels) in the terminal next to a
node and a player.  Each line gives, over the last period: estimates received per second, the mean
loss torque [N·m] and loss power [W], the mean efficiency (and its minimum), the mean residual
[N·m] when measured output torque is present, the latest measured efficiency over the node's window
with its standard uncertainty (``efficiency/measured``), the mean of any further Float64 output channel
(:mod:`base.output_channels`), and the node's latest ``/diagnostics`` level and message; each online
trace's result (``loss/traced``, latched: also the last one before the watcher started) on a line of
its own.  The outputs are taken
raw and best effort with shallow queues: a slow terminal never holds the node back, and the rate
shown is what reached the watcher.

:class:`WatchWindow` (no rclpy) collects and formats one period; :func:`watch` is the ROS shell.
"""

from __future__ import annotations

import csv
import datetime
import json
import math
import re
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..base.interface import NAMESPACE, Topic
from ..base.output_channels import OUTPUT_CHANNELS, float64_channels, trace_channels, window_channels
from ..recordings.messages import decode_float64
from .diagnostics import LEVEL_NAMES, STATUS_NAME

#: the channels the line formats in a place of their own; any other is added as ``name mean unit``
_FORMATTED = ("loss_torque", "loss_power", "efficiency", "residual_torque", "efficiency_measured",
              "efficiency_measured_uncertainty")


def watched_channels():
    """The Float64 channels watch subscribes to: per sample and the measured efficiency's windows."""
    return float64_channels() + window_channels()


@dataclass
class WatchWindow:
    """Serialized Float64 outputs and the latest diagnostics received during one period."""

    payloads: dict[str, list[bytes]] = field(default_factory=lambda: {c.name: [] for c in watched_channels()})
    diagnostic: tuple[int, str] | None = None  #: (level, message) of the node's latest status
    traced: list[str] = field(default_factory=list)  #: online trace results received, not yet printed
    #: the latest measured-efficiency window and its uncertainty, kept across periods (one comes a
    #: second of sample time: a period of the watcher's own clock may see none)
    measured: tuple[float, float] = (math.nan, math.nan)
    status_at: float | None = None  #: when the node's latest status came (``time.monotonic``)
    started: float = field(default_factory=time.monotonic)  #: when the watcher began

    def add_status(self, level: int, message: str, values: dict[str, str]) -> None:
        """The node's status (``/diagnostics``): its level and message, and the measured efficiency it
        states (the same window the window channels carry, so a row has it from the first status on,
        not only after the next window message)."""
        self.diagnostic = (level, message)
        self.status_at = time.monotonic()
        try:
            efficiency = float(values.get("measured efficiency", "none"))
        except ValueError:  # "none (no measured output torque)"
            return
        try:
            uncertainty = float(values.get("measured efficiency uncertainty", "0"))
        except ValueError:  # "not stated (sensors.*)": 0, as the window channel says it
            uncertainty = 0.0
        self.measured = (efficiency, uncertainty)

    def add_traced(self, level: int, message: str) -> None:
        """An online trace's result (``loss/traced``): printed on a line of its own."""
        self.traced.append(f"traced [{LEVEL_NAMES.get(level, str(level))}] {message}")

    def take_traced(self) -> list[str]:
        lines, self.traced = self.traced, []
        return lines

    def add(self, channel: str, raw: bytes) -> None:
        self.payloads[channel].append(raw)

    def silent_s(self, period_s: float, now: float | None = None) -> float:
        """How long the node has been silent on ``/diagnostics`` (its status comes once a second): the
        time since its latest status, or since the watcher began when none came; 0 while it speaks."""
        now = time.monotonic() if now is None else now
        age = now - (self.status_at if self.status_at is not None else self.started)
        return age if age > max(SILENT_AFTER_S, 2.5 * period_s) else 0.0

    def take(self, period_s: float, now: float | None = None) -> dict:
        """The period's figures (and start a new one): what :meth:`line`, ``--csv`` and ``--json`` show.

        Keys: ``estimates_per_s``, ``loss_torque_nm``, ``loss_power_w``, ``efficiency``,
        ``efficiency_min`` (means over the period), ``residual_nm``, ``efficiency_measured`` and
        ``efficiency_measured_uncertainty`` (the latest window), ``level`` and ``message`` of the
        node's status -- ``SILENT`` and how long where ``/diagnostics`` stopped (:meth:`silent_s`: a node
        that ended, was killed or hangs is not an idle rig) --, ``status_age_s``; a further Float64 channel by
        its name (its mean).  NaN / "" where none came."""
        values = {k: decode_float64(v) for k, v in self.payloads.items()}
        for v in self.payloads.values():
            v.clear()
        level, message = self.diagnostic if self.diagnostic is not None else (None, "")
        eff = values["efficiency"]
        measured, spread = values["efficiency_measured"], values["efficiency_measured_uncertainty"]
        if len(measured):
            self.measured = (float(measured[-1]), float(spread[-1]) if len(spread) else math.nan)
        row = {"estimates_per_s": len(values["loss_torque"]) / period_s,
               "loss_torque_nm": _mean(values["loss_torque"]), "loss_power_w": _mean(values["loss_power"]),
               "efficiency": _mean(eff),
               "efficiency_min": float(np.nanmin(eff)) if np.isfinite(eff).any() else math.nan,
               "residual_nm": _mean(values["residual_torque"]),
               "efficiency_measured": self.measured[0], "efficiency_measured_uncertainty": self.measured[1],
               "level": "" if level is None else LEVEL_NAMES.get(level, str(level)), "message": message}
        now = time.monotonic() if now is None else now
        row["status_age_s"] = now - self.status_at if self.status_at is not None else math.nan
        silent = self.silent_s(period_s, now)
        if silent:
            last = f"; its last status: [{row['level']}] {message}" if row["level"] else ""
            row["level"] = "SILENT"
            row["message"] = (f"no status from the node for {silent:.0f} s: /diagnostics stopped (the node ended, "
                              f"was killed or hangs){last}" if self.status_at is not None else
                              f"no status from a node in {silent:.0f} s (none running in this namespace and "
                              "ROS_DOMAIN_ID?)")
        row |= {name: _mean(v) for name, v in values.items() if name not in _FORMATTED}
        return row

    def line(self, period_s: float, topic_of_loss: str) -> str:
        """Format the period and start a new one: ``est/s  loss  power  η  residual  [level] message``."""
        row = self.take(period_s)
        message = row["message"]
        if row["estimates_per_s"] and math.isfinite(row["efficiency_measured"]):  # said once, in its column
            message = _HEADLINE.sub("", message)
        status = f"  [{row['level']}] {message}" if row["level"] else ""
        if row["estimates_per_s"] == 0:
            return f"no estimates on {topic_of_loss} in the last {period_s:.1f} s{status}"
        parts = [
            f"{row['estimates_per_s']:7.0f} est/s",
            f"loss {row['loss_torque_nm']:.4f} N·m",
            f"{row['loss_power_w']:.2f} W",
        ]
        if math.isfinite(row["efficiency"]):
            parts.append(f"η {100 * row['efficiency']:.2f} % (min {100 * row['efficiency_min']:.2f})")
        else:
            parts.append("η —")
        if math.isfinite(row["residual_nm"]):
            parts.append(f"residual {row['residual_nm']:+.4f} N·m")
        if math.isfinite(row["efficiency_measured"]):  # the latest window (one a second)
            u = row["efficiency_measured_uncertainty"]
            spread = f" ± {100 * u:.2f}" if u > 0 else ""
            parts.append(f"η measured {100 * row['efficiency_measured']:.2f}{spread} %")
        parts.extend(f"{name} {row[name]:.4g} {OUTPUT_CHANNELS[name].unit}" for name in self.payloads
                     if name not in _FORMATTED and math.isfinite(row[name]))
        return "  ".join(parts) + status


#: the node's status comes once a second: silent after this long without one (or 2.5 periods, if longer)
SILENT_AFTER_S = 3.0
#: the status message's measured-efficiency headline ("; measured efficiency 98.1 ± 0.3 % over 10 s")
_HEADLINE = re.compile(r"(^|; )measured efficiency [^;]* over [^;]* s$")


def _mean(v: np.ndarray) -> float:
    finite = v[np.isfinite(v)]
    return float(finite.mean()) if len(finite) else float("nan")


def watch(namespace: str = NAMESPACE, period_s: float = 1.0, count: int = 0, out=None, fmt: str = "text",
          until_silent_s: float = 0.0) -> int:
    """Print one :meth:`WatchWindow.line` per ``period_s`` until Ctrl-C (or ``count`` lines); ``fmt``
    ``csv`` (a header, then one row of :meth:`WatchWindow.take` per period, the time first; a figure with
    no value an empty field) or ``json`` (one object per line, null) for a logger; the time to the
    millisecond.  ``until_silent_s``: end with status 3 once the node has said nothing on ``/diagnostics``
    for that long (a logger's watchdog: a dead node is no idle rig)."""
    out = sys.stdout if out is None else out  # as the command line wraps it now (its errors name it)
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from .qos import output_qos

    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    window = WatchWindow()
    node = Node("rollergear_watch")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    for channel in watched_channels():  # the outputs' table (:mod:`base.output_channels`)
        node.create_subscription(Float64, channel.absolute_topic(namespace),
                                 lambda raw, c=channel.name: window.add(c, raw), qos, raw=True)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(STATUS_NAME):
                window.add_status(status.level[0] if isinstance(status.level, bytes) else int(status.level),
                                  status.message, {kv.key: kv.value for kv in status.values})

    node.create_subscription(DiagnosticArray, Topic.DIAGNOSTICS, on_diagnostics, 10)
    for channel in trace_channels():  # latched: the last result, also one made before watch started
        node.create_subscription(
            DiagnosticStatus, channel.absolute_topic(namespace),
            lambda msg: window.add_traced(msg.level[0] if isinstance(msg.level, bytes) else int(msg.level),
                                          msg.message), output_qos(channel))
    # the events executor takes a message for a few µs: a watcher of four 1 kHz topics keeps up,
    # where the single-threaded one falls behind on a slower machine
    executor = EventsExecutor()
    executor.add_node(node)
    topic_of_loss = OUTPUT_CHANNELS["loss_torque"].absolute_topic(namespace)
    print(
        f"watching {ns or '/'} (outputs and /diagnostics), a line every {period_s:g} s; Ctrl-C to stop", file=sys.stderr
    )
    lines = 0
    writer = None
    status = 0
    try:
        start = time.monotonic()
        while count <= 0 or lines < count:
            deadline = start + (lines + 1) * period_s
            while (left := deadline - time.monotonic()) > 0:
                executor.spin_once(timeout_sec=min(left, 0.1))
            if fmt == "text":
                stamp = time.strftime('%H:%M:%S')
                for traced in window.take_traced():
                    print(f"{stamp}  {traced}", file=out, flush=True)
                print(f"{stamp}  {window.line(period_s, topic_of_loss)}", file=out, flush=True)
            else:
                now = datetime.datetime.now(datetime.UTC)
                row = {"time_utc": now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"} \
                    | window.take(period_s)
                row["traced"] = " | ".join(window.take_traced())
                if fmt == "json":
                    print(json.dumps({k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                      for k, v in row.items()}), file=out, flush=True)
                else:
                    if writer is None:
                        writer = csv.DictWriter(out, fieldnames=list(row), lineterminator="\n")
                        writer.writeheader()
                    writer.writerow({k: _field(row.get(k, "")) for k in writer.fieldnames})
                    out.flush()
            lines += 1
            if until_silent_s > 0 and window.silent_s(period_s) >= until_silent_s:
                print(f"rollergear watch: no status from the node for {window.silent_s(period_s):.0f} s: ended "
                      "(--until-silent)", file=sys.stderr)
                status = 3
                break
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the normal end
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
    return status


def _field(value) -> str | float | int:
    """A CSV field: a figure with no value (NaN) empty."""
    return "" if isinstance(value, float) and not math.isfinite(value) else value
