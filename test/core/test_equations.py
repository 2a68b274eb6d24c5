"""The paper's equations: the registry covers the paper, documents each formula, and vectorises."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.core import equations as m


def test_registry_covers_the_paper_and_documents_each_equation():
    numbers = {int(k[2:4]) for k in m.EQUATIONS}
    assert {1, 2, 3, 4, 5, 6, 7, 8, 9, 14, 15, 17, 18, 19, 20, 21, 22, 24, 26, 30} <= numbers
    for name, fn in m.EQUATIONS.items():
        doc = fn.__doc__ or ""
        assert f"{int(name[2:4])}" in doc, f"{name}: docstring must give the equation number"
        assert "=" in doc or "η" in doc, f"{name}: docstring must state the formula"


@pytest.mark.parametrize("name", sorted(m.EQUATIONS))
def test_every_registered_equation_is_finite_and_vectorises(name):
    fn = m.EQUATIONS[name]
    x = np.array([0.5, 1.0, 2.0])
    args = {
        "eq01_drive_force": (x, 0.0475, 5), "eq02_normal_force": (x, 0.35, 0.0),
        "eq03_rolling_resistance": (2.3e11, 0.0027, 19.0, 4600.0, x * 1e-11, x * 1e-4),
        "eq04_rolling_radius_drive": (0.006 * x, 0.0475, 0.35), "eq05_rolling_radius_driven": (0.006 * x, 0.065, 0.35),
        "eq06_ellipticity": (0.05, 0.003 * x), "eq07_groove_radius": (0.5 + 0.03 * x, 0.006),
        "eq08_material_parameter": (2.3e11 * x, 2e-8), "eq09_speed_parameter": (x, 0.1, 0.0027, 2.3e11),
        "eq14_rolling_speed": (100 * x, 7.9, 0.006), "eq15_load_parameter": (100 * x, 2.3e11, 0.0027),
        "eq17_curvature_torque": (0.1, 100 * x, 1e-4, 0.0031, 0.34), "eq18_deformed_radius": (0.006 * x, 0.53),
        "eq19_ellipse_semi_major": (1.1552, 0.0027, 19.0, x * 1e-4),
        "eq20_ellipse_semi_minor": (1.1502, 0.0027, 19.0, x * 1e-4),
        "eq21_hysteresis_torque": (0.006, 100 * x, 19.0), "eq22_ball_friction_torque": (0.1, x, 0.006),
        "eq22_drive_contact_force": (x, x, 0.006, 0.0475, 0.35, 0.0),
        "eq26_driven_contact_force": (x, x, 0.006, 0.065, 0.35, 0.0), "eq24_lever_arm": (0.0475 * x, 0.006, 0.35),
        "eq30_loss_torque": (5, x, 0.025, x, 0.033), "eq30_efficiency": (10 * x, 100 * x, 0.1 * x),
    }[name]
    out = np.asarray(fn(*args), dtype=float)
    assert out.shape == (3,)
    assert np.all(np.isfinite(out))
    # monotone in the first varying argument where the paper's law is a positive power
    if name not in ("eq04_rolling_radius_drive", "eq06_ellipticity", "eq07_groove_radius",
                    "eq26_driven_contact_force", "eq30_efficiency"):
        assert np.all(np.diff(out) > 0), name
