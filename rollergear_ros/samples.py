"""Loading recordings for calibration: replay through the bare model, keep samples with a measured loss.

Next to :mod:`.replay`, whose estimator it runs (no effects, no adaptation).  No rclpy import.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .bag import TopicMap
from .errors import BagError
from .model import LossModel
from .params import Config, validate


@dataclass
class SampleData:
    """Per-sample inputs and measured loss of one or more bags (valid samples only)."""

    t_ns: np.ndarray
    bag_id: np.ndarray
    torque: np.ndarray
    speed: np.ndarray
    temperature: np.ndarray
    measured_loss: np.ndarray
    model_loss: np.ndarray
    fr_part: np.ndarray
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def residual(self) -> np.ndarray:
        return self.measured_loss - self.model_loss


def load_samples(bags: Sequence[str | Path], config: Config, topics: TopicMap = TopicMap(),
                 warn: Callable[[str], None] | None = None, min_speed_rad_s: float = 2.0,
                 progress: bool = False) -> SampleData:
    """Replay bags through the bare model (no effects, no adaptation) and keep samples with a measured loss."""
    from .replay import replay

    base = validate({k: v for k, v in config.to_flat().items() if not k.startswith("effects.")}
                    | {"estimator.adapt": False})
    model = LossModel(base.gearbox)
    parts = []
    skipped: dict[str, int] = {}
    for i, bag in enumerate(bags):
        summary, batches = replay(bag, base, topics, show_progress=progress, warn=warn, collect=True)
        for k, v in summary.skipped.items():
            skipped[k] = skipped.get(k, 0) + v
        for b in batches:
            ok = np.isfinite(b.measured_loss_nm) & (np.abs(b.speed_rad_s) >= min_speed_rad_s)
            temp = b.temperature_c if b.temperature_c is not None else np.full(len(b.t_ns), np.nan)
            parts.append((b.t_ns[ok], np.full(int(ok.sum()), i), b.torque_nm[ok], b.speed_rad_s[ok], temp[ok],
                          b.measured_loss_nm[ok], np.abs(b.loss_torque_nm[ok])))
    if not parts or sum(len(p[0]) for p in parts) == 0:
        raise BagError("no samples with a measured output torque and |speed| >= "
                         f"{min_speed_rad_s:g} rad/s: calibration needs the output torque topic")
    cols = [np.concatenate([p[j] for p in parts]) for j in range(7)]
    return SampleData(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6],
                      model.fr_part(cols[2], cols[3]), skipped)
