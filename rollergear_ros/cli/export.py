"""``rollergear export --fmu``: the calibrated gearbox as a model energy managers run (a native FMI 2.0 unit)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..base.atomic import together
from ..base.errors import UsageError
from ..sources.paths import Output, check_outputs
from .args import add_params_option, config_from_args, default_params_path, finite_float, positive_float

EXAMPLE = "rollergear export --fmu gearbox.fmu --params calibrated.yaml"


def cmd_export(args: argparse.Namespace) -> int:
    from ..core.oil import OIL_TEMPERATURE_RANGE_C
    from ..outputs.fmu import build_fmu

    config = config_from_args(args)
    out = Path(args.fmu)
    if out.suffix.lower() != ".fmu":
        raise UsageError(f"--fmu {out}: an FMU file ends in .fmu")
    oil = args.oil_temperature_c
    low, high = OIL_TEMPERATURE_RANGE_C
    if oil is not None and not (low <= oil[0] < oil[1] <= high and oil[2] > 0 and (oil[1] - oil[0]) / oil[2] <= 1000):
        raise UsageError(f"--oil-temperature-c START STOP STEP: {low:g} <= START < STOP <= {high:g} degC, STEP > 0, "
                         "at most 1000 steps")
    check_outputs([args.params], [Output("--fmu", out, "fmu")])
    print(f"tabulating the model of {args.params or default_params_path()} …", flush=True)
    with together():
        table = build_fmu(config, out, args.params or default_params_path(), tuple(oil) if oil else None,
                          args.speed_max_rpm, args.torque_max_nm)
    calibrated, rated = table.ranges_text()
    print(f"wrote {out}: {table.provenance['strings']['rollergear_table']}; interpolation error <= "
          f"{table.interpolation_error_nm:.3g} N·m, <= {100 * table.interpolation_error_relative:.2g} % where the "
          f"efficiency is defined; calibrated: {calibrated}; rated: {rated} (outputs inside_calibration, "
          "inside_rating)")
    return 0


def register(sub) -> None:
    p = add_params_option(sub.add_parser(
        "export", help="the calibrated gearbox as an FMI 2.0 co-simulation unit (--fmu)",
        description="A native FMI 2.0 co-simulation unit of the parameter file's model (the paper's model "
        "and the accepted physical effects; the rig's torque-sensor errors not applied, as in map): inputs drive "
        "torque, drive speed, oil temperature; outputs loss torque, loss power, efficiency. It carries the model as "
        "a table with its interpolation error stated; its binary is C built at export with the machine's compiler "
        "($CC, cc or gcc) and needs nothing on the host; its sources ship inside it (sources/)."))
    p.add_argument("--fmu", required=True, metavar="FILE.fmu", help="the unit to write")
    p.add_argument("--speed-max-rpm", type=positive_float, metavar="RPM",
                   help="the table's speeds up to ± this (default: the map grid's, gearbox.rated_speed_rpm, widened "
                        "to what the calibration saw)")
    p.add_argument("--torque-max-nm", type=positive_float, metavar="NM",
                   help="the table's torques ± this (default: the map grid's, ± gearbox.rated_torque_nm, widened to "
                        "what the calibration saw)")
    p.add_argument("--oil-temperature-c", type=finite_float, nargs=3, metavar=("START", "STOP", "STEP"),
                   help="a model that follows the oil: the table's temperatures before refinement "
                        "(default -20 140 5 degC; halved where the oil's viscosity changes fast)")
    p.set_defaults(func=cmd_export)
