"""``rollergear map``: the VECTO loss map of the calibrated model (over oil temperatures; measured maps of
recordings)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from ..base.atomic import together
from ..base.errors import UsageError, damaged_exit
from ..base.interface import package_version
from ..outputs.lossmap import reverse_path
from ..outputs.measuredmap import MIN_SAMPLES
from ..outputs.oiltable import MAX_MAP_TEMPERATURES
from ..sources.paths import Output, check_outputs
from .args import add_params_option, config_from_args, default_params_path, finite_float, oil_temperature_c

EXAMPLE = "rollergear map --params calibrated.yaml --out lossmap.vtlm --both-directions"


def cmd_map(args: argparse.Namespace) -> int:
    from ..outputs.lossmap import grid

    config = config_from_args(args)
    m = config.map
    speeds = grid(*(args.speed_rpm or (m.speed_min_rpm, m.last_speed_rpm(config.gearbox), m.speed_step_rpm)))
    torques = grid(*(args.torque_nm or m.torques_nm(config.gearbox)))
    out = Path(args.out)
    both = args.both_directions or m.both_directions
    temperatures = _map_temperatures(args.oil_temperature_c)
    forward = {t: map_path(out, t, len(temperatures) > 1) for t in temperatures}
    table = Path(args.table) if args.table else (out.with_suffix(".csv") if len(temperatures) > 1 else None)
    if table is not None and table.suffix.lower() not in (".csv", ".parquet"):
        raise UsageError(f"--table {table}: a .csv or .parquet file")
    outputs = []
    for path in forward.values():
        for p in [path, *([reverse_path(path)] if both else [])]:
            outputs += [Output("--out", p, "vtlm")] + ([Output("its picture", p.with_suffix(".png"), "png")]
                                                       if not args.no_plot else [])
    if table is not None:
        outputs.append(Output("--table", table, table.suffix.lower().lstrip(".")))
    if args.measured and not args.recording:
        raise UsageError("--measured needs a --recording with measured output torque")
    if args.min_samples < 1:
        raise UsageError("--min-samples must be >= 1")
    measured_paths = {bag: out.with_name(f"{out.stem}_measured_{Path(bag).stem}.vtlm") for bag in args.recording} \
        if args.measured else {}
    for path in measured_paths.values():
        outputs += [Output("a measured map", path, "vtlm"),
                    Output("the reverse measured map", reverse_path(path), "vtlm"),
                    Output("its table", path.with_suffix(".csv"), "csv")]
    check_outputs([args.params, *args.recording], outputs)
    with together():  # the maps, pictures and tables are put in place together, or none
        return _write_maps(args, config, speeds, torques, forward, both, table, measured_paths)


def _map_temperatures(given: list[float] | None) -> list[float | None]:
    """``--oil-temperature-c``'s temperatures (none given: one map, at no stated temperature)."""
    if not given:
        return [None]
    if len(set(given)) < len(given):
        raise UsageError(f"--oil-temperature-c: a temperature given twice ({' '.join(f'{t:g}' for t in given)})")
    if len(given) > MAX_MAP_TEMPERATURES:
        raise UsageError(f"--oil-temperature-c: at most {MAX_MAP_TEMPERATURES} temperatures (got {len(given)})")
    return list(given)


def map_path(out: Path, temperature_c: float | None, several: bool) -> Path:
    """The map file of one oil temperature: ``--out`` itself, or with several temperatures
    ``lossmap.vtlm`` -> ``lossmap_60C.vtlm`` (``lossmap_-10C.vtlm``, ``lossmap_22.5C.vtlm``)."""
    return out.with_name(f"{out.stem}_{temperature_c:g}C{out.suffix}") if several else out


