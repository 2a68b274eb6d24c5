"""Gear oils by their data sheets: viscosity over temperature (no rclpy).

A data sheet gives the kinematic viscosity at 40 and 100 °C (ASTM D445) and the density at 15 °C.
ASTM D341 (Walther) draws the kinematic viscosity through the two points,
``log10(log10(ν + 0.7)) = A − B·log10(θ[K])``; the density falls about 6.5·10⁻⁴ per K; the
model's ``η`` is the dynamic viscosity ``ρ·ν``.  :func:`vogel_from_datasheet` gives the Vogel law
``η(θ) = η_ref·exp(B/(θ + C) − B/(θ_ref + C))`` closest to that curve: the starting point and range
``calibrate --oil`` gives the viscosity law, instead of searching all B and C.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["OIL_EXPANSION_PER_K", "OIL_TEMPERATURE_RANGE_C", "dynamic_viscosity_pa_s", "oil_viscosity_ratio",
           "plausible_oil_temperature", "vogel_from_datasheet", "vogel_viscosity_ratio", "walther_viscosity_mm2_s"]

#: thermal expansion of a gear oil's density [1/K] (mineral oils: 6–7·10⁻⁴)
OIL_EXPANSION_PER_K = 6.5e-4
#: oil temperatures taken as measured (°C); a reading outside is a broken sensor (a Pt100 open
#: circuit reads ~850 °C, a short −242 °C) or a wrong unit, and counts as no temperature
OIL_TEMPERATURE_RANGE_C = (-100.0, 400.0)


def plausible_oil_temperature(theta_c):
    """``theta_c`` where it lies in :data:`OIL_TEMPERATURE_RANGE_C`, NaN elsewhere (arrays or floats)."""
    low, high = OIL_TEMPERATURE_RANGE_C
    if isinstance(theta_c, float | int):
        return float(theta_c) if low <= theta_c <= high else math.nan
    theta = np.asarray(theta_c, dtype=float)
    return np.where((theta >= low) & (theta <= high), theta, np.nan)


def vogel_viscosity_ratio(theta_c, b_k: float, c_k: float, theta_ref_c: float):
    """``η(θ)/η(θ_ref) = exp(B/(θ + C) − B/(θ_ref + C))`` (Vogel)."""
    return np.exp(b_k / (np.asarray(theta_c) + c_k) - b_k / (theta_ref_c + c_k))


def walther_viscosity_mm2_s(theta_c, nu40_mm2_s: float, nu100_mm2_s: float):
    """Kinematic viscosity by ASTM D341 (Walther) through two data-sheet points:
    ``log10(log10(ν + 0.7)) = A − B·log10(θ[K])`` with ``A``, ``B`` from ν40 and ν100 [mm²/s]."""
    t40, t100 = math.log10(313.15), math.log10(373.15)
    y40, y100 = (math.log10(math.log10(nu + 0.7)) for nu in (nu40_mm2_s, nu100_mm2_s))
    slope = (y40 - y100) / (t100 - t40)
    a = y40 + slope * t40
    return 10.0 ** 10.0 ** (a - slope * np.log10(np.asarray(theta_c) + 273.15)) - 0.7


def dynamic_viscosity_pa_s(theta_c, nu40_mm2_s: float, nu100_mm2_s: float, density15_kg_m3: float = 880.0):
    """``η = ρ·ν`` [Pa·s]: ν by :func:`walther_viscosity_mm2_s`, ρ falling linearly from 15 °C."""
    density = density15_kg_m3 * (1.0 - OIL_EXPANSION_PER_K * (np.asarray(theta_c) - 15.0))
    return walther_viscosity_mm2_s(theta_c, nu40_mm2_s, nu100_mm2_s) * 1e-6 * density


def oil_viscosity_ratio(theta_c, nu40_mm2_s: float, nu100_mm2_s: float, theta_ref_c: float = 40.0):
    """``η(θ)/η(θ_ref)`` of a real oil (:func:`dynamic_viscosity_pa_s`)."""
    return (dynamic_viscosity_pa_s(theta_c, nu40_mm2_s, nu100_mm2_s)
            / dynamic_viscosity_pa_s(theta_ref_c, nu40_mm2_s, nu100_mm2_s))


def vogel_from_datasheet(nu40_mm2_s: float, nu100_mm2_s: float, density15_kg_m3: float = 880.0,
                         theta_ref_c: float = 40.0, span_c: tuple[float, float] = (0.0, 120.0)
                         ) -> tuple[float, float, float]:
    """The Vogel law closest (in log η) to the data sheet's curve over ``span_c``: ``(B, C, η_ref)``
    [K, K, Pa·s], η_ref the dynamic viscosity at ``theta_ref_c``."""
    from scipy.optimize import least_squares

    theta = np.linspace(*span_c, 61)
    target = np.log(oil_viscosity_ratio(theta, nu40_mm2_s, nu100_mm2_s, theta_ref_c))

    def misfit(v):
        b, c = v
        return b / (theta + c) - b / (theta_ref_c + c) - target

    fit = least_squares(misfit, [1000.0, 100.0], bounds=([1.0, 20.0], [1e5, 1e3]))
    b_k, c_k = (float(x) for x in fit.x)
    return b_k, c_k, float(dynamic_viscosity_pa_s(theta_ref_c, nu40_mm2_s, nu100_mm2_s, density15_kg_m3))
