"""Loading data for calibration: recordings replayed through the bare model (samples with a
measured loss), or steady-state tables (:mod:`sources.tables`, one sample per operating point).

Next to :mod:`replay.run`, whose estimator it runs (no effects, no adaptation).  No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..recordings.messages import TopicMap
from ..sources.channelmap import ChannelMap
from ..base.errors import BagError, InputFileError
from ..base.interface import Metadata
from ..core.model import LossModel
from ..core.effects import EFFECTS
from ..core.params import Config, validate
from ..core.speednoise import reading_noise
from ..sources.tables import SteadyStateTable


@dataclass
class RecordedInputs:
    """One recording's paired samples as replay estimated them, every one in time order: what a
    parameter file is replayed on to say what it does (:func:`file_residual`)."""

    t_ns: np.ndarray
    torque_nm: np.ndarray
    speed_rad_s: np.ndarray
    out_torque_nm: np.ndarray
    out_speed_rad_s: np.ndarray
    temperature_c: np.ndarray


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
    #: the samples left out beyond a plausibility limit, by limit, and the setting to raise ('': none)
    beyond_text: str = ""
    steady_state: bool = False  #: rows of steady-state tables (dwell means), not a time series
    #: rows whose loss is the power balance of their torque readings (:attr:`~sources.tables.SteadyStateTable.readings`)
    torque_readings: bool = False
    ratio: float | None = None  #: the tables' own input/output ratio (one for all), for the calibrated file
    sign_width_rad_s: float = 0.0  #: the estimator's smooth sign width (its effects see the same direction)
    #: a spin test: nothing on the output (its torque 0 throughout), the drive torque is the loss itself
    spin_test: bool = False
    #: the model's parts at each sample (:meth:`~core.model.LossModel.parts`): what a model parameter scales
    parts: dict[str, np.ndarray] = field(default_factory=dict)
    out_torque: np.ndarray | None = None  #: the measured output torque of each sample (NaN: none)
    out_speed: np.ndarray | None = None  #: the measured output speed of each sample (NaN: none, the ratio's)
    speed_ratio: float = 1.0  #: input/output speed ratio where the output speed is not measured
    speed_noise_text: str = ""  #: the speed noise the estimates were made with, and where it came from
    #: the largest share of a recording lost to damage (:func:`base.errors.lost_share`)
    lost_share: float = 0.0
    #: parameter -> the recordings' value the samples were read at instead of the parameter file's far-off
    #: one (the speed noise, the gearbox ratio: :func:`load_samples`); the calibrated file carries them
    overrides: dict[str, float] = field(default_factory=dict)
    ratio_text: str = ""  #: what was done about the ratio, when it was overridden
    #: each recording's paired samples (None: rows of tables), and each analysed sample's index in its
    #: recording's: where a parameter file is replayed on them
    recordings: list[RecordedInputs] | None = None
    source_index: np.ndarray | None = None
    #: each recording's place in the list given (``bag_id`` counts them in :func:`recording_key` order)
    given_order: list[int] | None = None
    #: the direction the estimate took at each sample (:attr:`~core.estimator.BatchEstimate.sign`; None:
    #: the smooth sign of the speed, as for a table's rows)
    sign: np.ndarray | None = None

    def given_index(self, bag: int) -> int:
        """Recording ``bag``'s place in the list it was given in."""
        return self.given_order[bag] if self.given_order is not None else bag

    @property
    def residual(self) -> np.ndarray:
        return self.measured_loss - self.model_loss

    @property
    def load_torque(self) -> np.ndarray | None:
        """The torque each sample passes through the gearbox, to tell its loads apart: a recording's
        measured output torque (None: not measured); a table row's output torque referred to the input,
        ``T_in − L·sgn ω`` -- its power balance, whichever of output torque, efficiency or loss column
        the row came with."""
        if self.steady_state:
            return self.torque - self.measured_loss * np.sign(self.speed)
        return self.out_torque

    def select(self, keep: np.ndarray) -> SampleData:
        """The samples where ``keep`` (a boolean mask) holds."""
        from dataclasses import replace

        def pick(a):
            return None if a is None else a[keep]

        return replace(self, t_ns=self.t_ns[keep], bag_id=self.bag_id[keep], torque=self.torque[keep],
                       speed=self.speed[keep], temperature=self.temperature[keep],
                       measured_loss=self.measured_loss[keep], model_loss=self.model_loss[keep],
                       fr_part=self.fr_part[keep], parts={k: v[keep] for k, v in self.parts.items()},
                       out_torque=pick(self.out_torque), out_speed=pick(self.out_speed),
                       source_index=pick(self.source_index), sign=pick(self.sign))


