"""``rollergear export --fmu``: the calibrated gearbox as a model an energy manager can run."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..base.atomic import together
from ..base.errors import UsageError
from ..sources.paths import Output, check_outputs
from .args import config_from_args, default_params_path, finite_float


def cmd_export(args: argparse.Namespace) -> int:
    from ..outputs.fmu import build_fmu

    config = config_from_args(args)
    out = Path(args.fmu)
    if out.suffix.lower() != ".fmu":
        raise UsageError(f"--fmu {out}: an FMU file ends in .fmu")
    oil = args.oil_temperature_c
    if oil is not None and not (oil[0] < oil[1] and oil[2] > 0 and -100 <= oil[0] and oil[1] <= 400
                                and (oil[1] - oil[0]) / oil[2] <= 1000):
        raise UsageError("--oil-temperature-c START STOP STEP: -100 <= START < STOP <= 400 degC, STEP > 0, "
                         "at most 1000 steps")
    check_outputs([args.params], [Output("--fmu", out, "fmu")])
    print(f"tabulating the model of {args.params or default_params_path()} …", flush=True)
    with together():
        table = build_fmu(config, out, args.params or default_params_path(), tuple(oil) if oil else None)
    print(f"wrote {out}: {table.provenance['strings']['rollergear_table']}; interpolation error <= "
          f"{table.interpolation_error_nm:.3g} N·m, <= {100 * table.interpolation_error_relative:.2g} % where the "
          "efficiency is defined")
    return 0


def register_export(sub, with_params) -> None:
    p = with_params(sub.add_parser(
        "export", help="the calibrated gearbox as an FMI 2.0 co-simulation unit (--fmu)",
        description="An FMI 2.0 co-simulation unit (pythonfmu) of the parameter file's model (the paper's model "
        "and the accepted physical effects; the rig's torque-sensor errors not applied, as in map): inputs drive "
        "torque, drive speed, oil temperature; outputs loss torque, loss power, efficiency. It carries the model as "
        "a table with its interpolation error stated and runs without this package (the host needs a Python 3 "
        "shared library)."))
    p.add_argument("--fmu", required=True, metavar="FILE.fmu", help="the unit to write")
    p.add_argument("--oil-temperature-c", type=finite_float, nargs=3, metavar=("START", "STOP", "STEP"),
                   help="a model that follows the oil: the table's temperatures before refinement "
                        "(default -20 140 5 degC; halved where the oil's viscosity changes fast)")
    p.set_defaults(func=cmd_export)


REGISTER = [register_export]
