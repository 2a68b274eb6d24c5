"""``rollergear export --fmu``: the calibrated gearbox as an FMI 2.0 co-simulation unit.

The unit is made with ``pythonfmu`` and carries the model as a table (:mod:`outputs.fmutable`)
with the code that interpolates it (:mod:`outputs.fmu_gearbox`, standard library only), so it runs
where this package is not installed.  What the host needs: a 64-bit Linux or Windows FMI 2.0
importer and a Python 3 with its shared library (``pythonfmu``'s binary starts the interpreter; the
unit embeds ``pythonfmu``'s own module).  The model description carries the provenance: package
version, parameter file (its name and SHA-256), calibration, accepted effects, the parameters as YAML, the table's grid
and its interpolation error.  No rclpy import.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..base.atomic import replacing
from ..base.errors import UsageError
from ..base.interface import package_version
from ..core.operating_points import reference_temperature_c
from ..core.params import Config, config_to_yaml
from .fmutable import LossTable, loss_table
from .lossmap import accepted_effects_text, calibration_lines

__all__ = ["SLAVE_MODULE", "build_fmu"]

#: the unit's module (and its model identifier's class, ``RollergearGearbox``)
SLAVE_MODULE = "rollergear_gearbox"


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
    description = (f"Roller gearing gearbox losses (rollergear_ros {package_version()}): parameters "
                   f"{parameters}; accepted effects: {effects}; a table of {grid}; {error}")
    return {"description": description, "package_version": package_version(), "strings": {
        "rollergear_version": package_version(),
        "rollergear_parameters_file": parameters,
        "rollergear_calibration": calibration or "none",
        "rollergear_accepted_effects": effects,
        "rollergear_parameters_yaml": config_to_yaml(config),
        "rollergear_table": grid,
        "rollergear_created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}}


def build_fmu(config: Config, out: str | Path, params_path: str | Path | None = None,
              oil_grid_c: tuple[float, float, float] | None = None) -> LossTable:
    """Write the unit to ``out`` (replaced atomically) and return the table it carries."""
    try:
        from pythonfmu.builder import FmuBuilder
    except ImportError:  # pragma: no cover - a requirement of the package
        raise UsageError("export --fmu needs pythonfmu (pip install pythonfmu)") from None
    table = loss_table(config, oil_grid_c)
    table.provenance = _provenance(config, Path(params_path) if params_path else None, table)
    reference = reference_temperature_c(config)
    with tempfile.TemporaryDirectory(prefix="rollergear_fmu_") as tmp:
        work = Path(tmp)
        script = work / f"{SLAVE_MODULE}.py"
        shutil.copyfile(Path(__file__).with_name("fmu_gearbox.py"), script)
        meta = table.as_json()
        meta["reference_temperature_c"] = 40.0 if reference is None else reference  # the input's start value
        (work / "rollergear_table.json").write_text(json.dumps(meta), encoding="utf-8")
        (work / "rollergear_loss.f64").write_bytes(np.ascontiguousarray(table.loss_nm, dtype="<f8").tobytes())
        built = FmuBuilder.build_FMU(script, dest=work / "unit" / "gearbox.fmu",
                                     project_files=[work / "rollergear_table.json", work / "rollergear_loss.f64"],
                                     needsExecutionTool="true", canHandleVariableCommunicationStepSize="true")
        with replacing(out) as partial:
            shutil.copyfile(built, partial)
    return table