#: a time slice ``[start, end)`` of a recording [ns since 1970] (None: open)
TimeSpan = tuple[int | None, int | None]


def load_samples(bags: Sequence[str | Path], config: Config, topics: TopicMap = TopicMap(),
                 warn: Callable[[str], None] | None = None, min_speed_rad_s: float = 0.0,
                 progress: bool = False, windows: Sequence[TimeSpan] | None = None) -> SampleData:
    """Replay bags through the bare model (no effects, no adaptation) and keep samples with a measured
    loss: down to 3 × the speed reading's noise from standstill (closer, the direction is not known and
    the estimator gives no measured loss), or ``min_speed_rad_s``.

    The speed reading's noise is the parameter file's, or learned (``auto``).  A file's value
    :data:`SPEED_NOISE_FACTOR` times off the noise the recordings' speeds show (their second
    differences, :func:`~core.speednoise.reading_noise`) is a rig nuisance the file has wrong: the
    recordings are replayed again at theirs, said in :attr:`SampleData.speed_noise_text`, and
    :attr:`SampleData.overrides` carries it into the calibrated file.

    The same for the gearbox ratio (:func:`recordings_ratio`): where the recordings' own ratio is not the
    file's, they are read again at theirs (said in :attr:`SampleData.ratio_text`; the paper's model
    takes the balls' kinematics from the geometry, not from this ratio).

    ``windows``: per bag, the time slice ``[start, end)`` (ns, None: open) whose samples are read -- only its
    chunks (and a lead-in) are, as a fleet's window of a long log (:class:`~replay.window.TimeWindow`)."""
    data = _load(bags, config, topics, warn, min_speed_rad_s, progress, windows)
    overrides: dict[str, float] = {}
    given = config.estimator.speed_noise_rad_s
    if isinstance(given, float) and not data.steady_state:
        seen = reading_noise(data.speed, data.bag_id)
        if math.isfinite(seen) and seen > 0 and not 1.0 / SPEED_NOISE_FACTOR <= given / seen <= SPEED_NOISE_FACTOR:
            overrides["estimator.speed_noise_rad_s"] = measured = float(f"{seen:.3g}")
            noise_text = (f"{measured:.3g} rad/s, what the recordings' speeds show (their second differences): the "
                          f"parameter file's {given:.3g} rad/s is {given / seen:.3g} × that; the samples were read "
                          "again at the recordings' and the calibrated file says it")
    ratio = recordings_ratio(data, config.estimator.min_speed_for_efficiency_rad_s)
    if ratio is not None:
        overrides["gearbox.ratio"] = ratio
    if not overrides:
        return data
    again = _load(bags, config.with_values(overrides), topics, None, min_speed_rad_s, progress, windows)
    again.overrides = overrides
    if "estimator.speed_noise_rad_s" in overrides:
        again.speed_noise_text = noise_text
    if ratio is not None:
        again.ratio_text = (f"the recordings' speed ratio is {ratio:.6g} (median motor/output speed), the parameter "
                            f"file's gearbox.ratio gives {data.speed_ratio:.6g}: below "
                            f"{config.estimator.min_speed_for_efficiency_rad_s:g} rad/s the measured loss is the "
                            "torque balance at the file's ratio, so the samples were read again at the recordings' "
                            "and the calibrated file says it")
    return again


#: the recordings' speed ratio may differ from the parameter file's by this share (a roller gearing's
#: creep, rounding of a stated ratio) before the two are taken to describe different gearboxes
RATIO_TOLERANCE = 0.02


