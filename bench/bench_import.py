#!/usr/bin/env python3
"""Data in: import of 1 hour at 1 kHz from MDF4 and CSV against the format's own reader, and
calibrate on a 10 000-row steady-state table.

Baselines measured in the same run: reading the MDF4 file's channels with ``asammdf`` alone
(``MDF(path)`` + ``get`` of each channel, the samples as numpy arrays), and reading the CSV with
``pyarrow.csv.read_csv`` alone.  The import does that reading plus units, alignment and writing
the ROS 2 MCAP (4 Float64 topics per sample + the oil temperature).  The writing alone (the same
aligned channels, read beforehand) is timed too: what an import costs beyond any reader.

Usage: python bench/bench_import.py [--minutes 60] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from common import best_of

from rollergear_ros.calibration.calibrate import calibrate
from rollergear_ros.sources.channelmap import load_channel_map
from rollergear_ros.sources.importer import import_source, write_aligned
from rollergear_ros.core.params import load_config
from rollergear_ros.calibration.samples import table_samples
from rollergear_ros.sources.timeseries import align, read_series

CHANNEL_MAP = """format: timeseries
time: {column: t, unit: s}
motor_torque: {column: T_in, unit: N*m}
motor_speed: {column: n_in, unit: rpm}
output_torque: {column: T_out, unit: N*m}
output_speed: {column: n_out, unit: rpm}
oil_temperature: {column: T_oil, unit: degC}
"""


def signals(n: int, rate_hz: float) -> dict[str, np.ndarray]:
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng(0)
    torque = 50 + 40 * np.sin(2 * np.pi * t / 17) + rng.normal(0, 0.05, n)
    speed_rpm = 1500 + 1200 * np.sin(2 * np.pi * t / 41)
    return {"t": t, "T_in": torque, "n_in": speed_rpm, "T_out": -1.368 * (torque - 0.2), "n_out": speed_rpm / 1.368,
            "T_oil": 40 + 30 * (1 - np.exp(-t / 900))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="rollergear_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    n = int(args.minutes * 60 * args.rate)
    s = signals(n, args.rate)
    cmap = work / "map.yaml"
    cmap.write_text(CHANNEL_MAP)
    mdf_map = work / "map_mdf4.yaml"  # the MDF4 file's channels carry their own time
    mdf_map.write_text("".join(line + "\n" for line in CHANNEL_MAP.splitlines() if not line.startswith("time:")))

    from asammdf import MDF, Signal

    mf4 = work / "rig.mf4"
    if not mf4.exists():
        mdf = MDF(version="4.10")
        mdf.append([Signal(s[k], s["t"], name=k, unit=u) for k, u in
                    (("T_in", "Nm"), ("n_in", "rpm"), ("T_out", "Nm"), ("n_out", "rpm"))])
        slow = slice(None, None, max(int(args.rate // 10), 1))
        mdf.append([Signal(s["T_oil"][slow], s["t"][slow], name="T_oil", unit="degC")])
        mdf.save(mf4, overwrite=True)
        mdf.close()

    def asammdf_alone():
        with MDF(mf4) as m:
            for k in ("T_in", "n_in", "T_out", "n_out", "T_oil"):
                sig = m.get(k)
                np.asarray(sig.samples, dtype=np.float64), np.asarray(sig.timestamps)

    import pyarrow as pa
    import pyarrow.csv as pacsv

    csv = work / "rig.csv"
    if not csv.exists():
        pacsv.write_csv(pa.table(s), csv)

    print(f"{n:,} samples ({args.minutes:g} min at {args.rate:g} Hz); MDF4 {mf4.stat().st_size / 1e6:.0f} MB, "
          f"CSV {csv.stat().st_size / 1e6:.0f} MB; best of 2")
    for label, src, src_map, baseline_label, baseline in (
            ("MDF4", mf4, mdf_map, "asammdf reading the channels", asammdf_alone),
            ("CSV", csv, cmap, "pyarrow.csv.read_csv", lambda: pacsv.read_csv(csv))):
        t_base = best_of(baseline, 2)
        out = work / f"{label}.mcap"
        t_imp = best_of(lambda src=src, out=out, src_map=src_map: import_source(src, out, src_map), 2)
        print(f"import {label}: {t_imp:.2f} s = {n / t_imp / 1e3:.0f} k samples/s ({4 * n / t_imp / 1e6:.1f} M msg/s, "
              f"{out.stat().st_size / 1e6:.0f} MB MCAP); {baseline_label} alone: {t_base:.2f} s -> "
              f"{t_base / t_imp:.2f}x its speed")
    aligned = align(read_series(mf4, load_channel_map(mdf_map)))
    out = work / "written.mcap"
    t_write = best_of(lambda: write_aligned(aligned, out), 2)
    print(f"writing alone (the aligned channels to the MCAP, nothing read): {t_write:.2f} s = "
          f"{4 * n / t_write / 1e6:.1f} M msg/s; {out.stat().st_size / 1e6:.0f} MB")

    table = work / "table.vtlm"
    rng = np.random.default_rng(1)
    speeds = np.linspace(0, 3000, 100)
    torques = np.linspace(-100, 100, 100)
    ss, tt = (a.ravel() for a in np.meshgrid(speeds, torques, indexing="ij"))
    loss = 0.05 + 1e-4 * (ss * 2 * np.pi / 60) ** 1.3 + 2e-3 * np.abs(tt) + rng.normal(0, 0.002, len(ss))
    table.write_text("Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]\n"
                     + "\n".join(f"{a:.6g},{b:.6g},{abs(c):.6g}" for a, b, c in zip(ss, tt, loss)) + "\n")
    config = load_config()
    t0 = time.perf_counter()
    data = table_samples([table], config)
    result = calibrate(data, config)
    took = time.perf_counter() - t0
    print(f"calibrate on a {len(data.t_ns):,}-row steady-state table: {took:.2f} s (verdict {result.verdict}: "
          f"{', '.join(e.name for e in result.effects)})")


if __name__ == "__main__":
    main()
