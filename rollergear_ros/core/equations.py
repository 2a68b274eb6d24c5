"""The paper's equations, one pure function each (lmfit ``lineshapes`` style), and the contact geometry.

Each function's docstring gives its formula and equation number (Polák; the reading of ``docs/model.md``);
:data:`EQUATIONS` collects them (tested across the registry).  :func:`contact_geometry` evaluates
the load- and speed-independent ones once for a parameter set.  numpy and ``math`` only: the
parameter set (:mod:`.params`) validates with this geometry and the model (:mod:`.model`) chains
these equations, so both build on this module and neither on the other's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from ..base.interface import RPM_PER_RAD_S


class GearboxDimensions(Protocol):
    """What :func:`contact_geometry` reads of a parameter set (:class:`.params.GearboxParams`)."""

    alpha_deg: float
    dw_m: float
    dm1_m: float
    dm2_m: float
    f1: float
    f2: float
    E_eq_pa: float
    alpha_p_per_pa: float


def drive_force_n(torque_nm, dm1_m, z):
    """Eq. 1 with load sharing: ``F_h = |T| / (z·d_m1/2)`` — torque shared by the z loaded balls."""
    return np.abs(torque_nm) / (z * dm1_m / 2.0)


def normal_force_n(drive_force, alpha_rad, beta_rad):
    """Eq. 2: ``F_n = F_h / (cos α · cos β)``."""
    return drive_force / (math.cos(alpha_rad) * math.cos(beta_rad))


def rolling_radius_drive_m(dw_m, dm1_m, alpha_rad):
    """Eq. 4: ``1/R_x1 = 2/d_w − 2cos α/(d_m1 + d_w cos α)``; returns ``R_x1``."""
    c = math.cos(alpha_rad)
    return 1.0 / (2.0 / dw_m - 2.0 * c / (dm1_m + dw_m * c))


def rolling_radius_driven_m(dw_m, dm2_m, alpha_rad):
    """Eq. 5: ``1/R_x2 = 2/d_w + 2cos α/(d_m2 − d_w cos α)``; returns ``R_x2``."""
    c = math.cos(alpha_rad)
    return 1.0 / (2.0 / dw_m + 2.0 * c / (dm2_m - dw_m * c))


def groove_radius_m(f, dw_m):
    """Eq. 7: ``R_y = f·d_w/(2f − 1)``."""
    return f * dw_m / (2.0 * f - 1.0)


def ellipticity(ry_m, rx_m):
    """Eq. 6: ``k = R_y/R_x``."""
    return ry_m / rx_m


def material_parameter(e_eq_pa, alpha_p_per_pa):
    """Eq. 8: ``G = E·α_p`` (dimensionless; the paper's "[GPa]" for α_p is a typo, 1/Pa)."""
    return e_eq_pa * alpha_p_per_pa


def rolling_speed_m_s(speed_rad_s, internal_ratio, dw_m):
    """Eq. 13–14: ``v = n·i·d_w[mm]·π/60000`` with ``n = |ω|·60/2π`` rpm, i.e. ``|ω|·i·d_w/2``."""
    n_rpm = np.abs(speed_rad_s) * RPM_PER_RAD_S
    return n_rpm * internal_ratio * (dw_m * 1e3) * math.pi / 60000.0


def speed_parameter(v_m_s, eta_pa_s, rx_m, e_eq_pa):
    """Eq. 9: ``U = v·η0/(R_x·E)``."""
    return v_m_s * eta_pa_s / (rx_m * e_eq_pa)


def load_parameter(fn_n, e_eq_pa, rx_m):
    """Eq. 15: ``W = F_n/(E·R_x²)``."""
    return fn_n / (e_eq_pa * rx_m ** 2)


def rolling_resistance_n(e_eq_pa, rx_m, k, g, u, w):
    """Eq. 3 (Houpert): ``F_r = 2.86·E·R_x²·k^0.348·G^0.022·U^0.66·W^0.47``."""
    return 2.86 * e_eq_pa * rx_m ** 2 * k ** 0.348 * g ** 0.022 * np.power(u, 0.66) * np.power(w, 0.47)


def ellipse_semi_major_m(ellipse_a, rx_m, k, w):
    """Eq. 19: ``a = 1.1552·R_x·k^0.4676·W^(1/3)`` (paper prints 1.552, docs/model.md reading 3)."""
    return ellipse_a * rx_m * k ** 0.4676 * np.cbrt(w)


def ellipse_semi_minor_m(ellipse_b, rx_m, k, w):
    """Eq. 20: ``b = 1.1502·R_x·k^−0.1876·W^(1/3)`` (paper prints 1.502)."""
    return ellipse_b * rx_m * k ** -0.1876 * np.cbrt(w)


def deformed_radius_m(dw_m, f):
    """Eq. 18: ``R_d = 2·d_w·f/(2f + 1)``."""
    return 2.0 * dw_m * f / (2.0 * f + 1.0)


def curvature_torque_nm(mu_m, fn_n, a_m, rd_m, y):
    """Eq. 17: ``T_c = 0.1·μ_m·F_n·a²/R_d·(1 − 5Y³ + 3Y⁵)``."""
    return 0.1 * mu_m * fn_n * a_m ** 2 / rd_m * (1.0 - 5.0 * y ** 3 + 3.0 * y ** 5)


def hysteresis_torque_nm(dw_m, fn_n, k):
    """Eq. 21 (Snare): ``T_er = 7.48e-7·(d_w[mm]/2)^(1/3)·F_n^1.33·(1 − 3.519e-3·(k − 1)^0.806)`` N·mm → N·m."""
    t_nmm = 7.48e-7 * (dw_m * 1e3 / 2.0) ** (1.0 / 3.0) * np.power(fn_n, 1.33) * (
        1.0 - 3.519e-3 * (k - 1.0) ** 0.806)
    return t_nmm * 1e-3


def ball_friction_torque_nm(mu_b, fg_n, dw_m):
    """Eq. 22/26 term: ``T_b = μ_b·F_g·d_w/2``."""
    return mu_b * fg_n * dw_m / 2.0


def drive_contact_force_n(s_n, fr_sum_n, dw_m, dm1_m, alpha_rad, fg_n):
    """Eq. 22: ``F_1 = S + (F_r1 + F_r2)·d_w·cos α/d_m1 + F_g/2`` with ``S = ΣT/d_w + ΣF_r``."""
    return s_n + fr_sum_n * dw_m * math.cos(alpha_rad) / dm1_m + fg_n / 2.0


def driven_contact_force_n(s_n, fr_sum_n, dw_m, dm2_m, alpha_rad, fg_n):
    """Eq. 26: ``F_2 = S − (F_r1 + F_r2)·d_w·cos α/d_m2 + F_g/2``."""
    return s_n - fr_sum_n * dw_m * math.cos(alpha_rad) / dm2_m + fg_n / 2.0


def lever_arm_m(dm_m, dw_m, alpha_rad):
    """Eq. 24/28: ``R_j = d_mj/2 + d_w·cos α/2``."""
    return dm_m / 2.0 + dw_m * math.cos(alpha_rad) / 2.0


def loss_torque_nm(z, f1_n, r1_m, f2_n, r2_m):
    """Eq. 25, 29, 30: ``T_loss = z·F_1·R_1 + z·F_2·R_2`` (input-referred, ≥ 0)."""
    return z * f1_n * r1_m + z * f2_n * r2_m


def efficiency(torque_nm, speed_rad_s, loss_nm, min_torque_nm=0.0, min_speed_rad_s=0.0):
    """Eq. 30 in four quadrants.

    Motoring (``T·ω > 0``): ``η = (|T| − T_loss)/|T|``; regeneration (``T·ω < 0``, power flows
    back): ``η = |T|/(|T| + T_loss)``.  NaN (undefined, never a made-up number) where
    ``|T| < min_torque``, ``|ω| < min_speed``, ``T·ω = 0``, or the loss exceeds the motoring torque.
    """
    t = np.asarray(torque_nm, dtype=float)
    w = np.asarray(speed_rad_s, dtype=float)
    loss = np.asarray(loss_nm, dtype=float)
    at = np.abs(t)
    power_sign = np.sign(t) * np.sign(w)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.where(power_sign > 0, (at - loss) / at, at / (at + loss))
    undefined = (at < max(min_torque_nm, 0.0)) | (np.abs(w) < max(min_speed_rad_s, 0.0)) | (power_sign == 0)
    undefined |= ~(eta > 0.0)
    return np.where(undefined, np.nan, eta)


#: the registry of the paper's equations (lmfit-lineshapes style), used by tests and docs
EQUATIONS: dict[str, Callable] = {
    "eq01_drive_force": drive_force_n,
    "eq02_normal_force": normal_force_n,
    "eq03_rolling_resistance": rolling_resistance_n,
    "eq04_rolling_radius_drive": rolling_radius_drive_m,
    "eq05_rolling_radius_driven": rolling_radius_driven_m,
    "eq06_ellipticity": ellipticity,
    "eq07_groove_radius": groove_radius_m,
    "eq08_material_parameter": material_parameter,
    "eq09_speed_parameter": speed_parameter,
    "eq14_rolling_speed": rolling_speed_m_s,
    "eq15_load_parameter": load_parameter,
    "eq17_curvature_torque": curvature_torque_nm,
    "eq18_deformed_radius": deformed_radius_m,
    "eq19_ellipse_semi_major": ellipse_semi_major_m,
    "eq20_ellipse_semi_minor": ellipse_semi_minor_m,
    "eq21_hysteresis_torque": hysteresis_torque_nm,
    "eq22_drive_contact_force": drive_contact_force_n,
    "eq22_ball_friction_torque": ball_friction_torque_nm,
    "eq24_lever_arm": lever_arm_m,
    "eq26_driven_contact_force": driven_contact_force_n,
    "eq30_loss_torque": loss_torque_nm,
    "eq30_efficiency": efficiency,
}


class ContactGeometry(NamedTuple):
    """Load- and speed-independent quantities of both contacts (eq. 4–8, 18, 24, 28)."""

    rx1: float
    rx2: float
    ry1: float
    ry2: float
    k1: float
    k2: float
    rd1: float
    rd2: float
    r1: float
    r2: float
    g: float


def contact_geometry(p: GearboxDimensions) -> ContactGeometry:
    """Evaluate the geometry equations once for a parameter set."""
    a = math.radians(p.alpha_deg)
    rx1 = rolling_radius_drive_m(p.dw_m, p.dm1_m, a)
    rx2 = rolling_radius_driven_m(p.dw_m, p.dm2_m, a)
    ry1 = groove_radius_m(p.f1, p.dw_m)
    ry2 = groove_radius_m(p.f2, p.dw_m)
    return ContactGeometry(
        rx1=rx1, rx2=rx2, ry1=ry1, ry2=ry2, k1=ellipticity(ry1, rx1), k2=ellipticity(ry2, rx2),
        rd1=deformed_radius_m(p.dw_m, p.f1), rd2=deformed_radius_m(p.dw_m, p.f2),
        r1=lever_arm_m(p.dm1_m, p.dw_m, a), r2=lever_arm_m(p.dm2_m, p.dw_m, a),
        g=material_parameter(p.E_eq_pa, p.alpha_p_per_pa))