def recordings_ratio(data: SampleData, min_speed_rad_s: float) -> float | None:
    """The recordings' own speed ratio where it is not the parameter file's (beyond
    :data:`RATIO_TOLERANCE`), else None.

    Where the drive turns fast enough (``|ω| ≥ min_speed_rad_s``) the measured loss takes the output
    speed the recordings hold (measured, or the channel map's ratio's); below it, where the quotient
    of two speeds is noise, the torque balance ``(T_in − T_out/ratio)·sgn ω`` with the file's
    ``gearbox.ratio``.  Two ratios make two losses on either side of that speed: a fit of the slow
    samples' error, not of the gearbox.  A spin test (no output torque) is the same under any ratio.
    """
    if data.steady_state or data.spin_test or data.out_speed is None or data.out_torque is None:
        return None
    moving = (np.isfinite(data.out_speed) & (data.out_speed != 0) & np.isfinite(data.out_torque)
              & (np.abs(data.speed) >= min_speed_rad_s))
    if np.count_nonzero(moving) < 10:
        return None
    ratio = float(f"{float(np.median(data.speed[moving] / data.out_speed[moving])):.6g}")
    if ratio <= 0 or abs(ratio / data.speed_ratio - 1.0) <= RATIO_TOLERANCE:
        return None
    return ratio


#: a parameter file's speed noise this many times off what the recordings show is replaced
SPEED_NOISE_FACTOR = 5.0


def _load(bags, config, topics, warn, min_speed_rad_s, progress, windows=None) -> SampleData:
    from ..replay.run import replay

    base = bare_config(config)
    batches_of_bags = []
    skipped: dict[str, int] = {}
    widths, said, lost, beyond = [], [], [0.0], []
    for i, bag in enumerate(bags):
        window = None if windows is None or windows[i] == (None, None) else windows[i]
        summary, batches = replay(bag, base, topics, show_progress=progress, warn=warn, collect=True,
                                  parameter_changes=False, window_ns=window)  # the bare model throughout
        if summary.interrupted:  # a calibration of part of the data is no answer to the command given
            raise KeyboardInterrupt
        lost.append(summary.lost_share)
        for k, v in summary.skipped.items():
            skipped[k] = skipped.get(k, 0) + v
        batches_of_bags.append(batches)
        widths.append(summary.speed_noise_rad_s)
        said.append(summary.speed_noise_text)
        if summary.beyond_text:
            beyond.append(summary.beyond_text if len(bags) == 1 else f"{bag}: {summary.beyond_text}")
    data = samples_from_estimates(batches_of_bags, config, skipped, min_speed_rad_s, max(widths, default=0.0))
    data.speed_noise_text = "; ".join(dict.fromkeys(said))
    data.lost_share = max(lost)
    data.beyond_text = "; ".join(beyond)
    return data


def bare_config(config: Config) -> Config:
    """``config`` without its effects, adaptation and channel lags: the model whose residual calibration
    analyses, of the samples as recorded (a lag is found in them and written, not assumed)."""
    from ..core.lagalign import LAG_CHANNELS

    return validate({k: v for k, v in config.to_flat().items() if not k.startswith("effects.")}
                    | {f"effects.{n}.enabled": False for n in EFFECTS}  # no oil law either, not the data sheet's
                    | {"estimator.adapt": False} | {f"estimator.{c}_lag_s": 0.0 for c in LAG_CHANNELS})


