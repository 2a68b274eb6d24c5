"""``rollergear export --fmu``: the calibrated gearbox as a native FMI 2.0 co-simulation unit.

The unit's binary is C compiled at export from sources this module generates: ``fmu_gearbox.c`` (the
lifecycle and the trilinear interpolation, fixed) and ``rollergear_table.h`` (the table's grid, its
constants, the GUID and the provenance strings); the loss values are the resource ``rollergear_loss.f64``
(:mod:`outputs.fmutable`), read once at instantiation.  No interpreter, nothing to install on the host:
the Linux x86-64 binary links the C library and libm only.  The sources and the FMI 2.0 headers ship in
the unit's ``sources/`` so any toolchain can build it for another platform.  The machine's C compiler
(``$CC``, else ``cc`` or ``gcc``) builds it; without one, one clear error line.  The model description
carries the provenance: package version, parameter file (its name and SHA-256), calibration, accepted
effects, the parameters as YAML, the table's grid and its interpolation error.  No rclpy import.
"""

from __future__ import annotations

import datetime
import hashlib
import math
import os
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, indent, tostring

import numpy as np

from ..base.atomic import replacing
from ..base.errors import UsageError
from ..base.interface import package_version
from ..core.operating_points import reference_temperature_c
from ..core.params import Config, config_to_yaml
from .fmutable import LossTable, loss_table
from .lossmap import accepted_effects_text, calibration_lines

__all__ = ["BOOLEANS", "MODEL_IDENTIFIER", "REALS", "build_fmu", "c_compiler", "fmi2_headers"]

#: the unit's model identifier: its binary's and its C source's name
MODEL_IDENTIFIER = "rollergear_gearbox"
#: the Real variables in value-reference order (the C source's VR_*): name, causality, unit, description
REALS = (("drive_torque_nm", "input", "N.m", "drive (input) torque [N*m]"),
         ("drive_speed_rad_s", "input", "rad/s", "drive (input) speed [rad/s]"),
         ("oil_temperature_c", "input", "degC", "oil temperature [degC]"),
         ("loss_torque_nm", "output", "N.m", "input-referred torque loss magnitude [N*m]"),
         ("loss_power_w", "output", "W", "loss power [W]"),
         ("efficiency", "output", "1", "efficiency [1], eq. 30 in four quadrants; NaN where undefined"),
         ("interpolation_error_nm", "calculatedParameter", "N.m", "largest |table - model| between the nodes [N*m]"),
         ("interpolation_error_relative", "calculatedParameter", "1",
          "the same relative to the loss where eta is defined"))
#: the Boolean outputs in value-reference order (the C source's VB_*): name, description
BOOLEANS = (("inside_table", "false: an input is not finite or lies beyond the table (the other outputs NaN)"),
            ("inside_calibration", "the point lies within what the calibration analysed (speed, torque, oil); false "
                                   "where the parameter file states no calibrated range"),
            ("inside_rating", "the point lies within the gearbox's rated speed and torque"))
#: the units' definitions in SI base units (exponents; a degC's offset)
UNIT_DEFINITIONS = {"N.m": {"kg": "1", "m": "2", "s": "-2"}, "rad/s": {"s": "-1", "rad": "1"},
                    "W": {"kg": "1", "m": "2", "s": "-3"}, "degC": {"K": "1", "offset": "273.15"}, "1": {}}
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")


def parameters_file_text(params_path: Path | None) -> str:
    """The parameter file as a unit names it: its file name and SHA-256 (a path of the machine that made
    the unit means nothing where it runs)."""
    if params_path is None:
        return "built-in defaults"
    digest = hashlib.sha256(Path(params_path).read_bytes()).hexdigest()
    return f"{Path(params_path).name} (sha256 {digest})"


