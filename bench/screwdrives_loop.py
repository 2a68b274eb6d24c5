#!/usr/bin/env python3
"""``calibrate`` on three measured screw drives it has never seen, held-out speed levels, as a Markdown table.

The data: the steady-state friction tests of Mablekos-Alexiou, da Cruz, Bergeles, "Friction-Inclusive
Modeling of Sliding Contact Transmission Systems in Robotics", IEEE T-RO 37(4), 2021 -- the public
repository https://github.com/RViMLab/TRO2021-Dynamic-Modelling (MIT), folder ``experiments/``: a
lead screw (drive 1), an antibacklash lead screw (drive 2) and a 60:1 worm drive (drive 3), each a
Maxon motor on an EPOS controller lifting and lowering one 0.096 kg payload at steady speeds of
±1…200 rpm, 500 samples per speed (the controller's averaged velocity in whole rpm and its averaged
torque in % of the 9.84 mN·m nominal torque, signs as the authors' ``getEposData.m``).

Each drive is calibrated as a spin test (output torque 0: the payload shows as the torque sensor's
offset, a constant in the drive torque), the paper's model off, adaptation off, on half of its speed
levels (the worm also with its payload given as a constant output torque at 60:1: one load, so no
load law may be claimed); the written file is replayed on the other half (``replay --csv``: the claim is the file) and
compared with a least-squares fit of Coulomb + viscous friction + a constant on the same training
samples. A second split holds out the slowest two levels (extrapolation to near standstill). The worm
is run once more as a steady-state table of its levels' means (one row a level and direction, the
payload as output torque): the one-load rule holds for a table's rows as for a recording.  A second table:
each drive calibrated on every steady-state level, its file replayed on the drive's start-stop runs (another
experiment of the same repository: from standstill to one speed, a reversal, a stop), never fitted.

Usage: ``python bench/screwdrives_loop.py DATA_DIR`` (a clone of the repository above).
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
NOMINAL_TORQUE_NM = 9.84e-3  #: the motors' nominal torque (sd_1dof.m): the unit of the torque column (%)
DRIVES = {"driveNo1": "lead screw", "driveNo2": "antibacklash lead screw", "driveNo3": "60:1 worm drive"}
CHANNELS = ("format: timeseries\ntime: {column: time_s, unit: s}\nmotor_torque: {column: torque_nm, unit: N*m}\n"
            "motor_speed: {column: speed_rpm, unit: rpm}\noutput_torque: {constant: %r, unit: N*m}\nratio: %r\n")
#: the worm's payload as its output torque: 0.096 kg on a 20 mm pulley (the authors' ``extLoad``), against
#: the lifting direction (power out positive while lifting, the motor turning backwards)
WORM_PAYLOAD_NM, WORM_RATIO = -0.096 * 9.812 * 0.02, 60.0
#: the level files are runs of one drive in one session, each on a clock from 0: their times overlap, so
#: calibrate cannot tell which came later, and it fits them as one (a stick-slipping 1 rpm level's
#: samples differ from the steady levels' at the same speed readings: a slip is no steady state)
ONE_SESSION = ("--segments", "off")


def convert(src: Path, dst: Path) -> int:
    """An EPOS Studio export -> a plain CSV (time [s], speed [rpm], torque [N·m], signs as ``getEposData.m``);
    rows that are no numbers (a hand note in a few of the worm's files) are left out: how many."""
    lines = src.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("ms;")) + 1
    rows, dropped = [], 0
    for line in lines[start:]:
        fields = [f for f in line.replace(",", "").split(";") if f]
        try:
            rows.append((float(fields[0]) / 1e3, -float(fields[1]), -float(fields[2]) * NOMINAL_TORQUE_NM / 100.0))
        except (ValueError, IndexError):
            dropped += 1
    with dst.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["time_s", "speed_rpm", "torque_nm"])
        writer.writerows(rows)
    return dropped


def level_rpm(path: Path) -> float:
    """The speed level a file is named by (``n30.csv``: −30 rpm)."""
    return float(re.sub(r"^n", "-", path.stem))