def samples_from_estimates(batches_of_bags: Sequence[Sequence], config: Config, skipped: dict[str, int] | None = None,
                           min_speed_rad_s: float = 0.0, sign_width_rad_s: float | None = None) -> SampleData:
    """The samples with a measured loss of estimates made with :func:`bare_config` (a list of
    :class:`~core.estimator.BatchEstimate` per recording; ``bag_id`` its index): what
    :func:`load_samples` returns for recordings, and the live tracer for the node's own samples;
    ``sign_width_rad_s``: the speed noise the estimates were made with (None: the parameter file's)."""
    if sign_width_rad_s is None:
        noise = config.estimator.speed_noise_rad_s
        sign_width_rad_s = noise if isinstance(noise, float) else 0.0
    model = LossModel(config.gearbox, enabled=config.estimator.paper_model)
    parts = []
    recordings, index = [], []
    loaded = False  # any output torque other than 0 (else: a spin test)
    # the recordings in an order of their own, not the order given: what is decided across them (folds,
    # changes between recordings) is the same for the same recordings listed in any order
    given = list(range(len(batches_of_bags)))
    if len(given) > 1:  # one recording: nothing to order (its key reads every sample)
        given.sort(key=lambda k: _inputs_key(batches_of_bags[k]))
    batches_of_bags = [batches_of_bags[k] for k in given]
    for i, batches in enumerate(batches_of_bags):
        offset = 0
        inputs: list[tuple[np.ndarray, ...]] = []
        for b in batches:
            m = len(b.t_ns)
            ok = np.isfinite(b.measured_loss_nm) & (np.abs(b.speed_rad_s) >= min_speed_rad_s)
            n = int(ok.sum())
            temp = b.temperature_c if b.temperature_c is not None else np.full(m, np.nan)
            out_t_all = b.out_torque_nm if b.out_torque_nm is not None else np.full(m, np.nan)
            out_w_all = b.out_speed_rad_s if b.out_speed_rad_s is not None else np.full(m, np.nan)
            inputs.append((b.t_ns, b.torque_nm, b.speed_rad_s, out_t_all, out_w_all, temp))
            parts.append((b.t_ns[ok], np.full(n, i), b.torque_nm[ok], b.speed_rad_s[ok], temp[ok],
                          b.measured_loss_nm[ok], np.abs(b.loss_torque_nm[ok]), out_t_all[ok], out_w_all[ok],
                          b.sign[ok]))
            index.append(offset + np.flatnonzero(ok))
            offset += m
            if b.out_torque_nm is not None and np.any(b.out_torque_nm[ok] != 0):
                loaded = True
        recordings.append(RecordedInputs(*(np.concatenate([part[j] for part in inputs]) if inputs else
                                           np.zeros(0) for j in range(6))))
    if not parts or sum(len(p[0]) for p in parts) == 0:
        raise BagError("no samples with a measured output torque and |speed| >= "
                       f"{max(min_speed_rad_s, 3 * sign_width_rad_s):g} rad/s: calibration needs "
                       "the output torque topic")
    cols = [np.concatenate([p[j] for p in parts]) for j in range(10)]
    return SampleData(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6],
                      model.fr_part(cols[2], cols[3]), dict(skipped or {}),
                      parts=model.parts(cols[2], cols[3]) if model.enabled else {},
                      sign_width_rad_s=sign_width_rad_s, spin_test=not loaded,
                      out_torque=cols[7], out_speed=cols[8], speed_ratio=config.gearbox.ratio_effective,
                      recordings=recordings, source_index=np.concatenate(index), given_order=given, sign=cols[9])


def recording_key(first_ns: int, torque: np.ndarray, speed: np.ndarray) -> tuple:
    """What orders recordings (or a table's groups) by themselves: first stamp, sample count, then their
    readings' sums of magnitudes to 9 digits (not their last bits: a recording read on another machine,
    or with a reading 1 ulp off, keeps its place)."""
    def digest(x: np.ndarray) -> str:
        x = np.asarray(x, dtype=np.float64)
        return f"{float(np.sum(np.abs(x[np.isfinite(x)]))):.9g}"

    return int(first_ns), len(torque), digest(torque), digest(speed)


def _inputs_key(batches: Sequence) -> tuple:
    """:func:`recording_key` of one recording's estimates."""
    if not batches or not sum(len(b.t_ns) for b in batches):
        return 0, 0, "", ""
    return recording_key(int(batches[0].t_ns[0]), np.concatenate([b.torque_nm for b in batches]),
                         np.concatenate([b.speed_rad_s for b in batches]))


def file_residual(data: SampleData, config: Config) -> np.ndarray:
    """What the parameter file ``config`` leaves of each analysed sample's measured loss (NaN where it
    measures none): the one forward path -- each recording replayed through the
    :class:`~core.estimator.Estimator` of the file as written (its channel lags, effects, sensor errors,
    speed noise and online adaptation), from its first sample, exactly as ``replay`` estimates it; rows of tables
    each on their own, as operating points (nothing adapts between them, nothing is learned from them),
    against the table's own measured loss."""
    from ..core.estimator import Estimator
    from ..core.operating_points import rows_config

    if data.recordings is None or data.source_index is None:  # rows: the table's own measured loss
        est = Estimator(rows_config(config), operating_points=True).process_batch(
            np.arange(len(data.t_ns), dtype=np.int64), data.torque, data.speed, temperature=data.temperature,
            breakdown=False)
        out = np.full(len(data.t_ns), np.nan)
        kept = est.t_ns.astype(np.intp)
        out[kept] = data.measured_loss[kept] - (est.loss_magnitude_nm + est.sensor_nm)
        return out
    out = np.full(len(data.t_ns), np.nan)
    for i, rec in enumerate(data.recordings):
        mine = np.flatnonzero(data.bag_id == i)
        if not len(mine):
            continue
        est = Estimator(config).estimate_paired(rec.t_ns, rec.torque_nm, rec.speed_rad_s, rec.out_torque_nm,
                                                rec.out_speed_rad_s, rec.temperature_c)
        if est is None:
            continue
        if len(est.t_ns) == len(rec.t_ns):  # replay kept only samples the estimator takes
            residual = est.residual_nm
        else:
            residual = np.full(len(rec.t_ns), np.nan)
            residual[np.searchsorted(rec.t_ns, est.t_ns)] = est.residual_nm
        out[mine] = residual[data.source_index[mine]]
    return out


