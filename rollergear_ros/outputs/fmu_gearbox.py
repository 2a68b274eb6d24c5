"""The co-simulation unit's own code: the calibrated gearbox's losses from its table (FMI 2.0).

``rollergear export --fmu`` (:mod:`outputs.fmu`) copies this file into the unit with the table
(``rollergear_table.json``, ``rollergear_loss.f64``: :mod:`outputs.fmutable`); it runs in the
host's Python with nothing of this package (standard library and ``pythonfmu``'s embedded
``Fmi2Slave`` only).  Each step it interpolates the table trilinearly at the inputs:

* inputs: ``drive_torque_nm`` [N·m], ``drive_speed_rad_s`` [rad/s] (signed; negative torque with
  positive speed regenerates), ``oil_temperature_c`` [°C] (ignored when the model follows no oil);
* outputs: ``loss_torque_nm`` [N·m] (input-referred magnitude, as a VECTO map), ``loss_power_w``
  [W] = ``loss_torque_nm · |ω|``, ``efficiency`` [1] (eq. 30 in four quadrants: motoring
  ``(|T| − T_loss)/|T|``, regenerating ``|T|/(|T| + T_loss)``; NaN where undefined: ``|T|``
  or ``|ω|`` below the estimator's thresholds), ``inside_table`` (false: an input is not finite or
  lies beyond the table, and every other output is NaN -- the table says nothing there);
* ``interpolation_error_nm``, ``interpolation_error_relative``: the largest error of the table
  against the model, measured when it was made.

Every variable carries its unit (``N.m``, ``rad/s``, ``W``, ``degC``, ``1``) with the unit definitions
in SI base units, and the model structure lists the outputs as initial unknowns, as FMI 2.0 asks
(``fmpy validate`` passes).  No input makes a step fail: a host that steps the unit with NaN or
infinite inputs gets NaN outputs, never an error status.
"""

from __future__ import annotations

import json
import math
from array import array
from bisect import bisect_right
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability
from pythonfmu.variables import Boolean, Real, String


#: each Real variable's unit, and the units' definitions in SI base units (exponents; a degC's offset)
UNITS = {"drive_torque_nm": "N.m", "drive_speed_rad_s": "rad/s", "oil_temperature_c": "degC",
         "loss_torque_nm": "N.m", "loss_power_w": "W", "efficiency": "1", "interpolation_error_nm": "N.m",
         "interpolation_error_relative": "1"}
UNIT_DEFINITIONS = {"N.m": {"kg": "1", "m": "2", "s": "-2"}, "rad/s": {"s": "-1", "rad": "1"},
                    "W": {"kg": "1", "m": "2", "s": "-3"}, "degC": {"K": "1", "offset": "273.15"}, "1": {}}


def _cell(nodes, x):
    """``(i, w)``: ``x`` lies in ``[nodes[i], nodes[i + 1]]`` at weight ``w``; None where it lies beyond
    the nodes or is not a number."""
    n = len(nodes)
    if not nodes[0] <= x <= nodes[-1]:  # NaN too
        return None
    if n == 1:
        return 0, 0.0
    i = min(bisect_right(nodes, x) - 1, n - 2)
    return i, (x - nodes[i]) / (nodes[i + 1] - nodes[i])


