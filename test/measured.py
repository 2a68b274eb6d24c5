"""The measured data of ``../shared/realdata`` as a user feeds them, and what a written file is judged against.

* :func:`tro_set`: one of the three TRO2021 screw drives (a lead screw, an antibacklash lead screw, a 60:1
  worm) as a DAQ exports a test plan -- its steady runs in the order they were recorded (each file's header
  date), one CSV, each run on its own time stamps after a 2 s pause; every other speed level fitted (the
  slowest and the fastest among them), the levels between held out; signs and units as the authors'
  ``getEposData.m``.  The worm
  also with its payload given as a constant output torque (one load).
* :func:`judge`: ``calibrate`` with the default settings on the fitted runs, the written file replayed on
  the held-out runs (the claim is the file): each held-out run's mean error -- the static map's error at
  an operating point it never saw -- beside no model and the least-squares lines on the fitted runs' means
  (Coulomb + viscous, + offset), which an engineer fits by hand in a minute.

The bench (``bench/measured_tables.py``) prints these; the suite's guard (``test/calibration/
test_measured_sets.py``) fails where a written file is worse than the hand fit.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from helpers import REALDATA

TRO = REALDATA / "tro2021_screw_drives" / "raw" / "experiments"
NOMINAL_TORQUE_NM = 9.84e-3  #: the motors' nominal torque (sd_1dof.m): the unit of the torque column (%)
#: the worm's payload as its output torque: m·g·r (0.096 kg on a 20 mm pulley), against the lifting direction
WORM_PAYLOAD_NM, WORM_RATIO = -0.01884, 60.0
DRIVES = {"driveNo1": "lead screw", "driveNo2": "antibacklash lead screw", "driveNo3": "60:1 worm drive"}
PAUSE_S = 2.0  #: between two runs of an export


@dataclass(frozen=True)
class Run:
    level_rpm: float
    recorded: dt.datetime
    t_s: np.ndarray
    speed_rpm: np.ndarray  #: signed as getEposData.m (−rpm)
    torque_nm: np.ndarray  #: signed as getEposData.m (−% of the nominal torque)


def tro_runs(drive: str) -> list[Run]:
    """A drive's steady-state runs (the 0.096 kg payload), in the order they were recorded.  A value a hand
    overwrote in the repository is read as recorded (its note: "was −8.9")."""
    runs = []
    for path in sorted((TRO / drive / "steady_state" / "0.096kg").glob("*.csv")):
        lines = path.read_text().splitlines()
        recorded = dt.datetime.strptime(lines[0].split(";")[1].split(",")[0], "%Y-%m-%d %H:%M:%S")
        first = next(i for i, line in enumerate(lines) if line.startswith("ms;")) + 1
        rows = []
        for line in lines[first:]:
            fields = line.split(",")[0].split(";")
            if len(fields) < 3:
                continue
            was = re.search(r"was\s*(-?[0-9.]+)", line)
            torque = was.group(1) if was else fields[2]
            rows.append((float(fields[0]) / 1e3, -float(fields[1]), -float(torque) * NOMINAL_TORQUE_NM / 100.0))
        a = np.array(rows)
        runs.append(Run(float(re.sub(r"^n", "-", path.stem)), recorded, a[:, 0], a[:, 1], a[:, 2]))
    return sorted(runs, key=lambda r: (r.recorded, r.level_rpm))


@dataclass
class MeasuredSet:
    """One measured data set as a user feeds it: the fitted runs' file and the held-out runs' file."""

    name: str
    train: Path
    held: Path
    channels: Path
    params: Path
    held_levels: list[float] = field(default_factory=list)


def tro_set(tmp: Path, drive: str, payload: bool = False) -> MeasuredSet:
    """:func:`tro_runs` as two exports (every other |speed| level fitted, slowest first; the rest held out),
    a channel map (output torque 0: a spin test; or the worm's payload) and the parameter file given (the
    paper's model off, the ratio)."""
    runs = tro_runs(drive)
    levels = sorted({abs(r.level_rpm) for r in runs})
    fitted = set(levels[0::2]) | {levels[-1]}  # the slowest and the fastest fitted: the held-out ones lie between
    tag = f"{drive}_{'load' if payload else 'spin'}"
    train = _export([r for r in runs if abs(r.level_rpm) in fitted], tmp / f"{tag}_train.csv")
    held = _export([r for r in runs if abs(r.level_rpm) not in fitted], tmp / f"{tag}_held.csv")
    ratio = WORM_RATIO if drive == "driveNo3" else 1.0
    channels = tmp / f"{tag}_map.yaml"
    channels.write_text("format: timeseries\ntime: {column: time_s, unit: s}\nmotor_torque: {column: torque_nm, "
                        "unit: N*m}\nmotor_speed: {column: speed_rpm, unit: rpm}\n"
                        f"output_torque: {{constant: {WORM_PAYLOAD_NM if payload else 0.0}, unit: N*m}}\n"
                        f"ratio: {ratio}\n")
    params = tmp / f"{tag}_params.yaml"
    params.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false}\n"
                      f"    gearbox: {{ratio: {ratio}}}\n")
    label = DRIVES[drive] + (", the payload as output torque" if payload else "")
    return MeasuredSet(label, train, held, channels, params, sorted(set(levels) - fitted))