def replay_residuals(csv_path: Path, channels: Path, params: Path, out: Path, steady: bool = False) -> np.ndarray:
    """The residual (measured − estimated loss) of each sample ``replay`` estimates with ``params``;
    ``steady``: of the samples within 5 % of the run's top speed only (no start, reversal or stop)."""
    subprocess.run([sys.executable, "-m", "rollergear_ros", "replay", str(csv_path), "--channels", str(channels),
                    "--params", str(params), "--csv", str(out)], check=True, capture_output=True, text=True)
    with out.open() as fh:
        reader = csv.DictReader(fh)
        key = next(k for k in reader.fieldnames if k.startswith("residual_torque"))
        rows = [(float(row[key]), abs(float(row["motor_speed [rad/s]"]))) for row in reader]
    if not rows:  # no sample replayed
        return np.empty(0)
    values, speed = (np.array(column) for column in zip(*rows))
    keep = np.isfinite(values) & ((speed >= 0.95 * speed.max()) if steady else True)
    return values[keep]


def evaluate(drive: str, files: list[Path], held: set[float], work: Path, given: Path, channels: Path) -> dict:
    """Calibrate on the levels not ``held``, replay the held ones; the errors [N·m] of each way."""
    train = [p for p in files if abs(level_rpm(p)) not in held]
    test = [p for p in files if abs(level_rpm(p)) in held]
    written = work / f"{drive}.yaml"
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", *map(str, train), "--channels",
                           str(channels), "--params", str(given), "--out", str(written), "--json", *ONE_SESSION],
                          capture_output=True, text=True)
    result = json.loads(proc.stdout)
    row = {"effects": result["effects"], "written": result["written"]}

    def data(paths):
        arrays = [np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2) for p in paths]
        return [a[:, 1] * np.pi / 30.0 for a in arrays], [a[:, 2] for a in arrays]

    speed, torque = data(train)
    w, t = np.concatenate(speed), np.concatenate(torque)
    coef = _least_squares(w, t)
    speed, torque = data(test)
    ls_levels = [t[w != 0] - _coulomb_viscous_constant(w[w != 0]) @ coef for w, t in zip(speed, torque)]
    row["floor"] = _rms(np.concatenate([t - t.mean() for t in torque]))
    row["ls"] = (_rms(np.concatenate(ls_levels)), _rms(np.array([r.mean() for r in ls_levels])))
    for name, params in (("given", given), ("file", written if result["written"] else given)):
        levels = [replay_residuals(p, channels, params, work / f"{p.stem}_{name}.csv") for p in test]
        estimated = [r for r in levels if len(r)]  # a level may have no sample the estimator takes (near 0)
        row[name] = (_rms(np.concatenate(estimated or [np.empty(0)])), _rms(np.array([r.mean() for r in estimated])),
                     sum(map(len, levels)), sum(len(t) for t in torque))
    return row


def evaluate_start_stop(drive: str, files: list[Path], runs: list[Path], work: Path, given: Path,
                        channels: Path) -> dict:
    """Calibrate on every steady-state level; replay the written file on the drive's start-stop runs (another
    experiment: from standstill to one speed, a reversal, a stop) beside the least-squares fit of the levels."""
    written = work / f"{drive}_levels.yaml"
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", *map(str, files), "--channels",
                           str(channels), "--params", str(given), "--out", str(written), "--json", *ONE_SESSION],
                          capture_output=True, text=True)
    result = json.loads(proc.stdout)
    a = np.concatenate([np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2) for p in files])
    w, t = a[:, 1] * np.pi / 30.0, a[:, 2]
    coef = _least_squares(w, t)
    row = {"effects": result["effects"], "runs": []}
    for run in runs:
        b = np.loadtxt(run, delimiter=",", skiprows=1, ndmin=2)
        w, t = b[:, 1] * np.pi / 30.0, b[:, 2]
        ls = t[w != 0] - _coulomb_viscous_constant(w[w != 0]) @ coef
        top = np.abs(w) >= 0.95 * np.abs(w).max()
        ls_steady = t[top] - _coulomb_viscous_constant(w[top]) @ coef
        errors = [replay_residuals(run, channels, params, work / f"{run.stem}_{name}.csv", steady)
                  for steady in (False, True)
                  for name, params in (("given", given), ("file", written if result["written"] else given))]
        row["runs"].append((run, *map(_rms, errors[:2]), _rms(ls), *map(_rms, errors[2:]), _rms(ls_steady),
                            len(errors[1]), len(w)))
    return row