class RollergearGearbox(Fmi2Slave):
    """Roller gearing gearbox losses (rollergear_ros's calibrated model, tabulated)."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        folder = Path(self.resources)
        meta = json.loads((folder / "rollergear_table.json").read_text(encoding="utf-8"))
        self.speeds = meta["speeds_rad_s"]
        self.torques = meta["torques_nm"]
        self.temperatures = meta["temperatures_c"]
        self.loss = array("d")
        self.loss.frombytes((folder / "rollergear_loss.f64").read_bytes())
        self.min_torque = meta["min_torque_nm"]
        self.min_speed = meta["min_speed_rad_s"]
        provenance = meta["provenance"]
        self.description = provenance["description"]
        self.version = provenance["package_version"]

        self.drive_torque_nm = 0.0
        self.drive_speed_rad_s = 0.0
        self.oil_temperature_c = float(meta["reference_temperature_c"])
        self.loss_torque_nm = 0.0
        self.loss_power_w = 0.0
        self.efficiency = math.nan
        self.inside_table = True
        self.interpolation_error_nm = float(meta["interpolation_error_nm"])
        self.interpolation_error_relative = float(meta["interpolation_error_relative"])
        for name, text in provenance["strings"].items():
            setattr(self, name, text)

        for name, what in (("drive_torque_nm", "drive (input) torque [N*m]"),
                           ("drive_speed_rad_s", "drive (input) speed [rad/s]"),
                           ("oil_temperature_c", "oil temperature [degC]")):
            self.register_variable(Real(name, causality=Fmi2Causality.input, description=what))
        for name, what in (("loss_torque_nm", "input-referred torque loss magnitude [N*m]"),
                           ("loss_power_w", "loss power [W]"),
                           ("efficiency", "efficiency [1], eq. 30 in four quadrants; NaN where undefined")):
            self.register_variable(Real(name, causality=Fmi2Causality.output, description=what))
        self.register_variable(Boolean("inside_table", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete,
                                       description="false: an input is not finite or lies beyond the table "
                                                   "(the other outputs NaN)"))
        for name, what in (("interpolation_error_nm", "largest |table - model| between the nodes [N*m]"),
                           ("interpolation_error_relative", "the same relative to the loss where eta is defined")):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed, description=what))
        for name in provenance["strings"]:
            self.register_variable(String(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                                          description="provenance (rollergear_ros)"))
        self._evaluate()

    def to_xml(self, model_options=None):
        """The model description pythonfmu writes, with the units (:data:`UNITS`) and the initial unknowns."""
        root = super().to_xml(model_options or {})
        units = Element("UnitDefinitions")
        for name, base in UNIT_DEFINITIONS.items():
            SubElement(SubElement(units, "Unit", {"name": name}), "BaseUnit", base)
        root.insert(list(root).index(root.find("CoSimulation")) + 1, units)
        variables = root.find("ModelVariables")
        for scalar in variables:
            real = scalar.find("Real")
            if real is not None and scalar.get("name") in UNITS:
                real.set("unit", UNITS[scalar.get("name")])
        structure = root.find("ModelStructure")
        initial = SubElement(structure, "InitialUnknowns")
        for index, scalar in enumerate(variables, start=1):
            if scalar.get("causality") == "output":
                SubElement(initial, "Unknown", {"index": str(index)})
        return root

    def _evaluate(self):
        """The outputs at the present inputs (NaN, ``inside_table`` false, beyond the table)."""
        try:
            self._interpolate()
        except Exception:  # noqa: BLE001 - nothing may reach the host as an error status
            self._outside()

    def _outside(self):
        self.loss_torque_nm = self.loss_power_w = self.efficiency = math.nan
        self.inside_table = False

    def _interpolate(self):
        torque, speed = float(self.drive_torque_nm), float(self.drive_speed_rad_s)
        nt, nk = len(self.torques), len(self.temperatures)
        on_speed, on_torque = _cell(self.speeds, speed), _cell(self.torques, torque)
        on_oil = _cell(self.temperatures, float(self.oil_temperature_c)) if nk > 1 else (0, 0.0)
        if on_speed is None or on_torque is None or on_oil is None:
            self._outside()
            return
        (i, wi), (j, wj), (k, wk) = on_speed, on_torque, on_oil
        loss = self.loss
        total = 0.0
        for di, fi in ((0, 1.0 - wi), (1, wi)):
            if fi == 0.0:
                continue
            for dj, fj in ((0, 1.0 - wj), (1, wj)):
                if fj == 0.0:
                    continue
                base = ((i + di) * nt + j + dj) * nk + k
                total += fi * fj * (loss[base] * (1.0 - wk) + (loss[base + 1] * wk if wk else 0.0))
        self.loss_torque_nm = total
        self.loss_power_w = total * abs(speed)
        self.inside_table = True
        magnitude = abs(torque)
        power_sign = (torque > 0) - (torque < 0) if speed > 0 else ((torque < 0) - (torque > 0) if speed < 0 else 0)
        eta = math.nan
        if magnitude >= self.min_torque and abs(speed) >= self.min_speed and power_sign != 0:
            eta = (magnitude - total) / magnitude if power_sign > 0 else magnitude / (magnitude + total)
        self.efficiency = eta if eta > 0.0 else math.nan

    def do_step(self, current_time, step_size):
        self._evaluate()
        return True