def _write_maps(args: argparse.Namespace, config, speeds: np.ndarray, torques: np.ndarray,
                forward: dict[float | None, Path], both: bool, table: Path | None,
                measured_paths: dict[str, Path]) -> int:
    from ..core.modelform import ModelForm
    from ..core.operating_points import reference_temperature_c
    from ..outputs.lossmap import build_map, coverage_warning, map_comments, plot_map, vtlm_problems, write_vtlm
    from ..outputs.oiltable import oil_dependence_warning

    params_path = Path(args.params) if args.params else default_params_path()
    reference = reference_temperature_c(config)  # None: the model follows no oil
    form = ModelForm.from_text(config.calibration.model_form)
    oil_seen = form.seen_oil_c if form is not None and reference is not None else None
    maps = []  # (temperature, path, map)
    for temperature, out in forward.items():
        maps.append((temperature, out, build_map(config, speeds, torques, temperature)))
        if both:
            maps.append((temperature, reverse_path(out), build_map(config, speeds, torques, temperature, reverse=True)))
    for temperature, path, loss_map in maps:
        problems = vtlm_problems(loss_map)
        if problems:
            raise UsageError(f"{path} would not be a valid VECTO loss map: {'; '.join(problems)}")
        write_vtlm(loss_map, path, map_comments(config, params_path, temperature, loss_map.reverse))
        png = None if args.no_plot else path.with_suffix(".png")
        if png is not None:
            plot_map(loss_map, png, config.estimator.min_torque_for_efficiency_nm)
        eta = loss_map.efficiency
        print(f"wrote {path} ({len(speeds)} speeds 0…{speeds.max():g} rpm x {len(torques)} torques"
              f"{', reverse rotation' if loss_map.reverse else ''}"
              f"{'' if temperature is None else f', oil {temperature:g} °C'})" + (f" and {png}" if png else ""))
        if np.isfinite(eta).any():
            model_share = 100.0 * float(np.sum(loss_map.model_nm)) / max(float(np.sum(loss_map.loss_nm)), 1e-300)
            where = ("" if reference is None else
                     f" at the file's viscosity (gearbox.eta0_pa_s, the oil at {reference:g} °C)")
            print(f"  efficiency {100 * np.nanmin(eta):.2f} … {100 * np.nanmax(eta):.2f} %, "
                  f"max loss {loss_map.loss_nm.max():.4f} N·m; the paper's model alone{where}: {model_share:.0f} % "
                  "of this map's loss, summed over its points")
        if oil_seen is not None and temperature is not None and not oil_seen[0] <= temperature <= oil_seen[1]:
            print(f"rollergear: warning: {path}: oil {temperature:g} °C lies outside the oil temperatures the "
                  f"calibration saw ({oil_seen[0]:g} … {oil_seen[1]:g} °C): the oil's law is extrapolated there",
                  file=sys.stderr)
    if table is not None:
        from ..outputs.oiltable import write_long_table

        rows = write_long_table([(math.nan if t is None else t, m) for t, _, m in maps], table)
        print(f"wrote {table} ({rows} rows: speed x torque x oil temperature -> loss)")
    warning = oil_dependence_warning(config, [t for t in forward if t is not None])
    if warning:
        print(f"rollergear: warning: {warning}", file=sys.stderr)
    first_map = maps[0][2]
    status = 0
    for bag in args.recording:
        from ..replay.run import replay

        summary, batches = replay(bag, config, show_progress=False, collect=True,
                                  warn=lambda m: print(f"rollergear: warning: {m}", file=sys.stderr))
        if summary.interrupted:
            raise KeyboardInterrupt
        torque = np.concatenate([b.torque_nm for b in batches]) if batches else np.zeros(0)
        speed = np.concatenate([b.speed_rad_s for b in batches]) if batches else np.zeros(0)
        warning = coverage_warning(first_map, torque, speed, str(bag))
        if warning:
            print(f"rollergear: warning: {warning}", file=sys.stderr)
        else:
            print(f"{bag}: every sample lies inside the map")
        if bag in measured_paths:
            _write_measured(summary, config, bag, measured_paths[bag], args.min_samples)
        # a damaged recording: said, and exit 3 where it lost more than 1 % (as replay)
        status = max(status, damaged_exit(str(bag), summary.lost_share, "the coverage and the measured map hold "
                                                                       "what was readable"))
    return status


