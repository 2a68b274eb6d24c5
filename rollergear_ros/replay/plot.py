"""The replay's summary picture, for people without the viewer: one PNG per replayed recording.

Left, over time: the loss torque (mean per time bin, with the bin's range; where output torque
was measured, the estimate drawn over the measured loss), the efficiency in % (the model's over the
measured per sample, and the measured over ``node.efficiency_window_s`` with ± 2 standard
uncertainties shaded), the residual apart;
the residual change detector's alarms marked on every time axis.  Right: the recording's operating
points over the efficiency map of the model the replay used (the paper's model plus the accepted
effects, :func:`core.operating_points.evaluate_points`), speed in rpm as ``rollergear map`` draws it.

:class:`SummaryTrace` collects what the picture needs while the replay runs, in bounded memory
(a fixed number of time bins; an evenly thinned sample of operating points), so a day-long
recording draws as fast as a minute.  No rclpy import.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..base.atomic import save_figure
from ..base.errors import UsageError
from ..core.batchpath import BatchEstimate
from ..base.interface import RPM_PER_RAD_S
from ..core.operating_points import evaluate_points, only, temperature_effects
from ..core.params import Config

__all__ = ["SummaryTrace", "plot_summary", "summary_figure"]

#: time bins of the traces at least (a PNG is ~1 500 px wide)
TIME_BINS = 1000
#: operating points drawn over the map at most
MAX_POINTS = 20_000
#: grid of the efficiency map behind the operating points
MAP_GRID = 61


class SummaryTrace:
    """Per time bin: count, sum, min and max of the loss torque magnitude, the efficiency, the
    measured loss and the residual; and every ``stride``-th sample's operating point.

    The bins start 10 ms wide at the first sample and double (neighbours merged) whenever the
    recording outgrows ``2·bins`` of them, so the trace holds ``bins``–``2·bins`` bins whatever
    its length, without knowing it beforehand.
    """

    SERIES = ("loss_nm", "efficiency_pct", "measured_nm", "residual_nm", "measured_efficiency_pct",
              "window_pct", "window_u_pct")

    def __init__(self, samples: int, bins: int = TIME_BINS, max_points: int = MAX_POINTS) -> None:
        self.start_ns: int | None = None
        self.width_ns = 10_000_000
        self.capacity = 2 * bins
        self.stride = max(1, math.ceil(samples / max_points))
        self._seen = 0
        self.count = {k: np.zeros(self.capacity) for k in self.SERIES}
        self.total = {k: np.zeros(self.capacity) for k in self.SERIES}
        self.low = {k: np.full(self.capacity, np.inf) for k in self.SERIES}
        self.high = {k: np.full(self.capacity, -np.inf) for k in self.SERIES}
        self.points: list[tuple[np.ndarray, np.ndarray]] = []
        self.temperatures: list[np.ndarray] = []
        self.alarms_t_ns: set[int] = set()  #: the change detector's alarms (sample times)

    def _coarsen(self) -> None:
        """Double the bin width: bins 2k and 2k+1 become bin k."""
        half = self.capacity // 2
        for stats, merge, empty in ((self.count, np.add, 0.0), (self.total, np.add, 0.0),
                                    (self.low, np.minimum, np.inf), (self.high, np.maximum, -np.inf)):
            for key, v in stats.items():
                stats[key] = np.concatenate([merge(v[0::2], v[1::2]), np.full(half, empty)])
        self.width_ns *= 2

    def add(self, b: BatchEstimate) -> None:
        """One batch of estimates (in time order across batches, as the estimator gives them)."""
        n = len(b.t_ns)
        self.alarms_t_ns.update(b.alarms_t_ns)
        if not n:
            return
        t = np.asarray(b.t_ns, np.int64)
        if self.start_ns is None:
            self.start_ns = int(t[0])
        while (int(t.max()) - self.start_ns) // self.width_ns >= self.capacity:
            self._coarsen()
        where = np.clip((t - self.start_ns) // self.width_ns, 0, self.capacity - 1)
        values = {"loss_nm": np.abs(b.loss_torque_nm), "efficiency_pct": 100.0 * b.efficiency,
                  "measured_nm": b.measured_loss_nm, "residual_nm": b.residual_nm,
                  "measured_efficiency_pct": b.efficiency_measured, "window_pct": b.efficiency_measured_window,
                  "window_u_pct": b.efficiency_measured_uncertainty}
        for key, v in values.items():
            if v is None:
                continue
            if key in ("measured_efficiency_pct", "window_pct", "window_u_pct"):
                v = 100.0 * v
            ok = np.isfinite(v)
            if not ok.any():
                continue
            w, v = where[ok], v[ok]
            self.count[key] += np.bincount(w, minlength=self.capacity)
            self.total[key] += np.bincount(w, weights=v, minlength=self.capacity)
            np.minimum.at(self.low[key], w, v)
            np.maximum.at(self.high[key], w, v)
        take = np.arange((-self._seen) % self.stride, n, self.stride)
        self._seen += n
        self.points.append((b.speed_rad_s[take], b.torque_nm[take]))
        if b.temperature_c is not None:
            theta = b.temperature_c[take]
            self.temperatures.append(theta[np.isfinite(theta)])

    def series(self, key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(time_s, mean, low, high)`` of the bins that hold samples of ``key``."""
        c = self.count[key]
        ok = c > 0
        t_s = (np.flatnonzero(ok) + 0.5) * self.width_ns * 1e-9
        return t_s, self.total[key][ok] / c[ok], self.low[key][ok], self.high[key][ok]

    def operating_points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(speed_rad_s, torque_nm)`` of the thinned samples."""
        if not self.points:
            return np.empty(0), np.empty(0)
        return (np.concatenate([p[0] for p in self.points]), np.concatenate([p[1] for p in self.points]))

    def alarm_times_s(self) -> list[float]:
        """The alarms in seconds since the trace's first sample (the time axes' origin)."""
        if self.start_ns is None:
            return []
        return [(t - self.start_ns) * 1e-9 for t in sorted(self.alarms_t_ns)]

    def median_temperature_c(self) -> float | None:
        t = np.concatenate(self.temperatures) if self.temperatures else np.empty(0)
        return float(np.median(t)) if len(t) else None


def _efficiency_map(config: Config, speed: np.ndarray, torque: np.ndarray, temperature_c: float | None):
    """The efficiency [%] of the replay's model on a grid over the visited points, and a note of
    what was left out (effects needing a temperature the recording does not have)."""
    w_hi = max(float(np.max(np.abs(speed))), 1.0) * 1.05
    t_hi = max(float(np.max(np.abs(torque))), 1.0) * 1.05
    w_lo = -w_hi if (speed < 0).any() else 0.0
    t_lo = -t_hi if (torque < 0).any() else 0.0
    ws, ts = np.linspace(w_lo, w_hi, MAP_GRID), np.linspace(t_lo, t_hi, MAP_GRID)
    w, t = np.meshgrid(ws, ts, indexing="ij")
    note = ""
    needing = temperature_effects(config)
    if needing and temperature_c is None:
        config = only(config, tuple(n for n in config.effects.enabled() if n not in needing))
        note = f" (without {', '.join(needing)}: no oil temperature recorded)"
    try:
        eta = evaluate_points(config, t.ravel(), w.ravel(), temperature_c).efficiency.reshape(w.shape)
    except UsageError:
        return ws, ts, None, note
    return ws, ts, 100.0 * eta, note + (f" at {temperature_c:.0f} °C" if temperature_c is not None and needing else "")


def plot_summary(trace: SummaryTrace, config: Config, png_path: str | Path, title: str) -> Path:
    """Draw the summary picture (see the module docstring) to ``png_path``."""
    fig = summary_figure(trace, config, title)  # selects the Agg backend first
    import matplotlib.pyplot as plt

    out = Path(png_path)
    try:  # whole or not at all: an interrupt leaves no half-written picture
        save_figure(fig, out)
    finally:
        plt.close(fig)
    return out


def summary_figure(trace: SummaryTrace, config: Config, title: str):
    """The summary picture as a matplotlib figure (Agg): time axes left, the map right."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_residual = trace.count["residual_nm"].any()
    rows = 3 if has_residual else 2
    fig = plt.figure(figsize=(15, 3 + 2.4 * rows), dpi=100)
    grid = fig.add_gridspec(rows, 2, width_ratios=(1.7, 1))
    axes = [fig.add_subplot(grid[0, 0])]
    axes += [fig.add_subplot(grid[i, 0], sharex=axes[0]) for i in range(1, rows)]

    _time_axes(axes, trace, has_residual)
    axes[-1].set_xlabel("time since the start of the recording [s]")

    ax_map = fig.add_subplot(grid[:, 1])
    _operating_map(fig, ax_map, trace, config)
    ax_map.set_xlabel("drive speed [rpm]")
    ax_map.set_ylabel("drive torque [N·m]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _time_axes(axes: list, trace: SummaryTrace, has_residual: bool) -> None:
    """Loss (measured under estimated), efficiency and residual over time, bin means with their
    range shaded, the change alarms as dashed lines."""

    def draw(ax, key: str, label: str, color: str, zorder: float = 2.0) -> None:
        t_s, mean, low, high = trace.series(key)
        if len(t_s):
            ax.fill_between(t_s, low, high, color=color, alpha=0.2, lw=0, step="mid", zorder=zorder)
            ax.plot(t_s, mean, color=color, lw=0.9, label=label, zorder=zorder + 0.5, gid=key)

    if has_residual:  # the measured loss under, the estimate over it: the estimate stays visible
        draw(axes[0], "measured_nm", "measured loss", "0.45", zorder=2.0)
    draw(axes[0], "loss_nm", "estimated loss (bin mean, range shaded)", "tab:red", zorder=3.0)
    axes[0].set_ylabel("loss torque [N·m]")
    axes[0].legend(fontsize=8, loc="upper right")
    if trace.count["measured_efficiency_pct"].any():  # the measured under the model's, as the loss above
        draw(axes[1], "measured_efficiency_pct", "measured, per sample", "0.45", zorder=2.0)
    draw(axes[1], "efficiency_pct", "model", "tab:blue", zorder=3.0)
    if trace.count["window_pct"].any():
        t_s, eta, _, _ = trace.series("window_pct")
        _, u, _, _ = trace.series("window_u_pct")
        axes[1].fill_between(t_s, eta - 2 * u, eta + 2 * u, color="k", alpha=0.25, lw=0, step="mid", zorder=3.6)
        axes[1].plot(t_s, eta, color="k", lw=1.2, zorder=3.8, gid="window_pct",
                     label="measured over the window (± 2 u shaded)")
    if trace.count["measured_efficiency_pct"].any():  # the range the gearbox lives in, not single samples' noise
        means = [trace.series(k)[1] for k in ("efficiency_pct", "measured_efficiency_pct", "window_pct")]
        finite = np.concatenate([m[np.isfinite(m)] for m in means])
        if len(finite):
            lo, hi = np.percentile(finite, [2, 100])
            pad = max(0.1, 0.1 * (hi - lo))
            axes[1].set_ylim(lo - pad, hi + pad)
    axes[1].set_ylabel("efficiency [%]")
    if trace.count["measured_efficiency_pct"].any():
        axes[1].legend(fontsize=8, loc="lower right")
    if has_residual:
        draw(axes[2], "residual_nm", "residual", "tab:green")
        axes[2].axhline(0.0, color="k", lw=0.5)
        axes[2].set_ylabel("residual: measured −\nestimated loss [N·m]")
    for ax in axes:
        ax.grid(alpha=0.3)
        for i, t_s in enumerate(trace.alarm_times_s()):
            ax.axvline(t_s, color="tab:orange", lw=1.0, ls="--", zorder=4, gid="alarm",
                       label="residual change alarm" if i == 0 and ax is axes[0] else None)
    if trace.alarms_t_ns:
        axes[0].legend(fontsize=8, loc="upper right")


def _operating_map(fig, ax_map, trace: SummaryTrace, config: Config) -> None:
    """The operating points over the model's efficiency map, the quadrants named."""
    speed, torque = trace.operating_points()
    if len(speed):
        ws, ts, eta, note = _efficiency_map(config, speed, torque, trace.median_temperature_c())
        if eta is not None and np.isfinite(eta).any():
            finite = eta[np.isfinite(eta)]
            lo = max(math.floor(float(np.percentile(finite, 2))), 50)
            levels = np.round(np.linspace(lo, 100.0, 11), 2)
            cs = ax_map.contourf(ws * RPM_PER_RAD_S, ts, eta.T, levels=levels, cmap="viridis", extend="min")
            fig.colorbar(cs, ax=ax_map, label="efficiency of the model [%]")
        ax_map.scatter(speed * RPM_PER_RAD_S, torque, s=2, color="tab:red", alpha=0.3,
                       label="operating points (thinned)")
        ax_map.set_title(f"operating points over the efficiency map{note}", fontsize=9)
        ax_map.axhline(0.0, color="w", lw=0.6)
        ax_map.axvline(0.0, color="w", lw=0.6)
        for x, y, label in ((0.98, 0.98, "motoring"), (0.02, 0.02, "motoring"),
                            (0.02, 0.98, "regenerating"), (0.98, 0.02, "regenerating")):
            if (x > 0.5 or (speed < 0).any()) and (y > 0.5 or (torque < 0).any()):
                ax_map.text(x, y, label, transform=ax_map.transAxes, ha="right" if x > 0.5 else "left",
                            va="top" if y > 0.5 else "bottom", fontsize=8, color="w",
                            bbox={"facecolor": "0.2", "alpha": 0.5, "linewidth": 0})
        ax_map.legend(fontsize=8, loc="lower center")
