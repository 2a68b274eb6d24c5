"""The paper model's own parameters that real gearboxes get wrong: the calibration targets beside
the effect registry (:mod:`.effects`), one descriptor each, read by ``calibrate`` and the report.

The model (:class:`~.model.LossModel`) is a sum of parts, each a power law of ``|T|`` and ``|ω|``
times a constant of the geometry and of one material parameter:

    T_loss = K_fr(η0)·|ω|^0.66·|T|^0.47 + K_tc(μ_m, Y)·|T|^(5/3) + K_ter·|T|^1.33 + K_tb(μ_b, Fg)

A parameter that is off scales its part: ``K(v) = K(v_file)·f(v)/f(v_file)``.  ``calibrate`` fits
the part's relative change ``a`` as a linear coefficient of the part itself (its column:
``ΔT = a·part``), so ``f(v) = (1 + a)·f(v_file)`` and ``v = f⁻¹((1 + a)·f(v_file))``.  What tells a
parameter apart from the effects is the part's own shape over the recording -- the model's
derivative with respect to the parameter -- stated in :attr:`ModelParameter.tells_apart`.

=====================  =============  ===================================  =====================
parameter              part           f(v)                                 the paper's value
=====================  =============  ===================================  =====================
``gearbox.eta0_pa_s``  ``fr`` (eq. 3)  ``v^0.66`` (Fr ∝ U^0.66, U ∝ η0)    a data sheet's
``gearbox.mu_m``       ``tc`` (eq. 17) ``v``                               assumed (Table 1's μ)
``gearbox.Y``          ``tc`` (eq. 17) ``1 − 5v³ + 3v⁵``                  0.34
``gearbox.mu_b``       ``tb`` (eq. 22) ``v`` (0 without a ball force Fg)  0.1
=====================  =============  ===================================  =====================

``Y`` scales the same part as ``μ_m`` (``Tc ∝ μ_m·(1 − 5Y³ + 3Y⁵)``): no loss measurement tells
them apart, so ``calibrate`` fits ``μ_m`` and says so; ``μ_b`` acts only with a ball pressure force
``Fg > 0``, and then as a constant, the same column as ``drag_constant``.  With a varying oil
temperature and the ``viscosity_temperature`` effect, ``η0`` is the Vogel law's reference value
``η(θ_ref)``: its part is the Fr part at ``η(θ)`` (the column :mod:`calibration.selection` couples).
No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["MODEL_PARAMETERS", "ModelParameter", "model_parameter"]


@dataclass(frozen=True)
class ModelParameter:
    """One parameter of the paper's model as a calibration target."""

    key: str  #: the parameter file's key (``gearbox.…``)
    label: str  #: what it is, in words (the text output and the report)
    unit: str
    part: str  #: the model's part it scales (:meth:`~.model.LossModel.parts`)
    factor: Callable[[float], float]  #: the part ∝ factor(value)
    low: float  #: physical range of the fitted value
    high: float
    tells_apart: str  #: what in the data tells it from the effects
    same_part_as: str | None = None  #: another parameter of the same part: not fitted apart from it
    exponent: float | None = None  #: factor = value^exponent (a closed-form inverse), None: solved
    #: its part grows with the load alone (at one load, or a load that follows the speed, it is a constant
    #: or a speed law: the parameter is then no more than a drag, and not tested)
    depends_on_load: bool = False

    @property
    def name(self) -> str:
        return self.key

    def value(self, file_value: float, relative_change: float) -> float:
        """The parameter's value when its part changes by ``1 + relative_change`` (NaN outside its
        physical range or where no value gives that change)."""
        target = (1.0 + relative_change) * self.factor(file_value)
        if self.exponent is not None:
            if target <= 0:
                return math.nan
            v = target ** (1.0 / self.exponent)
        else:
            v = _solve(self.factor, target, self.low, self.high)
        return v if self.low <= v <= self.high else math.nan


def _solve(f: Callable[[float], float], target: float, lo: float, hi: float) -> float:
    """``v`` in ``[lo, hi]`` with ``f(v) = target`` for a monotone ``f`` (NaN when none)."""
    from scipy.optimize import brentq

    a, b = f(lo) - target, f(hi) - target
    if a == 0:
        return lo
    if b == 0:
        return hi
    if a * b > 0:
        return math.nan
    return float(brentq(lambda v: f(v) - target, lo, hi, xtol=1e-12))


MODEL_PARAMETERS: dict[str, ModelParameter] = {p.key: p for p in (
    ModelParameter("gearbox.eta0_pa_s", "oil viscosity at the reference temperature", "Pa·s", "fr",
                   lambda v: v ** 0.66, 1e-4, 10.0,
                   "the rolling part's shape |ω|^0.66·|T|^0.47 (and, with a varying oil temperature, the "
                   "viscosity law's level at every temperature)", exponent=0.66, depends_on_load=True),
    ModelParameter("gearbox.mu_m", "local friction coefficient of the curvature torque (eq. 17)", "", "tc",
                   lambda v: v, 0.0, 0.5, "the curvature part's shape |T|^(5/3): load only, steeper than linear",
                   exponent=1.0, depends_on_load=True),
    ModelParameter("gearbox.Y", "relative pure-rolling point (eq. 17)", "", "tc",
                   lambda v: 1.0 - 5.0 * v ** 3 + 3.0 * v ** 5, 0.0, 0.6,
                   "nothing apart from mu_m: the curvature part is mu_m·(1 − 5Y³ + 3Y⁵)", same_part_as="gearbox.mu_m",
                   depends_on_load=True),
    ModelParameter("gearbox.mu_b", "friction coefficient between balls", "", "tb", lambda v: v, 0.0, 1.0,
                   "nothing apart from drag_constant (a constant); it acts only with a ball force gearbox.Fg_n > 0",
                   exponent=1.0),
)}


def model_parameter(key: str) -> ModelParameter:
    return MODEL_PARAMETERS[key]


def fitted_parameters() -> tuple[str, ...]:
    """The parameters ``calibrate`` fits: one per part (the others of a part are said, not fitted)."""
    return tuple(k for k, p in MODEL_PARAMETERS.items() if p.same_part_as is None)
