"""``rollergear``: the command line (model, figures, map, simulate, replay, calibrate, play).

Every subcommand loads its parameters through :func:`core.params.load_config`; errors in
user input are reported as one line ``rollergear: error: …`` with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
from pathlib import Path
from collections.abc import Sequence

import numpy as np

from ..base.atomic import together
from ..base.errors import BagError, InputFileError, RollergearError, UsageError, damaged_exit
from ..base.interface import package_version
from ..ros.nodehelp import contract_line
from . import calibrate as calibrate_cli
from . import energy as energy_cli
from . import fleet as fleet_cli
from ..ros import player
from . import replay as replay_cli
from ..ros import watch
from .args import config_from_args, default_params_path, finite_float, oil_temperature_c
from ..outputs.measuredmap import MIN_SAMPLES
from ..outputs.oiltable import MAX_MAP_TEMPERATURES
from ..outputs.lossmap import reverse_path
from ..sources.paths import Output, check_input_file, check_outputs

# ---------------------------------------------------------------------------------- model
def cmd_model(args: argparse.Namespace) -> int:
    from ..core.model import BREAKDOWN_KEYS
    from ..core.operating_points import evaluate_points

    config = config_from_args(args)
    if args.csv:
        check_input_file("--csv", args.csv)
        torque, speed = _read_points_csv(Path(args.csv))
    else:
        if not args.torque or not args.speed:
            raise UsageError("give --torque and --speed values, or --csv FILE")
        tt, ww = np.meshgrid(np.asarray(args.torque, float), np.asarray(args.speed, float), indexing="ij")
        torque, speed = tt.ravel(), ww.ravel()
    res = evaluate_points(config, torque, speed, args.oil_temperature_c)

    def number(v: float) -> float | None:
        return None if math.isnan(v) else float(v)

    points = []
    for i in range(len(torque)):
        points.append({
            "torque_nm": float(torque[i]), "speed_rad_s": float(speed[i]),
            "loss_torque_nm": number(res.loss_torque_nm[i]), "loss_power_w": number(res.loss_power_w[i]),
            "efficiency": number(res.efficiency[i]),
            "breakdown_nm": {k: number(res.breakdown_nm[k][i]) for k in BREAKDOWN_KEYS},
            "model_nm": number(res.model_nm[i]),
            "effects_nm": {k: number(v[i]) for k, v in res.effects_nm.items()},
        })
    if args.json:
        json.dump({"points": points, "effects": list(res.effects_nm), "oil_temperature_c": args.oil_temperature_c,
                   "skipped": res.skipped}, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return 0
    head = (f"{'T [N·m]':>10} {'ω [rad/s]':>10} {'T_loss [N·m]':>13} {'P_loss [W]':>11} {'η [%]':>8} "
            f"{'model [%]':>9}  dominant term")
    print(head)
    print("-" * len(head))
    for p in points:
        if p["loss_torque_nm"] is None:
            print(f"{p['torque_nm']:>10.4g} {p['speed_rad_s']:>10.4g}  skipped: outside the estimator's "
                  "plausible range (estimator.max_abs_*)")
            continue
        terms = {**p["breakdown_nm"], **p["effects_nm"]}
        dom = max(terms, key=lambda k: abs(terms[k]))
        total = abs(p["loss_torque_nm"])
        share = 100.0 * terms[dom] / max(total, 1e-300)
        model_share = 100.0 * p["model_nm"] / max(total, 1e-300)
        eta = "n/a" if p["efficiency"] is None else f"{100 * p['efficiency']:.3f}"
        print(f"{p['torque_nm']:>10.4g} {p['speed_rad_s']:>10.4g} {p['loss_torque_nm']:>13.5f} "
              f"{p['loss_power_w']:>11.4f} {eta:>8} {model_share:>9.1f}  {dom} ({share:.0f} %)")
    if res.effects_nm:
        print(f"accepted effects of the parameter file: {', '.join(res.effects_nm)} "
              "(model [%]: the paper's model's share of the loss)")
    noise = config.estimator.speed_noise_rad_s
    print("the loss's sign near standstill: " + (
        f"tanh(ω/{noise:g} rad/s), the file's speed noise" if isinstance(noise, float) and noise > 0 else
        "the plain sign of each point's speed (estimator.speed_noise_rad_s: auto is not learned from points)"))
    return 0


def _read_points_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """CSV with a header naming a torque column (``torque``/``torque_nm``/``T``) and a speed column."""
    if not path.exists():
        raise InputFileError(f"{path} does not exist")
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise InputFileError(f"{path} has no data rows")
    cols = {c.strip().lower(): c for c in rows[0]}
    tcol = next((cols[c] for c in ("torque_nm", "torque", "t") if c in cols), None)
    wcol = next((cols[c] for c in ("speed_rad_s", "speed", "omega", "w") if c in cols), None)
    if tcol is None or wcol is None:
        raise InputFileError(f"{path}: need columns torque_nm and speed_rad_s (found {', '.join(rows[0])})")
    try:
        t = np.array([float(r[tcol]) for r in rows])
        w = np.array([float(r[wcol]) for r in rows])
    except ValueError as exc:
        raise InputFileError(f"{path}: {exc}") from None
    bad = ~(np.isfinite(t) & np.isfinite(w))
    if bad.any():
        raise InputFileError(f"{path}: row(s) {', '.join(str(i + 2) for i in np.flatnonzero(bad)[:10])} are not finite")
    return t, w


# ---------------------------------------------------------------------------------- figures / map
def cmd_figures(args: argparse.Namespace) -> int:
    from ..calibration.figures import write_figures

    check_outputs([args.params], [Output("--out", args.out, "folder", ("fig*.png", "figures.csv"))])
    with together():  # the six pictures and their table are put in place together, or none
        paths = write_figures(config_from_args(args), Path(args.out))
    for p in paths:
        print(p)
    return 0


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
    from ..outputs.lossmap import build_map, coverage_warning, map_comments, plot_map, vtlm_problems, write_vtlm
    from ..outputs.oiltable import oil_dependence_warning

    from ..core.modelform import ModelForm
    from ..core.operating_points import reference_temperature_c

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


# ---------------------------------------------------------------------------------- info
def cmd_info(args: argparse.Namespace) -> int:
    from ..sources.info import describe

    info = describe(args.file, args.channels)
    print(json.dumps(info.as_dict(), indent=2) if args.json else info.text())
    if info.lost_share >= 1.0:  # the exit statuses of every command (docs/interface.md)
        raise BagError(f"{args.file}: nothing readable")
    return damaged_exit(args.file, info.lost_share, "described what was readable")


# ---------------------------------------------------------------------------------- parser
#: the subcommands living in modules of their own: each module's ``REGISTER`` (functions that add
#: their subparser); ``model``, ``figures`` and ``map`` are built here
SUBCOMMAND_REGISTERS = (*replay_cli.REGISTER, *calibrate_cli.REGISTER, *fleet_cli.REGISTER, *player.REGISTER,
                        *watch.REGISTER, *energy_cli.REGISTER)

#: one example per subcommand, shown at the end of its --help
EXAMPLES = {
    "model": "rollergear model --torque 1 10 50 --speed 104.72 --params calibrated.yaml",
    "figures": "rollergear figures --out figures/",
    "map": "rollergear map --params calibrated.yaml --out lossmap.vtlm --both-directions",
    "simulate": "rollergear simulate --out rig.mcap --profile bidirectional_map --effect drag_speed:c=3e-4,p=1.4",
    "replay": "rollergear replay rig.mcap --params calibrated.yaml --out estimates.mcap --rrd review.rrd",
    "import": "rollergear import rig.mf4 --channels rig.yaml --out rig.mcap",
    "calibrate": "rollergear calibrate rig.mcap --out calibrated.yaml --report report/",
    "play": "rollergear play rig.mcap --rate 5 --loop",
    "fleet": "rollergear fleet calibrate fleet/ --out fleet_out/ --workers 2",
    "watch": "rollergear watch --period 1",
    "info": "rollergear info rig.mcap",
    "export": "rollergear export --fmu gearbox.fmu --params calibrated.yaml",
    "predict": "rollergear predict plan.mcap --params calibrated.yaml --csv plan_losses.csv",
}
CONTRACT = contract_line()


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rollergear", description="Roller gearing gearbox loss model, "
                                 "replay, calibration and ROS 2 tools.", epilog=CONTRACT)
    ap.add_argument("--version", action="version", version=f"rollergear {package_version()}")
    sub = ap.add_subparsers(dest="command", required=True)

    def with_params(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
        p.add_argument("--params", metavar="YAML", help="parameter file (default: config/gearbox.yaml)")
        return p

    p = with_params(sub.add_parser("model", help="evaluate the loss model at torque/speed points"))
    p.add_argument("--torque", type=finite_float, nargs="+", metavar="NM", help="drive torques [N·m] (signed)")
    p.add_argument("--speed", type=finite_float, nargs="+", metavar="RAD_S", help="drive speeds [rad/s] (signed)")
    p.add_argument("--csv", metavar="FILE", help="CSV with torque_nm, speed_rad_s columns")
    p.add_argument("--oil-temperature-c", type=oil_temperature_c, metavar="DEGC",
                   help="oil temperature, for an accepted effect that needs it (viscosity_temperature)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_model)

    p = with_params(sub.add_parser("figures", help="the paper's sensitivity study (Figs. 6-11) as PNG"))
    p.add_argument("--out", required=True, metavar="DIR", help="folder for fig06.png … fig11.png and figures.csv")
    p.set_defaults(func=cmd_figures)

    p = with_params(sub.add_parser("map", help="VECTO loss map (.vtlm) of the calibrated model + efficiency/loss PNG"))
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

    p = sub.add_parser("info", help="what a recording or table holds: topics, types, counts, rates, span, damage",
                       description="What FILE holds, as ros2 bag info / mcap info print it, for every format import "
                       "reads: topics (channels, columns) with types, counts and rates, the time span, the metadata "
                       "keys and the damaged spans.")
    p.add_argument("file", metavar="FILE", help="MCAP, rosbag2 folder or .db3, CSV, Parquet, MDF4, TDMS or .vtlm")
    p.add_argument("--channels", metavar="MAP.yaml",
                   help="channel map: a time-series file channel by channel as import reads it (else its columns)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=cmd_info)

    for register in SUBCOMMAND_REGISTERS:
        register(sub, with_params)
    for name, parser in sub.choices.items():
        parser.formatter_class = argparse.RawDescriptionHelpFormatter
        parser.epilog = "\n".join(filter(None, (parser.epilog, f"example:\n  {EXAMPLES[name]}" if name in EXAMPLES
                                                else None, CONTRACT)))
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if sys.stdout is None:  # started with its standard output closed (>&-): nothing it says would be seen
        if sys.stderr is not None:
            print("rollergear: error: standard output is closed", file=sys.stderr)
        return 2
    stdout, sys.stdout = sys.stdout, _NamedStdout(sys.stdout)
    try:
        return _run(args)
    finally:
        sys.stdout = stdout


def _run(args: argparse.Namespace) -> int:
    """The command, its errors as one line and an exit status."""
    try:
        status = int(args.func(args) or 0)
        sys.stdout.flush()  # what is still buffered: a full device is said here, not at exit
        return status
    except RollergearError as exc:
        print(f"rollergear: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rollergear: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:
        if exc.filename == STDOUT:
            _discard_stdout()
        elif exc.filename is None:  # not about a file: a defect, shown as one
            raise
        # the file system refused (disk full, permissions changed during the run): one line
        print(f"rollergear: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2


STDOUT = "standard output"  #: the file name an error writing standard output carries


class _NamedStdout:
    """Standard output whose write errors (a full device, a closed descriptor) name it: one error
    line, as for any file, instead of a traceback."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def _discard_stdout() -> None:
    """After standard output failed: what it still buffers goes to /dev/null, so that the
    interpreter's exit does not fail on it again (and print a traceback of its own)."""
    try:
        stream = sys.stdout._stream if isinstance(sys.stdout, _NamedStdout) else sys.stdout
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":  # run as the package's module so exception classes are shared
    from rollergear_ros.cli.main import main as _main

    sys.exit(_main())
