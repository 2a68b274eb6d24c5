"""Weighted least squares for the selection's fits: numerics that do not hinge on the machine.

Every fit goes through the SVD of its design with the columns scaled to unit weighted norm
(:func:`wls`, :func:`orthonormal_basis`), never through ``xᵀWx``, so that a design of columns of
very different size keeps its own condition, not its square; the profiles' thousands of residual
sums use the normal equations only where they are well conditioned (:func:`weighted_sse`).
No rclpy import.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Fit", "RANK_RCOND", "orthonormal_basis", "scaled_svd", "weighted_sse", "wls", "z_two_sided"]


@dataclass
class Fit:
    coef: np.ndarray
    cov: np.ndarray
    wsse: float
    pred: np.ndarray


#: singular values of a design (columns scaled to unit weighted norm) below this share of the largest
#: are no direction of it (the rank every fit and covariance uses)
RANK_RCOND = 1e-12


def scaled_svd(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(u, s, vt, scale)`` of the weighted design ``√w·x`` with its columns scaled to unit norm, the
    directions below :data:`RANK_RCOND` dropped.  Scaling first and never forming ``xᵀWx`` keeps a
    design of columns of very different size (a drag per rad/s beside a level in N·m) at its own
    condition, not its square: what a covariance or a test derived from it says does not hinge on
    the last bits the CPU's BLAS kernel computes."""
    xs = x * np.sqrt(w)[:, None]
    scale = np.linalg.norm(xs, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    u, s, vt = np.linalg.svd(xs / scale, full_matrices=False)
    keep = s > RANK_RCOND * (s[0] if len(s) else 1.0)
    return u[:, keep], s[keep], vt[keep], scale


def orthonormal_basis(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Columns spanning what ``x``'s span (weighted-orthonormal: ``Qᵀ·W·Q = I``).  A fit's prediction,
    residual and a Wald test of its coefficients do not change when its design is replaced by this
    basis; their numerics then no longer depend on the design's condition."""
    _u, s, vt, scale = scaled_svd(x, w)
    return x @ ((vt.T / s) / scale[:, None])


def wls(x: np.ndarray, y: np.ndarray, w: np.ndarray, groups: np.ndarray | None = None) -> Fit:
    """Weighted least squares with a cluster-robust (by ``groups``) sandwich covariance (by the SVD
    of the scaled design: :func:`scaled_svd`)."""
    u, s, vt, scale = scaled_svd(x, w)
    ys = y * np.sqrt(w)
    inv = 1.0 / s
    coef = (vt.T @ (inv * (u.T @ ys))) / scale
    pred = x @ coef
    r = y - pred
    root = (vt.T * inv) / scale[:, None]  # bread = root·rootᵀ = (xᵀWx)⁺
    bread = root @ root.T
    if groups is not None and len(np.unique(groups)) > x.shape[1] + 1:
        score = x * (w * r)[:, None]
        ug, inv_g = np.unique(groups, return_inverse=True)
        sums = np.zeros((len(ug), x.shape[1]))
        np.add.at(sums, inv_g, score)
        g = len(ug)
        meat = sums.T @ sums * (g / (g - 1))
        cov = bread @ meat @ bread
    else:
        dof = max(len(y) - x.shape[1], 1)
        cov = bread * float(np.sum(w * r * r)) / dof
    return Fit(coef, cov, float(np.sum(w * r * r)), pred)


#: the normal equations of a fit (columns scaled to unit norm) are solved where their condition is
#: below this; else the least-squares solver (rank-revealing) is asked
WELL_CONDITIONED = 1e8


def weighted_sse(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """The weighted residual sum of squares of the least-squares fit of ``y`` by the columns of ``x``:
    by its normal equations (columns scaled to unit weighted norm; a profile evaluates thousands of
    these) where they are well conditioned, else by the rank-revealing solver; the residual itself is
    computed, never ``y'Wy − b'X'Wy`` (a near-exact fit would cancel)."""
    wx = x * w[:, None]
    gram = x.T @ wx
    scale = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    g = gram / np.outer(scale, scale)
    if np.linalg.cond(g) < WELL_CONDITIONED:
        coef = np.linalg.solve(g, (wx.T @ y) / scale) / scale
    else:
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=1e-12)
    r = y - x @ coef
    return float(np.sum(w * r * r))


def z_two_sided(alpha: float) -> float:
    """``z`` with ``P(|Z| > z) = alpha`` for a standard normal ``Z`` (scipy.special's inverse normal
    CDF: the same numbers as ``scipy.stats.norm.isf``, without importing scipy.stats, ~1 s)."""
    from scipy.special import ndtri

    return float(-ndtri(alpha / 2))
