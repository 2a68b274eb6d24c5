"""Extra loss effects the paper's model lacks (the ``interface.md`` vocabulary).

Each effect is a pure function of the per-sample quantities, returning its contribution to the
*measured input-referred loss* ``T_loss,meas = (T_in·ω_in − T_out·ω_out)/|ω_in|`` [N·m] (positive =
more loss).  The functions use only ``abs``, ``**``, ``*`` and ``+`` so the same code runs on Python
floats (the node's per-sample path) and on numpy arrays (replay, calibration).

=========================  ==========================================  ======================
name                       contribution to the measured loss [N·m]     physical?
=========================  ==========================================  ======================
``drag_constant``          ``c``                                       yes (seal, return track)
``drag_speed``             ``c·|ω|^p``                                 yes (churning, windage)
``load_dependent``         ``c·|T|^q``                                 yes (bearing load, sliding)
``viscosity_temperature``  ``T_Fr·(s(θ) − 1)``, ``s = (η(θ)/η0)^0.66``  yes (oil warming)
``torque_offset``          ``b·sgn(ω)``                                no: torque-sensor zero error
``torque_gain``            ``g·T·sgn(ω)``                              no: torque-sensor gain error
=========================  ==========================================  ======================

``T_Fr`` is the Fr part of the model (eq. 3, ∝ η^0.66 through U^0.66 of eq. 9), and
``η(θ) = η0·exp(B/(θ + C) − B/(θ_ref + C))`` (Vogel).  Sensor effects are not losses: they enter
the comparison with the measured loss (the residual), never the published loss torque.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .params import EffectParams

FR_VISCOSITY_EXPONENT = 0.66  # Fr ∝ U^0.66 ∝ η^0.66 (eq. 3, 9)


def drag_constant(c_nm, abs_torque, abs_speed, torque, rot_sign):
    """Constant drag: ``ΔT = c`` (seal friction, return-track friction, Coulomb drag)."""
    return c_nm + 0.0 * abs_speed


def drag_speed(c, p, abs_torque, abs_speed, torque, rot_sign):
    """Speed drag: ``ΔT = c·|ω|^p`` (churning p≈1–2, viscous p=1, windage p≈2)."""
    return c * abs_speed ** p


def load_dependent(c, q, abs_torque, abs_speed, torque, rot_sign):
    """Load-dependent friction: ``ΔT = c·|T|^q`` (bearing load friction, sliding)."""
    return c * abs_torque ** q


def torque_offset(offset_nm, abs_torque, abs_speed, torque, rot_sign):
    """Torque-sensor zero error, input-referred: ``ΔT = b·sgn(ω)`` (flips with direction)."""
    return offset_nm * rot_sign


def torque_gain(gain, abs_torque, abs_speed, torque, rot_sign):
    """Torque-sensor gain error: ``ΔT = g·T·sgn(ω)`` (= g|T| motoring, −g|T| regenerating)."""
    return gain * torque * rot_sign


def viscosity_scale(b_k, c_k, theta_ref_c, theta_c):
    """``s = (η(θ)/η0)^0.66`` with Vogel ``η(θ)/η0 = exp(B/(θ + C) − B/(θ_ref + C))``."""
    return math.e ** (FR_VISCOSITY_EXPONENT * (b_k / (theta_c + c_k) - b_k / (theta_ref_c + c_k)))


#: registry: name -> (function, is a physical loss)
EFFECTS: dict[str, tuple[Callable, bool]] = {
    "drag_constant": (drag_constant, True),
    "drag_speed": (drag_speed, True),
    "load_dependent": (load_dependent, True),
    "viscosity_temperature": (viscosity_scale, True),
    "torque_offset": (torque_offset, False),
    "torque_gain": (torque_gain, False),
}


@dataclass(frozen=True)
class EffectTerms:
    """The contributions of the enabled effects for one sample or an array of samples."""

    physical_nm: object  #: added to the published loss torque magnitude
    sensor_nm: object  #: added only to the expected *measured* loss


def additive_effects(e: EffectParams, abs_torque, abs_speed, torque, rot_sign) -> EffectTerms:
    """Sum the enabled additive effects (all but viscosity, which scales the model's Fr part)."""
    phys = 0.0 * abs_speed
    sens = 0.0 * abs_speed
    if e.drag_constant:
        phys = phys + drag_constant(e.drag_constant_c_nm, abs_torque, abs_speed, torque, rot_sign)
    if e.drag_speed:
        phys = phys + drag_speed(e.drag_speed_c, e.drag_speed_p, abs_torque, abs_speed, torque, rot_sign)
    if e.load_dependent:
        phys = phys + load_dependent(e.load_dependent_c, e.load_dependent_q, abs_torque, abs_speed, torque, rot_sign)
    if e.torque_offset:
        sens = sens + torque_offset(e.torque_offset_offset_nm, abs_torque, abs_speed, torque, rot_sign)
    if e.torque_gain:
        sens = sens + torque_gain(e.torque_gain_gain, abs_torque, abs_speed, torque, rot_sign)
    return EffectTerms(phys, sens)