def _export(runs: list[Run], path: Path) -> Path:
    """Runs one after another on one clock, each on its own stamps after a pause."""
    with path.open("w") as fh:
        fh.write("time_s,speed_rpm,torque_nm\n")
        start = 0.0
        for r in runs:
            for t, n, q in zip(r.t_s, r.speed_rpm, r.torque_nm):
                fh.write(f"{start + t:.4f},{n:.10g},{q:.10g}\n")
            start += float(r.t_s[-1]) + PAUSE_S
    return path


def runs_of(csv: Path) -> list[np.ndarray]:
    """An export's runs (its pauses), each ``(t, speed [rad/s], torque [N·m])`` rows."""
    a = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    cut = np.r_[0, np.flatnonzero(np.diff(a[:, 0]) > 1.0) + 1, len(a)]
    return [np.column_stack([a[i:j, 0], a[i:j, 1] * np.pi / 30.0, a[i:j, 2]]) for i, j in zip(cut[:-1], cut[1:])]


def hand_fits(train: Path, held: Path) -> dict[str, float]:
    """The least-squares lines on the fitted runs' means (motor torque against speed), each one's RMS error
    over the held-out runs' means: Coulomb + viscous, and + offset (what the done-when names)."""
    def means(csv):
        return np.array([[r[:, 1].mean(), r[:, 2].mean()] for r in runs_of(csv)])

    fit, test = means(train), means(held)

    def columns(w, offset):
        return np.column_stack([np.sign(w), w] + ([np.ones_like(w)] if offset else []))

    out = {}
    for name, offset in (("least squares Coulomb + viscous", False), ("least squares + offset", True)):
        coef, *_ = np.linalg.lstsq(columns(fit[:, 0], offset), fit[:, 1], rcond=None)
        out[name] = float(np.sqrt(np.mean((test[:, 1] - columns(test[:, 0], offset) @ coef) ** 2)))
    return out


