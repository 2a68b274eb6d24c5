"""What a calibration left unresolved, and what it saw (``calibration.model_form``): the band's model form.

A parameter covariance says how sure the written parameters are -- not whether the written model
is the right one.  ``calibrate`` writes beside it, as one JSON text::

    calibration:
      model_form: '{"verdict": "inconclusive",
                    "alternatives": [{"name": "drag_constant", "params": {"c": 0.0398}}],
                    "unresolved": "dahl or drag_constant: ...",
                    "seen": {"speed_rad_s": 314.2, "torque_nm": 95.0, "oil_temperature_c": [21.5, 84.0]},
                    "segment": "the latest stretch, 9,800 samples after the change at 240.8 s"}'

* ``alternatives``: effects the fit kept and the file does not hold (the best of a set the data could
  not tell apart): a prediction is also made with each added, and the band spans them;
* ``unresolved``: what the verdict left open, in words; with no alternative to span, ``predict``
  refuses the band with it;
* ``seen``: the largest drive speed and torque the calibration analysed, and the span of oil temperatures it
  analysed (where it had them): beyond them (or beyond the gearbox's rating) the accepted effects are
  extrapolated, and the band counts their share as unknown;
* ``segment``: the part of the recordings the file describes where the gearbox changed inside them
  (``""``: every sample), said with every prediction.

``""``: none (a file calibrate did not write).  No rclpy import.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from .covariance import finite_number, json_parameter

__all__ = ["ModelForm", "model_form_problem"]

#: the most alternatives one file names
MAX_ALTERNATIVES = 16


@dataclass(frozen=True)
class ModelForm:
    """A calibration's unresolved alternatives and the range it saw (see the module docstring)."""

    verdict: str = ""
    alternatives: tuple[tuple[str, dict[str, float]], ...] = ()
    unresolved: str = ""
    seen_speed_rad_s: float = math.inf  #: the largest |ω| analysed (inf: not said)
    seen_torque_nm: float = math.inf  #: the largest |T| analysed
    #: the oil temperatures analysed, lowest and highest [°C] (None: not said, no temperature channel)
    seen_oil_c: tuple[float, float] | None = None
    segment: str = ""  #: the stretch of the recordings the file describes ('': all of them)
    notes: list[str] = field(default_factory=list, compare=False)

    def to_text(self) -> str:
        seen: dict = {k: v for k, v in (("speed_rad_s", self.seen_speed_rad_s), ("torque_nm", self.seen_torque_nm))
                      if math.isfinite(v)}
        if self.seen_oil_c is not None:
            seen["oil_temperature_c"] = list(self.seen_oil_c)
        return json.dumps({"verdict": self.verdict,
                           "alternatives": [{"name": n, "params": p} for n, p in self.alternatives],
                           "unresolved": self.unresolved, "seen": seen}
                          | ({"segment": self.segment} if self.segment else {}), separators=(",", ":"))

    @classmethod
    def from_text(cls, text: str) -> ModelForm | None:
        """The model form of a ``calibration.model_form`` text (``""``: None); ValueError says why not."""
        data = json_parameter(text)
        if data is None:
            return None
        if not isinstance(data, dict) or not set(data) <= {"verdict", "alternatives", "unresolved", "seen", "segment"}:
            raise ValueError('a JSON object of "verdict", "alternatives", "unresolved", "seen", "segment"')
        verdict, unresolved, segment = data.get("verdict", ""), data.get("unresolved", ""), data.get("segment", "")
        if not all(isinstance(v, str) for v in (verdict, unresolved, segment)):
            raise ValueError('"verdict", "unresolved" and "segment" are text')
        alternatives = data.get("alternatives", [])
        if not isinstance(alternatives, list) or len(alternatives) > MAX_ALTERNATIVES:
            raise ValueError(f'"alternatives" is a list of at most {MAX_ALTERNATIVES}')
        alts = []
        for a in alternatives:
            if not (isinstance(a, dict) and set(a) == {"name", "params"} and isinstance(a["name"], str)
                    and isinstance(a["params"], dict)
                    and all(isinstance(k, str) and finite_number(v) for k, v in a["params"].items())):
                raise ValueError('each alternative is {"name": effect, "params": {short name: number}}')
            alts.append((a["name"], {k: float(v) for k, v in a["params"].items()}))
        seen = data.get("seen", {})
        oil = seen.pop("oil_temperature_c", None) if isinstance(seen, dict) else None
        if not isinstance(seen, dict) or not set(seen) <= {"speed_rad_s", "torque_nm"} \
                or not all(finite_number(v) and v > 0 for v in seen.values()) \
                or not (oil is None or (isinstance(oil, list) and len(oil) == 2 and all(map(finite_number, oil))
                                        and oil[0] <= oil[1])):
            raise ValueError('"seen" is {"speed_rad_s": number > 0, "torque_nm": number > 0, '
                             '"oil_temperature_c": [lowest, highest]}')
        return cls(verdict, tuple(alts), unresolved, float(seen.get("speed_rad_s", math.inf)),
                   float(seen.get("torque_nm", math.inf)), None if oil is None else (float(oil[0]), float(oil[1])),
                   segment)




def model_form_problem(text: str, effects: dict) -> str | None:
    """Why a ``calibration.model_form`` text is not one (None: it is); ``effects``: the registry."""
    try:
        form = ModelForm.from_text(text)
    except ValueError as exc:
        return str(exc)
    for name, params in form.alternatives if form else ():
        if name not in effects:
            return f"alternative {name!r} is no effect"
        unknown = set(params) - {p.short for p in effects[name].parameters}
        if unknown:
            return f"alternative {name!r} has no parameter {', '.join(sorted(unknown))}"
    return None
