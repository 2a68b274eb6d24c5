"""A calibrated parameter file's covariance (``calibration.covariance``): which parameters, how sure.

``calibrate`` writes the covariance of what it fitted -- the accepted effects' coefficients, their
exponents and Vogel B, C, and the model's parameters it changed -- in the parameter file's own
keys, as one JSON text (a ROS parameter holds no matrix)::

    calibration:
      covariance: '{"keys": ["effects.drag_speed.c", "effects.drag_speed.p"],
                    "matrix": [[1.9e-11, -3.1e-09], [-3.1e-09, 6.2e-06]]}'

``predict`` (:mod:`.prediction`) propagates it to the loss of a planned drive.  ``""``: none
(a file calibrate did not write, or one with nothing fitted).  No rclpy import.
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_COVARIANCE_KEYS", "ParameterCovariance", "covariance_problem"]

#: the most parameters one covariance holds
MAX_COVARIANCE_KEYS = 64
#: |C_ij − C_ji| is tolerated up to this share of sqrt(C_ii·C_jj), a negative eigenvalue up to this
#: share of the largest variance (rounding)
SYMMETRY_TOLERANCE = 1e-9


def json_parameter(text: str):
    """A JSON text a string parameter holds (``calibration.*``): its value, None for ``""``; ValueError
    says why it is not JSON."""
    if not text.strip():
        return None
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"not JSON ({exc})") from None


def finite_number(v) -> bool:
    """Whether a JSON value is a finite number a float holds (an integer of 400 digits is not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


@dataclass(frozen=True)
class ParameterCovariance:
    """Parameter-file keys and their covariance matrix (in the keys' own units)."""

    keys: tuple[str, ...]
    matrix: np.ndarray

    def to_text(self) -> str:
        """The JSON text ``calibration.covariance`` holds (floats to their last digit)."""
        return json.dumps({"keys": list(self.keys), "matrix": [[float(v) for v in row] for row in self.matrix]},
                          separators=(",", ":"))

    @classmethod
    def from_text(cls, text: str) -> ParameterCovariance | None:
        """The covariance of a ``calibration.covariance`` text (``""``: None); ValueError says why not."""
        data = json_parameter(text)
        if data is None:
            return None
        if not isinstance(data, dict) or set(data) != {"keys", "matrix"}:
            raise ValueError('a JSON object with "keys" and "matrix" and nothing else')
        keys, rows = data["keys"], data["matrix"]
        if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys) or not keys:
            raise ValueError('"keys" is a list of parameter names')
        if len(keys) > MAX_COVARIANCE_KEYS or len(set(keys)) < len(keys):
            raise ValueError(f'"keys": at most {MAX_COVARIANCE_KEYS} parameters, each once')
        n = len(keys)
        if not isinstance(rows, list) or len(rows) != n or not all(isinstance(r, list) and len(r) == n for r in rows):
            raise ValueError(f'"matrix" is {n} rows of {n} numbers, one per key')
        if not all(finite_number(v) for r in rows for v in r):
            raise ValueError('"matrix" holds finite numbers only')
        matrix = np.array(rows, dtype=float)
        scale = max(float(np.max(np.abs(np.diag(matrix)))), 1e-300)
        pair_scale = np.sqrt(np.outer(np.abs(np.diag(matrix)), np.abs(np.diag(matrix)))) + 1e-300
        if (np.abs(matrix - matrix.T) > SYMMETRY_TOLERANCE * pair_scale).any():
            raise ValueError('"matrix" is not symmetric')
        lowest = np.linalg.eigvalsh((matrix + matrix.T) / 2).min()
        if (np.diag(matrix) < 0).any() or lowest < -SYMMETRY_TOLERANCE * scale:
            raise ValueError('"matrix" is not a covariance (a negative variance or eigenvalue)')
        return cls(tuple(keys), (matrix + matrix.T) / 2)


def covariance_problem(text: str, float_keys: Collection[str]) -> str | None:
    """Why ``text`` is no valid ``calibration.covariance`` for parameters ``float_keys``, or None."""
    try:
        cov = ParameterCovariance.from_text(text)
    except ValueError as exc:
        return str(exc)
    unknown = [k for k in (cov.keys if cov else ()) if k not in float_keys]
    if unknown:
        return f"{unknown[0]!r} is no numeric parameter of the file"
    return None
