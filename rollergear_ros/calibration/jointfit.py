"""The covariance of what ``calibrate`` fitted, in the parameter file's keys (``calibration.covariance``).

The selection fits coefficients linearly and profiles the members (exponents, Vogel B and C); their
95 % intervals are found one at a time.  What a prediction needs is their *joint* spread -- a
speed drag's ``c`` and ``p`` trade against each other -- so at the fit the design is linearised
in every profiled member (Gauss–Newton): one more column per member, the change of the set's
prediction per unit of it (numerically, the coefficients held), fitted with the same weights and
dwell clusters, so its covariance is the same cluster-robust sandwich the intervals use.  The
nuisance columns (a lag, the inertia) stay in the fit and drop out of the result (marginalised).
The fitted quantities then map to the file's keys: an effect's coefficient and members are keys
themselves, a model parameter's coefficient becomes its value through :mod:`core.modelparams`.
No rclpy import.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.covariance import ParameterCovariance
from ..core.effects import EFFECTS
from ..core.modelparams import MODEL_PARAMETERS
from ..core.params import Config
from .selection import Calibrator, Term

__all__ = ["fitted_covariance"]

#: a member's step for its derivative column, relative to its size
MEMBER_STEP = 1e-5


def fitted_covariance(cal: Calibrator, final: list[Term], selected: int, config: Config) -> ParameterCovariance | None:
    """The joint covariance of the first ``selected`` terms of ``final`` (the accepted ones) in the
    keys of ``config``'s file (module docstring); None when nothing was fitted."""
    if not selected:
        return None
    held = cal.held(final)
    k0 = len(cal.nuisance)
    fit = cal.fit(final)
    coef = fit.coef[k0:]
    x = cal.design(final, skip=held)
    y = cal.b.y - cal._offset(final, held)
    free = [i for i in range(len(final)) if i not in held]  # the terms with a column of x, in order
    # the quantities of the joint fit: x's columns, then each profiled member
    quantities: list[tuple[str, int, str]] = [("nuisance", j, "") for j in range(k0)]
    quantities += [("coefficient", i, "") for i in free]
    base = cal._offset(final, dict(enumerate(coef)))  # what the terms predict (the nuisance left out)
    extra = []
    for i, t in enumerate(final):
        for which, value in (("member", t.member), ("second", t.second)):
            if value is None or t.law is not None and not EFFECTS[t.name].scales_fr:
                continue
            step = MEMBER_STEP * max(abs(value), 1e-3)
            moved = list(final)
            moved[i] = cal._with_member(t, value + step if which == "member" else t.member,
                                        value + step if which == "second" else None)
            extra.append((cal._offset(moved, dict(enumerate(coef))) - base) / step)
            quantities.append((which, i, ""))
    design = np.column_stack([x, *extra]) if extra else x
    cov = cal.solve(design, y).cov
    keys, rows = _keys(final[:selected], quantities, coef, config)
    if not keys:
        return None
    jac = np.zeros((len(keys), len(quantities)))
    for r, (q, d) in enumerate(rows):
        jac[r, q] = d
    matrix = jac @ cov @ jac.T
    written = ParameterCovariance(tuple(keys), (matrix + matrix.T) / 2)  # symmetric to the last digit
    try:  # what the parameter file will accept (a degenerate fit writes none rather than an invalid file)
        return ParameterCovariance.from_text(written.to_text())
    except ValueError:
        return None


def _keys(accepted: Sequence[Term], quantities: list[tuple[str, int, str]], coef: np.ndarray,
          config: Config) -> tuple[list[str], list[tuple[int, float]]]:
    """The file keys of the accepted terms' fitted quantities and, for each, ``(quantity, d key / d
    quantity)``."""
    keys, rows = [], []
    flat = config.to_flat()
    for q, (kind, i, _) in enumerate(quantities):
        if kind == "nuisance" or i >= len(accepted):
            continue
        t = accepted[i]
        if t.name in MODEL_PARAMETERS:
            if kind != "coefficient":
                continue
            p = MODEL_PARAMETERS[t.name]
            c, file_value = float(coef[i]), flat[p.key]
            h = 1e-6 * max(abs(c), 1e-6)
            keys.append(p.key)
            rows.append((q, (p.value(file_value, c + h) - p.value(file_value, c - h)) / (2 * h)))
            continue
        effect = EFFECTS[t.name]
        short = {"coefficient": effect.coefficient, "member": effect.member, "second": effect.second_member}[kind]
        keys.append(f"effects.{t.name}.{effect.parameter(short).key}")
        rows.append((q, 1.0))
    return keys, rows