TABLE_MAP = ("format: steady_state\nmotor_torque: {column: torque_nm, unit: N*m}\n"
             "motor_speed: {column: speed_rpm, unit: rpm}\noutput_torque: {constant: %r, unit: N*m}\nratio: %r\n")


def level_table(files: list[Path], dst: Path, half: int | None = None) -> Path:
    """Each speed level's means (speed [rpm], torque [N·m]) as one row of a steady-state table; ``half``:
    of the level's first (0) or second (1) half of samples only."""
    with dst.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["speed_rpm", "torque_nm"])
        for p in files:
            a = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
            if half is not None:
                a = a[: len(a) // 2] if half == 0 else a[len(a) // 2:]
            writer.writerow([float(a[:, 1].mean()), float(a[:, 2].mean())])
    return dst


def evaluate_table(drive: str, files: list[Path], held: set[float] | None, work: Path, given: Path,
                   channels: Path) -> dict:
    """:func:`evaluate` on the levels' means as steady-state tables (one row a level and direction): the
    written file replayed on the held-out levels' rows (``held`` None: every level's first half fitted,
    its second half held out); the least-squares fit on the training rows."""
    tag = "halves" if held is None else "levels"
    if held is None:
        train = level_table(files, work / f"{drive}_{tag}_train.csv", half=0)
        test = level_table(files, work / f"{drive}_{tag}_test.csv", half=1)
    else:
        train = level_table([p for p in files if abs(level_rpm(p)) not in held], work / f"{drive}_{tag}_train.csv")
        test = level_table([p for p in files if abs(level_rpm(p)) in held], work / f"{drive}_{tag}_test.csv")
    written = work / f"{drive}_{tag}.yaml"
    proc = subprocess.run([sys.executable, "-m", "rollergear_ros", "calibrate", str(train), "--channels", str(channels),
                           "--params", str(given), "--out", str(written), "--json"], capture_output=True, text=True)
    if proc.returncode:  # too few rows: said in the table
        return {"error": proc.stderr.strip().splitlines()[-1]}
    result = json.loads(proc.stdout)
    row = {"effects": result["effects"], "written": result["written"], "floor": float("nan"),
           "untestable": result["untestable"]}

    def rows(path):
        a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        return a[:, 0] * np.pi / 30.0, a[:, 1]

    w, t = rows(train)
    coef = _least_squares(w, t)
    w, t = rows(test)
    ls = _rms(t - _coulomb_viscous_constant(w) @ coef)
    row["ls"] = (ls, ls)
    for name, params in (("given", given), ("file", written if result["written"] else given)):
        r = replay_residuals(test, channels, params, work / f"{drive}_{tag}_{name}.csv")
        row[name] = (_rms(r), _rms(r), len(r), len(t))
    return row


def _least_squares(w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The least-squares fit's coefficients (:func:`_coulomb_viscous_constant`) on the samples that move."""
    moving = w != 0.0
    coef, *_ = np.linalg.lstsq(_coulomb_viscous_constant(w[moving]), t[moving], rcond=None)
    return coef


def _coulomb_viscous_constant(w: np.ndarray) -> np.ndarray:
    """The least-squares fit's columns at speeds ``w``: Coulomb, viscous, a constant."""
    return np.column_stack([np.sign(w), w, np.ones_like(w)])


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else float("nan")


def _mnm(value_nm: float) -> str:
    """N·m as mN·m for the table ("—": no sample estimated)."""
    return f"{1e3 * value_nm:.3f}" if np.isfinite(value_nm) else "—"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, help="a clone of RViMLab/TRO2021-Dynamic-Modelling")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from rollergear_ros.core.params import config_to_yaml, load_config

    print("| drive | held out [rpm] | effects written | per sample: given → file / least squares / noise floor "
          "[mN·m] | level means: file / least squares [mN·m] | samples estimated (file) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="rollergear_screws_") as tmp:
        tmp = Path(tmp)
        def setup(name: str, payload_nm: float, ratio: float) -> tuple[Path, Path]:
            """A channel map and the parameter file given (the paper's model and adaptation off, the ratio)."""
            channels, given = tmp / f"{name}_map.yaml", tmp / f"{name}_given.yaml"
            channels.write_text(CHANNELS % (payload_nm, ratio))
            given.write_text(config_to_yaml(load_config(ROOT / "config" / "gearbox.yaml", {
                "estimator.paper_model": False, "estimator.adapt": False, "gearbox.ratio": ratio})))
            return channels, given

        spin = setup("spin", 0.0, 1.0)
        start_stop = []
        for drive, label in DRIVES.items():
            folder = tmp / drive
            folder.mkdir()
            sources = sorted((args.data / "experiments" / drive / "steady_state" / "0.096kg").glob("*.csv"))
            for src in sources:
                dropped = convert(src, folder / src.name)
                if dropped:
                    print(f"{drive}/{src.name}: {dropped} row(s) that are no numbers left out", file=sys.stderr)
            files = sorted(folder.glob("*.csv"), key=level_rpm)
            levels = sorted({abs(level_rpm(p)) for p in files})
            runs = [("every other", set(levels[1::2]), spin), ("slowest two", set(levels[:2]), spin)]
            payload, ratio = (WORM_PAYLOAD_NM, WORM_RATIO) if drive == "driveNo3" else (0.0, 1.0)
            if drive == "driveNo3":
                runs.append(("every other, the payload as output torque", set(levels[1::2]),
                             setup("load", WORM_PAYLOAD_NM, WORM_RATIO)))
            rows_map = tmp / f"{drive}_rows_map.yaml"
            rows_map.write_text(TABLE_MAP % (payload, ratio))
            rows_given = setup("load", payload, ratio)[1] if payload else spin[1]
            load = ", the payload as output torque" if payload else ""
            runs += [(f"table of level means{load}: every other", set(levels[1::2]), (rows_map, rows_given)),
                     (f"table of level means{load}: each level's second half", None, (rows_map, rows_given))]
            for split, held, (channels, given) in runs:
                table = split.startswith("table")
                row = (evaluate_table if table else evaluate)(drive, files, held, folder, given, channels)
                where = "" if held is None else ": " + ", ".join(f"{x:g}" for x in sorted(held))
                if "error" in row:
                    print(f"| {drive[-1]}: {label} | {split}{where} | {row['error']} | — | — | — |")
                    continue
                g, f, ls = row["given"], row["file"], row["ls"]
                print(f"| {drive[-1]}: {label} | {split}{where} | {_effects(row)} | "
                      f"{_mnm(g[0])} → {_mnm(f[0])} / {_mnm(ls[0])} / {_mnm(row['floor'])} | "
                      f"{_mnm(f[1])} / {_mnm(ls[1])} | {f[2]:,} of {f[3]:,} |")
            runs = []
            for src in sorted((args.data / "experiments" / drive / "start_stop").glob("*.csv"), key=level_rpm):
                convert(src, folder / f"start_stop_{src.name}")
                runs.append(folder / f"start_stop_{src.name}")
            row = evaluate_start_stop(drive, files, runs, folder, given=spin[1], channels=spin[0])
            start_stop.append((label, drive, row))
        print("\n| drive | start-stop run [rpm] | effects written (every steady-state level) | per sample: given → "
              "file / least squares [mN·m] | at the top speed only: given → file / least squares [mN·m] | "
              "samples estimated (file) |")
        print("|---|---|---|---|---|---|")
        for label, drive, row in start_stop:
            for run, given_rms, file_rms, ls_rms, given_top, file_top, ls_top, estimated, total in row["runs"]:
                print(f"| {drive[-1]}: {label} | ±{run.stem.split('_')[-1]} | {_effects(row)} | {_mnm(given_rms)} → "
                      f"{_mnm(file_rms)} / {_mnm(ls_rms)} | {_mnm(given_top)} → {_mnm(file_top)} / {_mnm(ls_top)} | "
                      f"{estimated:,} of {total:,} |")
    return 0


def _effects(row: dict) -> str:
    """The effects written, as the table shows them."""
    return "; ".join(f"`{e['name']}` " + ", ".join(f"{k} = {v:.3g}" for k, v in e["params"].items())
                     for e in row["effects"]) or "none"


if __name__ == "__main__":
    sys.exit(main())