def table_samples(paths: Sequence[str | Path], config: Config, warn: Callable[[str], None] | None = None,
                  cmap: ChannelMap | None = None) -> SampleData:
    """Steady-state tables as samples: one per row, its measured loss the table's (a dwell mean).

    Rows outside the estimator's plausible range (``estimator.max_abs_*``) are skipped and
    counted, as the estimator skips such samples; the model is the paper's unless
    ``estimator.paper_model`` switches it off.  Each file, and each value of the map's group
    column, is a gearbox state of its own (``bag_id``).  An MCAP that ``import`` made of a table is
    read back as that table's rows (:func:`imported_rows`).
    """
    from ..replay.run import imported_table
    from ..sources.tables import read_table

    model = LossModel(config.gearbox, enabled=config.estimator.paper_model)
    est = config.estimator
    parts = []
    implausible = 0
    ratios: set[float | None] = set()
    states: dict[tuple[int, str], int] = {}
    readings = True
    for i, path in enumerate(paths):
        record = imported_table(path)
        table = (imported_rows(path, record, config, warn) if record is not None else
                 read_table(path, cmap, config.gearbox.ratio_effective))
        readings = readings and table.readings
        if table.dropped and warn:
            warn(f"{path}: {table.dropped} rows without a finite torque, speed or loss: skipped")
        keep = est.plausible(table.torque_nm, table.speed_rad_s)
        if np.count_nonzero(~keep) > MAX_BEYOND_SHARE * len(keep):  # the table is another gearbox's size
            need_t = float(np.max(np.abs(table.torque_nm)))
            need_w = float(np.max(np.abs(table.speed_rad_s)))
            raise InputFileError(
                f"{path}: {np.count_nonzero(~keep)} of {len(keep)} rows lie beyond the estimator's plausible range "
                f"(estimator.max_abs_torque_nm {est.max_abs_torque_nm:g} N·m, max_abs_speed_rad_s "
                f"{est.max_abs_speed_rad_s:g} rad/s; the table reaches {need_t:.6g} N·m and {need_w:.6g} rad/s): "
                f"raise them in the parameter file (--params) to calibrate this table, e.g. "
                f"estimator.max_abs_torque_nm: {_round_up(need_t):g}, max_abs_speed_rad_s: {_round_up(need_w):g}")
        ratios.add(table.ratio)
        if not keep.all():
            implausible += int(np.count_nonzero(~keep))
            if warn:
                warn(f"{path}: {np.count_nonzero(~keep)} of {len(keep)} rows beyond estimator.max_abs_torque_nm "
                     f"({est.max_abs_torque_nm:g} N·m) or max_abs_speed_rad_s: skipped (raise them in the "
                     "parameter file for this gearbox)")
        group = table.group if table.group is not None else np.full(len(keep), "")
        state = np.array([states.setdefault((i, g), len(states)) for g in group[keep]], dtype=np.int64)
        parts.append((table.speed_rad_s[keep], table.torque_nm[keep], table.loss_nm[keep], table.temperature_c[keep],
                      state))
    speed, torque, loss, temperature, bag_id = (np.concatenate([p[j] for p in parts]) for j in range(5))
    if len(speed) == 0:
        raise BagError(f"no rows of {', '.join(map(str, paths))} within the estimator's plausible range")
    # nominal times 1 s apart: every row is its own block and dwell (see blocks.make_blocks)
    t_ns = np.arange(len(speed), dtype=np.int64) * 1_000_000_000
    data = SampleData(t_ns, bag_id, torque, speed, temperature, loss, model.loss_magnitude(torque, speed),
                      model.fr_part(torque, speed), {"implausible": implausible} if implausible else {},
                      steady_state=True, ratio=ratios.pop() if len(ratios) == 1 else None,
                      torque_readings=readings, parts=model.parts(torque, speed) if model.enabled else {})
    # nothing on the output in any row (its loss is all of its drive torque, to rounding): a spin test
    data.spin_test = bool(np.all(np.abs(data.load_torque) <= SPIN_TOLERANCE * np.abs(torque)))
    return data