def _provenance(config: Config, params_path: Path | None, table: LossTable) -> dict:
    """The description and the provenance strings the unit's model description carries."""
    calibration = " / ".join(calibration_lines(params_path))
    effects = accepted_effects_text(config) or "none (the paper's model only)"
    grid = (f"{len(table.speeds_rad_s)} speeds {table.speeds_rad_s[0]:g} … {table.speeds_rad_s[-1]:g} rad/s x "
            f"{len(table.torques_nm)} torques {table.torques_nm[0]:g} … {table.torques_nm[-1]:g} N*m x "
            + (f"{len(table.temperatures_c)} oil temperatures {table.temperatures_c[0]:g} … "
               f"{table.temperatures_c[-1]:g} degC" if table.follows_oil else "any oil temperature (none followed)"))
    error = (f"interpolation error <= {table.interpolation_error_nm:.3g} N*m, "
             f"<= {100 * table.interpolation_error_relative:.2g} % where the efficiency is defined")
    parameters = parameters_file_text(params_path)
    calibrated, rated = table.ranges_text()
    description = (f"Roller gearing gearbox losses (rollergear_ros {package_version()}): parameters "
                   f"{parameters}; accepted effects: {effects}; a table of {grid}; {error}")
    return {"description": description, "package_version": package_version(), "strings": {
        "rollergear_version": package_version(),
        "rollergear_parameters_file": parameters,
        "rollergear_calibration": calibration or "none",
        "rollergear_accepted_effects": effects,
        "rollergear_parameters_yaml": config_to_yaml(config),
        "rollergear_table": grid,
        "rollergear_calibrated_range": calibrated,
        "rollergear_rated_range": rated,
        "rollergear_created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}}


def c_compiler() -> str:
    """The machine's C compiler: ``$CC``, else ``cc`` or ``gcc`` on the PATH; one error line without one."""
    named = os.environ.get("CC", "").split()
    for candidate in ([named[0]] if named else []) + ["cc", "gcc"]:
        found = shutil.which(candidate)
        if found:
            return found
    raise UsageError("export --fmu builds the unit's binary with the machine's C compiler and found none "
                     "(install gcc, or name one in $CC)")


def fmi2_headers() -> Path:
    """The folder of the FMI 2.0 C headers (fmpy ships them)."""
    try:
        import fmpy
    except ImportError:  # pragma: no cover - a requirement of the package
        raise UsageError("export --fmu needs the FMI 2.0 headers fmpy ships (pip install fmpy)") from None
    folder = Path(fmpy.__file__).parent / "c-code"
    if not all((folder / h).exists() for h in FMI2_HEADERS):  # pragma: no cover - a broken fmpy
        raise UsageError(f"export --fmu: the FMI 2.0 headers are not in {folder}")
    return folder


def _c_string(text: str) -> str:
    """``text`` as a C string literal (UTF-8; every byte outside printable ASCII as an octal escape)."""
    out = []
    for byte in text.encode("utf-8"):
        ch = chr(byte)
        if ch in '"\\':
            out.append("\\" + ch)
        elif 32 <= byte < 127 and ch != "?":  # '?': no trigraphs
            out.append(ch)
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def _c_double(value: float) -> str:
    """A double as a C expression that reads back to the same bits (``INFINITY``, ``NAN`` as C99 names them)."""
    v = float(value)
    if math.isnan(v):
        return "NAN"
    if math.isinf(v):
        return "INFINITY" if v > 0 else "(-INFINITY)"
    return repr(v)


def _c_doubles(values: np.ndarray) -> str:
    """Doubles as C initialisers that read back to the same bits (17 significant digits)."""
    return ", ".join(_c_double(v) for v in np.asarray(values, dtype=float))


def table_header(table: LossTable, guid: str, reference_c: float, strings: dict[str, str]) -> str:
    """``rollergear_table.h``: the grid, the constants, the GUID and the provenance strings of one unit."""
    lines = ["/* Generated by rollergear_ros (export --fmu): the grid and constants of one unit's loss table. */",
             "#ifndef ROLLERGEAR_TABLE_H", "#define ROLLERGEAR_TABLE_H",
             f'#define RG_GUID "{guid}"',
             f"#define RG_NS {len(table.speeds_rad_s)}", f"#define RG_NT {len(table.torques_nm)}",
             f"#define RG_NK {len(table.temperatures_c)}",
             f"#define RG_MIN_TORQUE_NM {float(table.min_torque_nm)!r}",
             f"#define RG_MIN_SPEED_RAD_S {float(table.min_speed_rad_s)!r}",
             f"#define RG_INTERPOLATION_ERROR_NM {float(table.interpolation_error_nm)!r}",
             f"#define RG_INTERPOLATION_ERROR_RELATIVE {float(table.interpolation_error_relative)!r}",
             f"#define RG_REFERENCE_TEMPERATURE_C {float(reference_c)!r}",
             *_range_defines(table),
             f"static const double rg_speeds[RG_NS] = {{{_c_doubles(table.speeds_rad_s)}}};",
             f"static const double rg_torques[RG_NT] = {{{_c_doubles(table.torques_nm)}}};",
             f"static const double rg_temperatures[RG_NK] = {{{_c_doubles(table.temperatures_c)}}};",
             f"#define RG_N_STRINGS {len(strings)}",
             "static const char *const rg_strings[RG_N_STRINGS] = {"]
    lines += [f"    {_c_string(text)}, /* {name} */" for name, text in strings.items()]
    lines += ["};", "#endif", ""]
    return "\n".join(lines)


def _range_defines(table: LossTable) -> list[str]:
    """The calibrated and the rated range as the C source's constants (inf where a bound is not said)."""
    speed, torque, oil = table.calibrated if table.calibrated is not None else (math.inf, math.inf, None)
    low, high = oil if oil is not None and table.follows_oil else (-math.inf, math.inf)
    return [f"#define RG_CALIBRATED {int(table.calibrated is not None)}",
            f"#define RG_SEEN_SPEED_RAD_S {_c_double(speed)}", f"#define RG_SEEN_TORQUE_NM {_c_double(torque)}",
            f"#define RG_SEEN_OIL_LOW_C {_c_double(low)}", f"#define RG_SEEN_OIL_HIGH_C {_c_double(high)}",
            f"#define RG_RATED_SPEED_RAD_S {_c_double(table.rated[0])}",
            f"#define RG_RATED_TORQUE_NM {_c_double(table.rated[1])}"]


def model_description(table: LossTable, guid: str, reference_c: float, provenance: dict) -> bytes:
    """The unit's ``modelDescription.xml`` (FMI 2.0 co-simulation, its variables in the C source's order)."""
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": MODEL_IDENTIFIER, "guid": guid, "description": provenance["description"],
        "author": "rollergear_ros", "version": provenance["package_version"],
        "generationTool": f"rollergear_ros {provenance['package_version']}",
        "generationDateAndTime": provenance["strings"]["rollergear_created_utc"].replace("+00:00", "Z"),
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    sources = SubElement(SubElement(root, "CoSimulation", {
        "modelIdentifier": MODEL_IDENTIFIER, "canHandleVariableCommunicationStepSize": "true",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "false", "canSerializeFMUstate": "false",
        "providesDirectionalDerivative": "false"}), "SourceFiles")
    SubElement(sources, "File", {"name": f"{MODEL_IDENTIFIER}.c"})
    units = SubElement(root, "UnitDefinitions")
    for name, base in UNIT_DEFINITIONS.items():
        SubElement(SubElement(units, "Unit", {"name": name}), "BaseUnit", base)
    variables = SubElement(root, "ModelVariables")
    index, outputs, calculated = 0, [], []
    starts = {"drive_torque_nm": 0.0, "drive_speed_rad_s": 0.0, "oil_temperature_c": reference_c}
    for vr, (name, causality, unit, what) in enumerate(REALS):
        index += 1
        attrs = {"name": name, "valueReference": str(vr), "causality": causality, "description": what}
        real = {"unit": unit}
        if causality == "input":
            attrs["variability"] = "continuous"
            real["start"] = repr(starts[name])
        elif causality == "output":
            attrs |= {"variability": "continuous", "initial": "calculated"}
            outputs.append(index)
        else:
            attrs |= {"variability": "fixed", "initial": "calculated"}
            calculated.append(index)
        SubElement(SubElement(variables, "ScalarVariable", attrs), "Real", real)
    for vr, (name, what) in enumerate(BOOLEANS):
        index += 1
        SubElement(SubElement(variables, "ScalarVariable", {
            "name": name, "valueReference": str(vr), "causality": "output", "variability": "discrete",
            "initial": "calculated", "description": what}), "Boolean")
        outputs.append(index)
    for vr, name in enumerate(provenance["strings"]):
        index += 1
        SubElement(SubElement(variables, "ScalarVariable", {
            "name": name, "valueReference": str(vr), "causality": "calculatedParameter", "variability": "fixed",
            "initial": "calculated", "description": "provenance (rollergear_ros)"}), "String")
        calculated.append(index)
    structure = SubElement(root, "ModelStructure")
    listed = SubElement(structure, "Outputs")
    for i in outputs:
        SubElement(listed, "Unknown", {"index": str(i)})
    initial = SubElement(structure, "InitialUnknowns")
    for i in sorted(outputs + calculated):
        SubElement(initial, "Unknown", {"index": str(i)})
    indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n"


def build_fmu(config: Config, out: str | Path, params_path: str | Path | None = None,
              oil_grid_c: tuple[float, float, float] | None = None, speed_max_rpm: float | None = None,
              torque_max_nm: float | None = None) -> LossTable:
    """Write the unit to ``out`` (replaced atomically) and return the table it carries (its grid:
    :func:`~.fmutable.loss_table`)."""
    compiler, headers = c_compiler(), fmi2_headers()
    table = loss_table(config, oil_grid_c, speed_max_rpm, torque_max_nm)
    table.provenance = _provenance(config, Path(params_path) if params_path else None, table)
    reference = reference_temperature_c(config)
    reference_c = 40.0 if reference is None else float(reference)  # the oil input's start value
    guid = "{" + str(uuid.uuid4()) + "}"
    with tempfile.TemporaryDirectory(prefix="rollergear_fmu_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        shutil.copyfile(Path(__file__).with_name("fmu_gearbox.c"), src / f"{MODEL_IDENTIFIER}.c")
        (src / "rollergear_table.h").write_text(
            table_header(table, guid, reference_c, table.provenance["strings"]), encoding="utf-8")
        for header in FMI2_HEADERS:
            shutil.copyfile(headers / header, src / header)
        binary = Path(tmp) / f"{MODEL_IDENTIFIER}.so"
        cmd = [compiler, "-shared", "-fPIC", "-O2", "-std=c99", "-I", str(src), "-o", str(binary),
               str(src / f"{MODEL_IDENTIFIER}.c"), "-lm"]
        built = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if built.returncode != 0:
            first = (built.stderr.strip().splitlines() or ["no message"])[0]
            raise UsageError(f"export --fmu: {Path(compiler).name} could not build the unit's binary: {first}")
        loss = np.ascontiguousarray(table.loss_nm, dtype="<f8").tobytes()
        with replacing(out) as partial, zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as unit:
            unit.writestr("modelDescription.xml", model_description(table, guid, reference_c, table.provenance))
            unit.write(binary, f"binaries/linux64/{MODEL_IDENTIFIER}.so")
            unit.writestr("resources/rollergear_loss.f64", loss)
            for path in sorted(src.iterdir()):
                unit.write(path, f"sources/{path.name}")
    return table