@dataclass
class Judged:
    """A written file at the held-out operating points."""

    result: dict  #: calibrate's --json
    written: Path | None
    #: per held-out run: speed [rad/s], mean error [N·m], samples with a measured loss estimated, rows,
    #: rows with a loss estimate
    run_errors: list[tuple[float, float, int, int, int]]
    given_rms: float  #: no model (the parameter file given) at the held-out runs' means
    file_rms: float
    references: dict[str, float]
    #: the per-sample error calibrate claims the written file leaves of the fitted runs, and what replay of
    #: those runs with the file leaves of the same samples
    claimed_nm: float = float("nan")
    replayed_nm: float = float("nan")

    @property
    def estimated(self) -> tuple[int, int]:
        """Held-out samples with a residual, and rows."""
        return sum(r[2] for r in self.run_errors), sum(r[3] for r in self.run_errors)

    @property
    def loss_estimated(self) -> int:
        """Held-out rows with a loss estimate (every one, unless a lag or a limit cost some)."""
        return sum(r[4] for r in self.run_errors)

    def worst(self) -> tuple[float, float]:
        speed, error, *_ = max(self.run_errors, key=lambda r: abs(r[1]) if np.isfinite(r[1]) else np.inf)
        return speed, error


def held_out_run_errors(s: MeasuredSet, params: Path) -> list[tuple[float, float, int, int, int]]:
    """``replay`` of the held-out export with ``params``: per run its speed, the mean of the residual over
    the samples it measures a loss of, their count, the rows and the rows with a loss estimate."""
    from rollergear_ros.core.params import load_config
    from rollergear_ros.replay.run import replay
    from rollergear_ros.sources.importer import as_mcap

    with as_mcap([s.held], s.channels) as bags:
        _summary, batches = replay(bags[0], load_config(params), collect=True, show_progress=False)
    t = np.concatenate([b.t_ns for b in batches]).astype(float) * 1e-9
    r = np.concatenate([b.residual_nm for b in batches])
    w = np.concatenate([b.speed_rad_s for b in batches])
    loss = np.concatenate([b.loss_torque_nm for b in batches])
    cut = np.r_[0, np.flatnonzero(np.diff(t) > 1.0) + 1, len(t)]
    rows = [len(r) for r in runs_of(s.held)]
    out = []
    for k, (i, j) in enumerate(zip(cut[:-1], cut[1:])):
        ok = np.isfinite(r[i:j])
        out.append((float(np.mean(w[i:j])), float(np.mean(r[i:j][ok])) if ok.any() else float("nan"),
                    int(ok.sum()), rows[k] if k < len(rows) else 0, int(np.count_nonzero(np.isfinite(loss[i:j])))))
    return out


def judge(s: MeasuredSet, tmp: Path) -> Judged:
    """``calibrate`` with the defaults on the fitted runs, the written file at the held-out runs."""
    import json
    import subprocess
    import sys

    written = tmp / f"{s.train.stem}_written.yaml"
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", str(s.train), "--channels",
                           str(s.channels), "--params", str(s.params), "--out", str(written), "--json"],
                          capture_output=True, text=True)
    result = json.loads(proc.stdout)
    errors = held_out_run_errors(s, written if result["written"] else s.params)
    given = held_out_run_errors(s, s.params)

    def rms(rows):
        e = np.array([r[1] for r in rows])
        return float(np.sqrt(np.nanmean(e ** 2)))

    judged = Judged(result, written if result["written"] else None, errors, rms(given), rms(errors),
                    hand_fits(s.train, s.held))
    if result["written"]:
        judged.claimed_nm = result["sample_level_errors"]["after"]["rmse_nm"]
        judged.replayed_nm = replayed_error(s, written)
    return judged


def replayed_error(s: MeasuredSet, params: Path) -> float:
    """What ``replay`` of the fitted runs with ``params`` leaves of the samples calibrate analysed (RMS)."""
    from rollergear_ros.calibration.samples import load_samples
    from rollergear_ros.core.params import load_config
    from rollergear_ros.replay.run import replay
    from rollergear_ros.sources.importer import as_mcap

    with as_mcap([s.train], s.channels) as bags:
        analysed = load_samples(bags, load_config(s.params)).t_ns
        _summary, batches = replay(bags[0], load_config(params), collect=True, show_progress=False)
    t = np.concatenate([b.t_ns for b in batches])
    r = np.concatenate([b.residual_nm for b in batches])[np.searchsorted(t, analysed)]
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r * r)))