def imported_rows(path: str | Path, record: dict[str, str], config: Config,
                  warn: Callable[[str], None] | None = None) -> SteadyStateTable:
    """The rows of a steady-state table that ``import`` wrote as an MCAP (``record``: its import
    metadata), read back through replay as replay estimates them: each sample an operating point, its
    loss the power balance of its torques -- the table's own loss, to rounding.  The table's ratio and
    whether its loss was its torque readings' come from the metadata.  Every row comes back, those
    beyond the plausible range too: :func:`table_samples` judges them as it judges a table's own."""
    from ..core.paramspecs import spec_by_name
    from ..replay.run import replay

    specs = spec_by_name()
    every_row = bare_config(config).with_values({name: specs[name].high for name in (
        "estimator.max_abs_torque_nm", "estimator.max_abs_speed_rad_s")})
    summary, batches = replay(path, every_row, collect=True, parameter_changes=False, show_progress=False,
                              warn=warn)
    if summary.interrupted:
        raise KeyboardInterrupt

    def column(name: str) -> np.ndarray:
        parts = [getattr(b, name) if getattr(b, name) is not None else np.full(len(b.t_ns), np.nan) for b in batches]
        return np.concatenate(parts) if parts else np.zeros(0)

    loss = column("measured_loss_nm")
    ok = np.isfinite(loss)
    ratio = record.get(Metadata.IMPORT_RATIO, "")
    return SteadyStateTable(Path(path), column("speed_rad_s")[ok], column("torque_nm")[ok], loss[ok],
                            column("temperature_c")[ok], np.flatnonzero(ok), dropped=int(np.count_nonzero(~ok)),
                            ratio=float(ratio) if ratio else None,
                            readings=record.get(Metadata.IMPORT_READINGS) == "true")


#: a table row whose output torque referred to the input is within this share of its drive torque has
#: nothing on the output (its loss computed from an output torque of 0 differs from ``|T_in|`` by rounding)
SPIN_TOLERANCE = 1e-9
MAX_BEYOND_SHARE = 0.25  #: a table with more of its rows beyond the plausible range is refused, not cut


def _round_up(value: float) -> float:
    """A limit just above ``value`` with two significant digits (12 345 -> 13 000)."""
    if value <= 0:
        return 1.0
    scale = 10 ** (math.floor(math.log10(value)) - 1)
    return math.floor(value / scale + 1) * scale


LOADED_SHARE = 0.2  #: a sample is loaded when its |T| is at least this share of the 95th percentile of |T|


def power_balance_warning(data: SampleData) -> str | None:
    """A line saying so when the measured loss exceeds the input torque in most loaded samples.

    A passive gearbox loses less than it takes in: ``|T_loss,meas| < |T_in|`` except at a light
    load.  When most samples with ``|T| ≥ 20 %`` of the 95th percentile of ``|T|`` break that, the
    output torque is almost surely in the opposite sign convention (power out counted negative:
    the measured loss is then about ``2·|T|``), or the ratio or the output's unit is wrong -- a
    calibration would fit that as an effect.  None when the balance is plausible.
    """
    torque = np.abs(data.torque)
    if len(torque) == 0:
        return None
    loaded = torque >= LOADED_SHARE * np.percentile(torque, 95)
    loaded &= torque > 0
    if np.count_nonzero(loaded) < 10:
        return None
    share = np.abs(data.measured_loss[loaded]) / torque[loaded]
    over = float(np.mean(share > 1.0))
    if over <= 0.5:
        return None
    return (f"the measured loss exceeds the input torque in {100 * over:.0f} % of the loaded samples (median "
            f"|loss|/|T| = {float(np.median(share)):.2f}): the output torque is likely in the opposite sign "
            "convention (power out must be positive: scale: -1 in the channel map), or the ratio or the output's "
            "unit is wrong")
