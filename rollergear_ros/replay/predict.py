"""``predict``: what a planned drive will cost, from a recording, a table or arrays in memory.

A profile is what ``replay`` reads (an MCAP, or a CSV/Parquet/MF4/TDMS through a channel map as for
``import``: planned torque, speed, optionally oil temperature; with measured output torque, a
recorded drive, evaluated as ``replay`` evaluates it) or, for a planner in Python, a mapping of
arrays (a plan).  Its samples are paired as ``replay`` pairs them and go through
:class:`core.prediction.PredictionSums` (the loss and its 95 % band).  No rclpy import::

    from rollergear_ros import predict

    p = predict("plan.parquet", "calibrated.yaml", channels="plan.yaml")
    p = predict({"t_s": t, "torque_nm": torque, "speed_rad_s": speed, "oil_temperature_c": oil},
                "calibrated.yaml")
    p.energy_lost_j, p.energy_band_j
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from ..base.errors import UsageError
from ..base.progress import TimedProgress
from ..core.operating_points import rows_config
from ..core.params import Config, load_config
from ..core.prediction import Prediction, PredictionSums
from ..base.interface import Channel
from ..recordings.messages import TopicMap
from ..recordings.baginfo import inspect_bag
from .inputs import InputProblems, damaged_share, input_batches, paired_plan
from .run import table_rows

__all__ = ["ARRAY_KEYS", "predict"]

#: a profile given as arrays: these keys (``oil_temperature_c`` may be left out)
ARRAY_KEYS = ("t_s", "torque_nm", "speed_rad_s", "oil_temperature_c")
BATCH = 100_000


def predict(profile: str | Path | Mapping[str, np.ndarray], params: str | Path | Config | None = None, *,
            channels: str | Path | None = None, topics: TopicMap = TopicMap(), collect: bool = False,
            show_progress: bool | None = False, warn: Callable[[str], None] | None = None,
            note: Callable[[str], None] | None = None, adapt: bool = True) -> Prediction:
    """The loss energy and power of ``profile`` with their 95 % band (:mod:`core.prediction`).

    ``params``: a parameter file (a calibrated one carries its covariance), a :class:`Config`, or
    None for the package's defaults.  ``channels``: the channel map of a non-ROS table.
    ``collect``: keep each sample's loss power and its standard deviation in the result.
    ``warn`` is told what went wrong while reading (damage, dropped samples), ``note`` what a table's
    import made of it.  ``adapt``: a profile with measured output torque adapts the file's coefficients
    as ``replay`` does where the file says ``estimator.adapt: true`` (False: the coefficients as written).
    """
    from ..sources.importer import as_mcap

    config = params if isinstance(params, Config) else load_config(params)
    if isinstance(profile, Mapping):
        sums = PredictionSums(config, collect, adapt)
        _add_arrays(sums, profile)
        return sums.finish()
    with as_mcap([profile], channels, topics, note=note) as (bag,):
        sums, lost = _add_recording(config, collect, adapt, Path(bag), topics, show_progress,
                                    warn or (lambda text: None))
    result = sums.finish()
    result.lost_share = lost
    return result


def _add_arrays(sums: PredictionSums, profile: Mapping[str, np.ndarray]) -> None:
    """A profile of arrays in memory: times [s], torque [N·m], speed [rad/s], oil temperature [°C]."""
    missing = [k for k in ARRAY_KEYS[:3] if k not in profile]
    unknown = sorted(set(profile) - set(ARRAY_KEYS))
    if missing or unknown:
        raise UsageError(f"a profile of arrays has the keys {', '.join(ARRAY_KEYS)} (oil_temperature_c optional)"
                         + (f"; missing {', '.join(missing)}" if missing else "")
                         + (f"; unknown {', '.join(unknown)}" if unknown else ""))
    arrays = {k: np.asarray(profile[k], dtype=float).ravel() for k in profile}
    n = len(arrays["t_s"])
    if any(len(a) != n for a in arrays.values()):
        raise UsageError("a profile's arrays have one length: " + ", ".join(f"{k} {len(a)}" for k, a in arrays.items()))
    t = arrays["t_s"]
    if not np.isfinite(t).all() or (np.diff(t) < 0).any():
        raise UsageError("a profile's t_s are finite and do not go back")
    t_ns = np.round(t * 1e9).astype(np.int64)
    theta = arrays.get("oil_temperature_c")
    estimator = sums.base_estimator()
    for k in range(0, n, BATCH):
        part = slice(k, k + BATCH)
        sums.add(estimator.process_batch(t_ns[part], arrays["torque_nm"][part], arrays["speed_rad_s"][part],
                                         temperature=None if theta is None else theta[part]))


def _add_recording(config: Config, collect: bool, adapt: bool, bag: Path, topics: TopicMap,
                   show_progress: bool | None, warn: Callable[[str], None]) -> tuple[PredictionSums, float]:
    """A recording's samples, paired and estimated as ``replay`` does, batch by batch: its sums, and
    the share of it lost to damage, as replay states it (nothing readable: a :class:`BagError`).
    A recording with measured output torque (an output torque topic, or joint states, which a rig or
    robot records) is a recorded drive, evaluated as replay does; one without, a plan.  A steady-state
    table's import: its rows as operating points, as replay estimates them."""
    info = inspect_bag(bag)
    plan, pairing, period_s = paired_plan(info, topics)
    recorded = plan.mode == "joint_state" or Channel.OUTPUT_TORQUE in plan.float64.values()
    rows = table_rows(info)
    sums = PredictionSums(rows_config(config) if rows else config, collect, adapt, recorded)
    estimator = sums.base_estimator(pairing=pairing, sample_period_s=period_s, operating_points=rows)
    problems = InputProblems(estimator.counts, plan)
    total = sum(info.counts.get(t, 0) for t in plan.all_topics)
    read = 0
    with TimedProgress("predict", total, "msg", enabled=show_progress) as bar:
        for batch in input_batches(info, plan, BATCH, warn, problems):
            read += batch.message_count
            sums.add(estimator.push_many(batch.codes, batch.t_ns, batch.values, batch.source_ns))
            bar.update(len(batch.codes))
        sums.add(estimator.flush())
    return sums, damaged_share(info, problems, nothing_read=read == 0)
