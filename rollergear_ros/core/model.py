"""The ball-track loss model of Polák's paper, as read by ``docs/model.md``.

Pure physics: numpy and ``math`` only, no rclpy.  Each equation of the paper is a small function
of :mod:`.equations` whose docstring gives its formula and equation number; they are collected in
:data:`.equations.EQUATIONS` (tested across the registry).  :func:`evaluate_reference` chains them literally, sample by
sample as the paper does.  Because every per-sample quantity is a power law of ``|T|`` and
``|ω|``, :class:`LossModel` pre-computes the geometry once and evaluates

    T_loss = K_fr·|ω|^0.66·|T|^0.47·s_η + K_tc·|T|^(5/3) + K_er·|T|^1.33 + K_0           (eq. 22–30)

which is the same number (tested against the literal chain) at >10 M samples/s; ``s_η`` is
``(η/η0)^0.66`` when a viscosity other than ``eta0`` applies (temperature effect, eq. 9).

Sign conventions (REP 103): torque ``T`` [N·m] and speed ``ω`` [rad/s] are signed.  The loss
torque magnitude ``T_loss ≥ 0`` opposes rotation: signed loss torque = ``T_loss·sign(ω)``
(``sign(T)`` at standstill).  Loss power ``P_loss = T_loss·|ω|``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .floatops import tanh
from .equations import (ball_friction_torque_nm, contact_geometry, curvature_torque_nm,
                        drive_contact_force_n, drive_force_n, driven_contact_force_n, efficiency,
                        ellipse_semi_major_m, ellipse_semi_minor_m, hysteresis_torque_nm, load_parameter,
                        loss_torque_nm, normal_force_n, rolling_resistance_n, rolling_speed_m_s,
                        speed_parameter)

if TYPE_CHECKING:
    from .params import GearboxParams


#: breakdown keys: the contribution of each friction term and contact to T_loss [N·m]
BREAKDOWN_KEYS: tuple[str, ...] = ("fr1", "fr2", "tc1", "tc2", "ter1", "ter2", "tb", "fg")
BREAKDOWN_DESCRIPTIONS: dict[str, str] = {
    "fr1": "EHL rolling resistance Fr, drive contact (eq. 3)",
    "fr2": "EHL rolling resistance Fr, driven contact (eq. 3)",
    "tc1": "curvature/differential-sliding torque Tc, drive contact (eq. 17)",
    "tc2": "curvature/differential-sliding torque Tc, driven contact (eq. 17)",
    "ter1": "elastic hysteresis torque Ter, drive contact (eq. 21)",
    "ter2": "elastic hysteresis torque Ter, driven contact (eq. 21)",
    "tb": "ball-ball friction torque Tb (eq. 22)",
    "fg": "ball pressure force Fg/2 (eq. 22, 26)",
}


# --------------------------------------------------------------------------------------------
# The paper's equations, one pure function each (SI units unless the name says otherwise).
# --------------------------------------------------------------------------------------------

def reference_terms(p: GearboxParams, torque_nm, speed_rad_s, eta_pa_s=None) -> dict:
    """The literal chain of eq. 1–30, every term, for floats or equal-shape arrays.

    ``eta_pa_s``: the oil's dynamic viscosity per sample (default ``eta0``); it enters only ``U``
    of eq. 9 and through it Fr (eq. 3).  Slow and obvious on purpose: it is the reference
    :class:`LossModel` is tested against, and the simulator's full model at ``η(θ)``.
    """
    eta = p.eta0_pa_s if eta_pa_s is None else eta_pa_s
    geo = contact_geometry(p)
    a = math.radians(p.alpha_deg)
    b = math.radians(p.beta_deg)
    fn = normal_force_n(drive_force_n(torque_nm, p.dm1_m, p.z), a, b)
    v = rolling_speed_m_s(speed_rad_s, p.internal_ratio_effective, p.dw_m)
    terms: dict = {}
    for j, rx, k, rd in ((1, geo.rx1, geo.k1, geo.rd1), (2, geo.rx2, geo.k2, geo.rd2)):
        u = speed_parameter(v, eta, rx, p.E_eq_pa)
        w = load_parameter(fn, p.E_eq_pa, rx)
        terms[f"Fr{j}"] = rolling_resistance_n(p.E_eq_pa, rx, k, geo.g, u, w)
        a_j = ellipse_semi_major_m(p.ellipse_a, rx, k, w)
        terms[f"a{j}"] = a_j
        terms[f"b{j}"] = ellipse_semi_minor_m(p.ellipse_b, rx, k, w)
        terms[f"Tc{j}"] = curvature_torque_nm(p.mu_m, fn, a_j, rd, p.Y)
        terms[f"Ter{j}"] = hysteresis_torque_nm(p.dw_m, fn, k)
    tb = ball_friction_torque_nm(p.mu_b, p.Fg_n, p.dw_m)
    s = (terms["Tc1"] + terms["Tc2"] + terms["Ter1"] + terms["Ter2"] + tb) / p.dw_m + terms["Fr1"] + terms["Fr2"]
    fr_sum = terms["Fr1"] + terms["Fr2"]
    f1 = drive_contact_force_n(s, fr_sum, p.dw_m, p.dm1_m, a, p.Fg_n)
    f2 = driven_contact_force_n(s, fr_sum, p.dw_m, p.dm2_m, a, p.Fg_n)
    terms.update(Fn=fn, Tb=tb, S=s, F1=f1, F2=f2)
    terms["T_loss"] = loss_torque_nm(p.z, f1, geo.r1, f2, geo.r2)
    return terms


def evaluate_reference(p: GearboxParams, torque_nm: float, speed_rad_s: float,
                       eta_pa_s: float | None = None) -> dict[str, float]:
    """:func:`reference_terms` for one sample, as floats; ``T_loss`` and every term."""
    return {k: float(v) for k, v in reference_terms(p, torque_nm, speed_rad_s, eta_pa_s).items()}


@dataclass(frozen=True)
class LossResult:
    """Model output for arrays of samples (all arrays have the input's shape)."""

    loss_torque_nm: np.ndarray  #: signed, input-referred, opposes rotation
    loss_magnitude_nm: np.ndarray  #: |loss torque| = T_loss ≥ 0
    loss_power_w: np.ndarray  #: T_loss·|ω| ≥ 0
    efficiency: np.ndarray  #: (0, 1], NaN where undefined
    breakdown_nm: dict[str, np.ndarray]  #: contribution of each term to T_loss (sums to it)


class LossModel:
    """Fast evaluator of the loss model for one parameter set (vectorised and per sample)."""

    #: exponents of |T| in each term: Fr ∝ W^0.47, Tc ∝ F_n·a² ∝ F_n^(5/3), Ter ∝ F_n^1.33
    EXP_FR_T = 0.47
    EXP_FR_W = 0.66
    EXP_TC_T = 5.0 / 3.0
    EXP_TER_T = 1.33

    def __init__(self, params: GearboxParams, min_torque_for_efficiency_nm: float = 0.2,
                 min_speed_for_efficiency_rad_s: float = 0.5, enabled: bool = True) -> None:
        """``enabled = False``: the paper's model switched off (every coefficient 0), for a gearbox
        it does not describe, whose loss is then only the accepted effects (``estimator.paper_model``)."""
        self.params = params
        self.min_torque_nm = float(min_torque_for_efficiency_nm)
        self.min_speed_rad_s = float(min_speed_for_efficiency_rad_s)
        self.geometry = geo = contact_geometry(params)
        p = params
        a = math.radians(p.alpha_deg)
        # per unit |T| = 1 N·m and |ω| = 1 rad/s, through the literal equations
        fn1 = float(normal_force_n(drive_force_n(1.0, p.dm1_m, p.z), a, math.radians(p.beta_deg)))
        v1 = float(rolling_speed_m_s(1.0, p.internal_ratio_effective, p.dw_m))
        lever_s = p.z * (geo.r1 + geo.r2)  # dT_loss/dS
        lever_fr = lever_s + p.z * p.dw_m * math.cos(a) * (geo.r1 / p.dm1_m - geo.r2 / p.dm2_m)
        coef: dict[str, float] = {}
        for j, rx, k, rd in ((1, geo.rx1, geo.k1, geo.rd1), (2, geo.rx2, geo.k2, geo.rd2)):
            u = speed_parameter(v1, p.eta0_pa_s, rx, p.E_eq_pa)
            w = load_parameter(fn1, p.E_eq_pa, rx)
            coef[f"fr{j}"] = lever_fr * float(rolling_resistance_n(p.E_eq_pa, rx, k, geo.g, u, w))
            a_j = float(ellipse_semi_major_m(p.ellipse_a, rx, k, w))
            coef[f"tc{j}"] = lever_s / p.dw_m * float(curvature_torque_nm(p.mu_m, fn1, a_j, rd, p.Y))
            coef[f"ter{j}"] = lever_s / p.dw_m * float(hysteresis_torque_nm(p.dw_m, fn1, k))
        coef["tb"] = lever_s / p.dw_m * ball_friction_torque_nm(p.mu_b, p.Fg_n, p.dw_m)
        coef["fg"] = lever_s * p.Fg_n / 2.0
        if not enabled:
            coef = dict.fromkeys(coef, 0.0)
        self.enabled = enabled
        self.coefficients = coef
        self.k_fr = coef["fr1"] + coef["fr2"]
        self.k_tc = coef["tc1"] + coef["tc2"]
        self.k_ter = coef["ter1"] + coef["ter2"]
        self.k_0 = coef["tb"] + coef["fg"]
        self._exponents = np.array((self.EXP_FR_W, self.EXP_FR_T, self.EXP_TC_T, self.EXP_TER_T))

    def nonzero_terms(self) -> tuple[str, ...]:
        """The breakdown terms whose coefficient is not 0 (``tb`` and ``fg`` are 0 without a ball
        pressure force ``Fg``; every term with the paper's model switched off)."""
        return tuple(k for k, c in self.coefficients.items() if c != 0.0)

    # ---------------------------------------------------------------- vectorised
    def loss_magnitude(self, torque_nm, speed_rad_s, viscosity_scale=None) -> np.ndarray:
        """``T_loss ≥ 0`` [N·m] for arrays (eq. 22–30); ``viscosity_scale`` multiplies the Fr terms."""
        at = np.abs(np.asarray(torque_nm, dtype=float))
        aw = np.abs(np.asarray(speed_rad_s, dtype=float))
        fr = self.k_fr * np.power(aw, self.EXP_FR_W) * np.power(at, self.EXP_FR_T)
        if viscosity_scale is not None:
            fr = fr * viscosity_scale
        return fr + self.k_tc * np.power(at, self.EXP_TC_T) + self.k_ter * np.power(at, self.EXP_TER_T) + self.k_0

    def fr_part(self, torque_nm, speed_rad_s) -> np.ndarray:
        """The Fr (viscosity-dependent) part of ``T_loss`` [N·m], ∝ η0^0.66 (eq. 3, 9)."""
        at = np.abs(np.asarray(torque_nm, dtype=float))
        aw = np.abs(np.asarray(speed_rad_s, dtype=float))
        return self.k_fr * np.power(aw, self.EXP_FR_W) * np.power(at, self.EXP_FR_T)

    def parts(self, torque_nm, speed_rad_s) -> dict[str, np.ndarray]:
        """``T_loss`` as its parts [N·m] (they sum to it): ``fr`` (eq. 3, ∝ η0^0.66), ``tc`` (eq. 17,
        ∝ μ_m), ``ter`` (eq. 21), ``tb`` (eq. 22, ∝ μ_b) and ``fg`` (eq. 22/26): what a model
        parameter scales (:mod:`.modelparams`)."""
        at = np.abs(np.asarray(torque_nm, dtype=float))
        ones = np.ones_like(at)
        c = self.coefficients
        return {"fr": self.fr_part(torque_nm, speed_rad_s), "tc": self.k_tc * np.power(at, self.EXP_TC_T),
                "ter": self.k_ter * np.power(at, self.EXP_TER_T), "tb": c["tb"] * ones, "fg": c["fg"] * ones}

    def evaluate(self, torque_nm, speed_rad_s, viscosity_scale=None, breakdown: bool = True) -> LossResult:
        """Loss torque (signed), loss power, efficiency and breakdown for arrays of samples."""
        t = np.asarray(torque_nm, dtype=float)
        w = np.asarray(speed_rad_s, dtype=float)
        at, aw = np.abs(t), np.abs(w)
        pw_fr = np.power(aw, self.EXP_FR_W) * np.power(at, self.EXP_FR_T)
        if viscosity_scale is not None:
            pw_fr = pw_fr * viscosity_scale
        pw_tc = np.power(at, self.EXP_TC_T)
        pw_ter = np.power(at, self.EXP_TER_T)
        c = self.coefficients
        mag = self.k_fr * pw_fr + self.k_tc * pw_tc + self.k_ter * pw_ter + self.k_0
        bd: dict[str, np.ndarray] = {}
        if breakdown:
            ones = np.ones_like(at)
            for key, base in (("fr1", pw_fr), ("fr2", pw_fr), ("tc1", pw_tc), ("tc2", pw_tc),
                              ("ter1", pw_ter), ("ter2", pw_ter), ("tb", ones), ("fg", ones)):
                bd[key] = c[key] * base
        return LossResult(
            loss_torque_nm=mag * rotation_sign(w, t),
            loss_magnitude_nm=mag,
            loss_power_w=mag * aw,
            efficiency=efficiency(t, w, mag, self.min_torque_nm, self.min_speed_rad_s),
            breakdown_nm=bd,
        )

    # ---------------------------------------------------------------- per sample
    def loss_magnitude_scalar(self, torque_nm: float, speed_rad_s: float, viscosity_scale: float = 1.0) -> float:
        """Per-sample ``T_loss`` [N·m] on Python floats (the node's hot path), bit for bit what
        :meth:`evaluate` gives for the sample in an array."""
        at = abs(torque_nm)
        aw = abs(speed_rad_s)
        # the four powers in one call of numpy's power, the operations in :meth:`evaluate`'s order: the
        # same float as the vectorised path to the last bit (:mod:`.floatops`)
        p_fr_w, p_fr_t, p_tc, p_ter = np.power((aw, at, at, at), self._exponents).tolist()
        return self.k_fr * (p_fr_w * p_fr_t * viscosity_scale) + self.k_tc * p_tc + self.k_ter * p_ter + self.k_0

    def efficiency_scalar(self, torque_nm: float, speed_rad_s: float, loss_nm: float) -> float:
        """Per-sample eq. 30 in four quadrants (NaN where undefined, see :func:`efficiency`)."""
        at = abs(torque_nm)
        if at < self.min_torque_nm or abs(speed_rad_s) < self.min_speed_rad_s or torque_nm * speed_rad_s == 0:
            return math.nan
        eta = (at - loss_nm) / at if torque_nm * speed_rad_s > 0 else at / (at + loss_nm)
        return eta if eta > 0 else math.nan


#: beyond this many sign widths from 0 the smooth sign is the sign (tanh(8) = 1 − 2e-7)
SIGN_BAND = 8.0


def rotation_sign(speed_rad_s, torque_nm, width_rad_s: float = 0.0):
    """The direction a loss torque opposes: ``sign(ω)``, or ``sign(T)`` at standstill; with a
    ``width_rad_s`` > 0, ``tanh(ω/width)`` within :data:`SIGN_BAND` widths of 0 -- a direction the
    speed reading cannot tell runs smoothly through 0 (the estimator's width: the speed reading's noise).
    At a speed of exactly 0 (a joint at rest, an operating point of a loss map) it stays ``sign(T)``."""
    w = np.asarray(speed_rad_s, dtype=float)
    hard = np.where(w != 0, np.sign(w), np.sign(np.asarray(torque_nm, dtype=float)))
    if width_rad_s <= 0:
        return hard
    return np.where((np.abs(w) < SIGN_BAND * width_rad_s) & (w != 0), np.tanh(w / max(width_rad_s, 1e-300)), hard)


def rotation_sign_scalar(speed_rad_s: float, torque_nm: float, width_rad_s: float = 0.0) -> float:
    """Scalar :func:`rotation_sign`."""
    if width_rad_s > 0 and 0 < abs(speed_rad_s) < SIGN_BAND * width_rad_s:
        return tanh(speed_rad_s / width_rad_s)  # numpy's, as the vectorised sign (:mod:`.floatops`)
    if speed_rad_s > 0:
        return 1.0
    if speed_rad_s < 0:
        return -1.0
    return 1.0 if torque_nm > 0 else (-1.0 if torque_nm < 0 else 0.0)