def _write_measured(summary, config, bag: str, path: Path, min_samples: int) -> None:
    """``map --measured``: the recording's measured loss map (:mod:`outputs.measuredmap`)."""
    from ..outputs.measuredmap import measured_cells, write_measured_map

    if not summary.measured.samples:
        raise UsageError(f"{bag} has no measured output torque: no measured loss map")
    cells = measured_cells(summary.measured_cells, config, min_samples)
    stated = config.sensors.stated
    comments = [f"# measured loss map of {bag} (rollergear {package_version()}): per operating point the energy lost "
                "over the input's angle turned, input-referred",
                f"# cells: the map.* grid's nearest node (speed step {config.map.speed_step_rpm:g} rpm, torque step "
                f"{config.map.torque_step_nm:g} N*m), each with >= {min_samples} samples",
                "# standard uncertainties from " + ("the sensors' stated accuracy (sensors.*)" if stated else
                                                    "no stated accuracy: sensors.* is empty (0 in the CSV)")]
    files = write_measured_map(cells, path, comments)
    print(f"measured map of {bag}: {len(cells)} of {len(summary.measured_cells)} operating points with >= "
          f"{min_samples} samples -> {', '.join(str(f) for f in files)}")
    if path not in files:
        print(f"rollergear: warning: {bag}: fewer than 4 forward operating points with a valid measured loss: no "
              f"{path.name} (VECTO needs 4); the table holds what was measured", file=sys.stderr)


def register(sub) -> None:
    p = add_params_option(sub.add_parser(
        "map", help="VECTO loss map (.vtlm) of the calibrated model + efficiency/loss PNG"))
    p.add_argument("--out", default="lossmap.vtlm", metavar="VTLM",
                   help="the map (VECTO CSV layout); its PNG goes next to it (default: lossmap.vtlm)")
    p.add_argument("--speed-rpm", type=finite_float, nargs=3, metavar=("START", "STOP", "STEP"),
                   help="speed grid, >= 0 (default: the map section of the parameter file, 0 to the rated speed)")
    p.add_argument("--torque-nm", type=finite_float, nargs=3, metavar=("START", "STOP", "STEP"),
                   help="torque grid, both signs (default: the map section of the parameter file, -100 100 5)")
    p.add_argument("--both-directions", action="store_true",
                   help="also reverse rotation, to a second file NAME_reverse.vtlm (VECTO maps have speeds >= 0)")
    p.add_argument("--oil-temperature-c", type=oil_temperature_c, nargs="+", metavar="DEGC",
                   help="oil temperature(s), for an accepted effect that needs it (viscosity_temperature); several: "
                        "a map per temperature, OUT_<T>C.vtlm, and the long table (--table)")
    p.add_argument("--table", metavar="CSV|PARQUET",
                   help="the maps as one long table, speed x torque x oil temperature -> loss (default with several "
                        "temperatures: OUT with .csv)")
    p.add_argument("--recording", action="append", default=[], metavar="BAG",
                   help="warn when this recording visited operating points outside the map (repeatable)")
    p.add_argument("--measured", action="store_true",
                   help="also write each --recording's measured loss map beside the model's: OUT_measured_BAG.vtlm "
                        "(+ _reverse.vtlm) and .csv, the operating points with enough samples and their uncertainty")
    p.add_argument("--min-samples", type=int, default=MIN_SAMPLES, metavar="N",
                   help=f"--measured: a cell needs this many samples (default {MIN_SAMPLES})")
    p.add_argument("--no-plot", action="store_true", help="no PNG")
    p.set_defaults(func=cmd_map)
