"""The selection's least squares against the textbook formulas (numpy's solver, the normal equations)."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.calibration.leastsquares import orthonormal_basis, weighted_sse, wls


def _design(seed: int, n: int = 400):
    rng = np.random.default_rng(seed)
    speed = rng.uniform(1.0, 300.0, n)
    x = np.column_stack([np.ones(n), speed, np.sqrt(speed)])  # a level, a drag per rad/s, a law between
    y = x @ np.array([0.3, 2e-3, 1e-2]) + rng.normal(0.0, 0.01, n)
    w = rng.uniform(0.5, 2.0, n)
    return x, y, w, rng


@pytest.mark.parametrize("seed", [0, 1])
def test_wls_is_weighted_least_squares_with_the_classical_covariance_without_groups(seed):
    x, y, w, _ = _design(seed)
    sw = np.sqrt(w)
    expected, *_ = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=None)
    fit = wls(x, y, w)
    assert fit.coef == pytest.approx(expected, rel=1e-9, abs=1e-12)
    r = y - x @ expected
    dof = len(y) - x.shape[1]
    cov = np.linalg.inv(x.T @ (x * w[:, None])) * float(np.sum(w * r * r)) / dof
    assert fit.cov == pytest.approx(cov, rel=1e-7)
    assert fit.wsse == pytest.approx(float(np.sum(w * r * r)), rel=1e-12)


def test_wls_with_groups_is_the_cluster_robust_sandwich():
    x, y, w, rng = _design(2)
    groups = rng.integers(0, 40, len(y))
    fit = wls(x, y, w, groups)
    bread = np.linalg.inv(x.T @ (x * w[:, None]))
    score = x * (w * (y - x @ fit.coef))[:, None]
    sums = np.array([score[groups == g].sum(axis=0) for g in np.unique(groups)])
    g = len(sums)
    assert fit.cov == pytest.approx(bread @ (sums.T @ sums * g / (g - 1)) @ bread, rel=1e-7)


def test_an_orthonormal_basis_spans_the_design_and_is_weighted_orthonormal():
    x, y, w, _ = _design(3)
    q = orthonormal_basis(x, w)
    assert q.T @ (q * w[:, None]) == pytest.approx(np.eye(x.shape[1]), abs=1e-10)
    assert wls(q, y, w).pred == pytest.approx(wls(x, y, w).pred, rel=1e-10, abs=1e-12)


def test_weighted_sse_agrees_with_wls_also_on_a_design_near_rank_deficiency():
    x, y, w, rng = _design(4)
    assert weighted_sse(x, y, w) == pytest.approx(wls(x, y, w).wsse, rel=1e-9)
    twin = np.column_stack([x, x[:, 1] * (1.0 + 1e-12 * rng.normal(size=len(y)))])  # a column twice
    assert weighted_sse(twin, y, w) == pytest.approx(wls(x, y, w).wsse, rel=1e-6)
    assert wls(twin, y, w).wsse == pytest.approx(wls(x, y, w).wsse, rel=1e-6)
