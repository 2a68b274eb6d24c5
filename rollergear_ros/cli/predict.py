"""``rollergear predict``: what a planned drive will cost, with its band."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..base.atomic import together
from ..base.errors import UsageError, damaged_exit
from ..sources.paths import Output, check_outputs
from .args import add_params_option, add_topic_options, config_from_args, topics_from_args

EXAMPLE = "rollergear predict plan.mcap --params calibrated.yaml --csv plan_losses.csv"


def cmd_predict(args: argparse.Namespace) -> int:
    from ..replay.predict import predict

    exports = [(kind, getattr(args, kind)) for kind in ("csv", "parquet") if getattr(args, kind) is not None]
    check_outputs([args.profile, args.params, args.channels], [Output(f"--{k}", p, k) for k, p in exports])
    config = config_from_args(args)
    result = predict(args.profile, config, channels=args.channels, topics=topics_from_args(args),
                     collect=bool(exports), show_progress=None if not args.json else False,
                     warn=lambda m: print(f"rollergear: warning: {m}", file=sys.stderr),
                     note=lambda m: print(m, file=sys.stderr), adapt=not args.no_adapt)
    if result.samples == 0:
        raise UsageError(f"{args.profile}: no sample to predict (no paired torque and speed)")
    with together():
        for kind, path in exports:
            _write_samples(result, kind, Path(path))
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(result.text())
        for _, path in exports:
            print(f"per sample: {path}")
    return damaged_exit(args.profile, result.lost_share, "predicted from what was readable")


def _write_samples(result, kind: str, path: Path) -> None:
    """Each sample's loss power and its 95 % band as CSV or Parquet (atomically)."""
    import numpy as np

    from ..base.atomic import replacing

    low, high = result.loss_power_band_w()
    columns = {"time_s": (result.t_ns - result.t_ns[0]) * 1e-9 if len(result.t_ns) else result.t_ns * 1.0,
               "loss_power_w": result.loss_power_w, "loss_power_low95_w": low, "loss_power_high95_w": high}
    with replacing(path) as partial:
        if kind == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            pq.write_table(pa.table({"log_time_ns": result.t_ns, **columns}), partial)
        else:
            table = np.column_stack(list(columns.values()))
            header = ",".join(columns)
            np.savetxt(partial, table, delimiter=",", header=header, comments="", fmt="%.9g")


def register(sub) -> None:
    p = add_params_option(sub.add_parser(
        "predict", help="what a planned drive will cost: loss energy and power with their 95 %% band",
        description="The loss power and energy of a profile (planned torque, speed, optionally oil temperature: "
        "an MCAP, or a CSV/Parquet/MF4/TDMS with --channels as for import) under the parameter file's model, "
        "and their 95 % band: the first-order propagation of the calibration's parameter covariance "
        "(calibration.covariance, written by calibrate). The rig's torque-sensor errors are not applied; a profile "
        "with measured output torque (a recorded drive) adapts as replay does where the file says estimator.adapt: "
        "true, so predict of a recorded drive is its replay."))
    p.add_argument("profile", metavar="PROFILE", help="MCAP, or a table with --channels")
    p.add_argument("--channels", metavar="MAP.yaml", help="the channel map of a CSV/Parquet/MF4/TDMS profile")
    p.add_argument("--csv", metavar="FILE", help="each sample's loss power and its 95 %% band as CSV")
    p.add_argument("--parquet", metavar="FILE", help="... as Parquet (with the log time in ns)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the text")
    p.add_argument("--no-adapt", action="store_true",
                   help="the file's coefficients as written even where the profile has measured output torque")
    add_topic_options(p)
    p.set_defaults(func=cmd_predict)
