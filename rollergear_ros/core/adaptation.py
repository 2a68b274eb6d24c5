"""Online adaptation of the accepted effects and watching the residual.

:class:`RecursiveLeastSquares` adapts the linear coefficients of the accepted effects (registry:
``adaptive``) from the residual; :class:`ChangeDetector` raises an alarm when the residual's block
means drift (CUSUM); :class:`ResidualStats` keeps its running mean and RMS.  Pure Python and numpy;
no rclpy import.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from .effects import EFFECTS, EffectInputs, with_temperature
from .params import Config


def adaptive_effects(config: Config) -> tuple[str, ...]:
    """Accepted effects whose linear coefficient is adapted online (registry: ``adaptive``)."""
    return tuple(n for n in config.effects.enabled() if EFFECTS[n].adaptive)


def effect_coefficients(config: Config) -> dict[str, float]:
    """The linear coefficient of each adaptive effect, as configured."""
    return {n: config.effects.params(n)[EFFECTS[n].coefficient] for n in adaptive_effects(config)}


def coefficient_bounds(names: Iterable[str]) -> list[tuple[float, float]]:
    """The range a parameter file may hold for each adaptive effect's linear coefficient (the
    validation of a written file, :mod:`.paramspecs`): online adaptation stays inside it."""
    from .paramspecs import spec_by_name

    specs = spec_by_name()
    bounds = []
    for n in names:
        spec = specs[f"effects.{n}.{EFFECTS[n].parameter(EFFECTS[n].coefficient).key}"]
        bounds.append((float(spec.low), float(spec.high)))
    return bounds


def regressor_plan(names: Iterable[str], config: Config) -> list[tuple[Callable[[EffectInputs], Any], float]]:
    """For each adaptive effect: its term bound to its parameters with the coefficient set to 1
    (positionally: the per-sample path builds no keyword dict), and the registry's
    ``regressor_scale`` -- worked out once, so the per-sample path only evaluates."""
    plan = []
    for n in names:
        params = {**config.effects.params(n), EFFECTS[n].coefficient: 1.0}
        plan.append((_bound_term(EFFECTS[n].term, params, EFFECTS[n].needs_temperature),
                     EFFECTS[n].regressor_scale(config.effects.params(n))))
    return plan


def _bound_term(term, params: dict[str, float], needs_temperature: bool) -> Callable[[EffectInputs], Any]:
    """``x -> term(x, **params)`` with the parameters passed by position (the same call, cheaper);
    an effect that follows the oil sees a missing temperature at its reference viscosity."""
    args = tuple(params[name] for name in list(inspect.signature(term).parameters)[1:])
    if needs_temperature:
        return lambda x: term(with_temperature(x, params), *args)
    return lambda x: term(x, *args)


def regressors(plan: list[tuple], x: EffectInputs) -> list:
    """Normalised regressor of each adaptive effect of a :func:`regressor_plan`: its term with
    coefficient 1 over its scale (a well-conditioned RLS covariance); floats or arrays."""
    return [term(x) / scale for term, scale in plan]


class RecursiveLeastSquares:
    """RLS with exponential forgetting and a bounded covariance (anti-windup), pure Python.

    ``θ ← θ + K·(y − φᵀθ)``, ``K = Pφ/(λ + φᵀPφ)``, ``P ← (P − KφᵀP)/λ``, then ``P`` is scaled so that
    ``trace(P) ≤ max_trace``; with ``bounds``, each ``θ_i`` is projected into its ``[low, high]``
    (projection RLS: a coefficient a parameter file could not hold is never used) and each projection
    counted in :attr:`held`.  A handful of parameters: plain lists beat numpy here (~5 µs/update).
    """

    def __init__(self, theta0: list[float], forgetting: float, p0: float = 1.0, max_trace: float = 1e6,
                 bounds: list[tuple[float, float]] | None = None) -> None:
        n = len(theta0)
        self.theta = list(theta0)
        self.lam = forgetting
        self.max_trace = max_trace
        self.P = [[p0 if i == j else 0.0 for j in range(n)] for i in range(n)]
        self.bounds = [(-math.inf, math.inf)] * n if bounds is None else list(bounds)
        self.held = [0] * n  #: per parameter: the updates whose θ was projected back to a bound

    def _project(self, i: int, theta: float) -> float:
        low, high = self.bounds[i]
        if theta < low:
            self.held[i] += 1
            return low
        if theta > high:
            self.held[i] += 1
            return high
        return theta

    def predict(self, phi: list[float]) -> float:
        return sum(t * f for t, f in zip(self.theta, phi))

    def update(self, phi: list[float], y: float) -> float:
        """One update; returns the a-priori prediction error ``y − φᵀθ``."""
        n = len(phi)
        if n == 1:  # one adapted effect (the usual case): the same arithmetic without the loops
            return self._update_one(phi[0], y)
        P = self.P
        pphi = [sum(P[i][j] * phi[j] for j in range(n)) for i in range(n)]
        denom = self.lam + sum(phi[i] * pphi[i] for i in range(n))
        err = y - self.predict(phi)
        k = [v / denom for v in pphi]
        self.theta = [self._project(i, t + ki * err) for i, (t, ki) in enumerate(zip(self.theta, k))]
        inv_lam = 1.0 / self.lam
        for i in range(n):
            ki = k[i]
            row = P[i]
            for j in range(n):
                row[j] = (row[j] - ki * pphi[j]) * inv_lam
        trace = sum(P[i][i] for i in range(n))
        if trace > self.max_trace:
            s = self.max_trace / trace
            for row in P:
                for j in range(n):
                    row[j] *= s
        return err

    def _update_one(self, f: float, y: float) -> float:
        """:meth:`update` for one parameter: the same operations in the same order (bit for bit)."""
        p = self.P[0][0]
        pphi = p * f
        denom = self.lam + f * pphi
        theta = self.theta[0]
        err = y - theta * f
        k = pphi / denom
        self.theta[0] = self._project(0, theta + k * err)
        p = (p - k * pphi) * (1.0 / self.lam)
        if p > self.max_trace:
            p *= self.max_trace / p
        self.P[0][0] = p
        return err


class ChangeDetector:
    """Two-sided CUSUM on block averages of the residual (not raw samples).

    ``g⁺ ← max(0, g⁺ + x̄ − δ/2)``, ``g⁻ ← max(0, g⁻ − x̄ − δ/2)``; an alarm when either exceeds
    ``h = 4δ``; after an alarm the sums are held at 0 until ``|x̄| < δ/2`` for 3 blocks, so one
    change gives one alarm while adaptation settles.  While held (:attr:`refractory`) the residual
    is still beyond its threshold.  An alarm before the residual was ever within ``δ/2`` for 3 blocks
    is no change: the residual was off from the start (the parameters lack an effect;
    :attr:`alarm_from_start`).
    """

    def __init__(self, block_samples: int, threshold_nm: float) -> None:
        self.block = block_samples
        self.delta = threshold_nm
        self.acc = 0.0
        self.n = 0
        self.g_pos = 0.0
        self.g_neg = 0.0
        self.alarms = 0
        self.refractory = False
        self.calm_blocks = 0
        self.last_block_mean = math.nan
        self.alarm_times_ns: list[int] = []
        #: per alarm: whether the residual had never been calm before it (off from the start, no change)
        self.alarm_from_start: list[bool] = []
        self._calm_run = 0  # consecutive calm blocks before the first alarm
        self.settled = False  #: the residual has been within δ/2 for 3 blocks in a row

    def add_many(self, x: np.ndarray, t_ns: np.ndarray) -> None:
        """:meth:`add` for arrays of finite residuals (block sums with numpy, CUSUM per block)."""
        if self.delta <= 0 or len(x) == 0:
            return
        i = 0
        n = len(x)
        if self.n:  # complete the open block sample by sample
            while i < n and self.n:
                self.add(float(x[i]), int(t_ns[i]))
                i += 1
        full = (n - i) // self.block
        if full:
            sums = x[i:i + full * self.block].reshape(full, self.block).sum(axis=1)
            ends = t_ns[i + self.block - 1:i + full * self.block:self.block]
            for s_, t_ in zip(sums.tolist(), ends.tolist()):
                # the block's first samples summed with numpy; its last one goes through add(), so
                # the alarm logic stays in one place
                last = float(x[i + self.block - 1])
                self.acc, self.n = s_ - last, self.block - 1
                self.add(last, int(t_))
                i += self.block
        for j in range(i, n):
            self.add(float(x[j]), int(t_ns[j]))

    def add(self, x: float, t_ns: int) -> bool:
        """Add one residual; returns True when this sample raises an alarm."""
        if self.delta <= 0 or not math.isfinite(x):
            return False
        self.acc += x
        self.n += 1
        if self.n < self.block:
            return False
        m = self.acc / self.n
        self.acc, self.n = 0.0, 0
        self.last_block_mean = m
        k = self.delta / 2.0
        if self.refractory:
            self.calm_blocks = self.calm_blocks + 1 if abs(m) < k else 0
            if self.calm_blocks >= 3:
                self.refractory = False
                self.settled = True
            return False
        if not self.settled:
            self._calm_run = self._calm_run + 1 if abs(m) < k else 0
            self.settled = self._calm_run >= 3
        self.g_pos = max(0.0, self.g_pos + m - k)
        self.g_neg = max(0.0, self.g_neg - m - k)
        if self.g_pos > 4 * self.delta or self.g_neg > 4 * self.delta:
            self.alarms += 1
            self.alarm_times_ns.append(t_ns)
            self.alarm_from_start.append(not self.settled)
            self.g_pos = self.g_neg = 0.0
            self.refractory = True
            self.calm_blocks = 0
            return True
        return False


class ResidualStats:
    """Running residual statistics over an exponentially weighted window (for diagnostics)."""

    def __init__(self, alpha: float = 1e-3) -> None:
        self.alpha = alpha
        self.mean = 0.0
        self.mean_sq = 0.0
        self.count = 0

    def add(self, r: float) -> None:
        if not math.isfinite(r):
            return
        self.count += 1
        a = max(self.alpha, 1.0 / self.count)
        self.mean += a * (r - self.mean)
        self.mean_sq += a * (r * r - self.mean_sq)

    def add_many(self, r: np.ndarray) -> None:
        """:meth:`add` for an array of finite residuals (the same numbers, vectorised)."""
        i = 0
        n = len(r)
        warm = int(math.ceil(1.0 / self.alpha))
        while i < n and self.count < warm:  # the running-average phase
            self.add(float(r[i]))
            i += 1
        if i >= n:
            return
        x = r[i:]
        k = len(x)
        a = self.alpha
        w = a * (1.0 - a) ** np.arange(k - 1, -1, -1, dtype=float)
        decay = (1.0 - a) ** k
        # sums, not np.dot: a BLAS dot starts OpenBLAS's threads, which then spin on the other core
        # for a while after each call and take it from the writer's compression thread
        wx = w * x
        self.mean = decay * self.mean + float(wx.sum())
        self.mean_sq = decay * self.mean_sq + float((wx * x).sum())
        self.count += k

    @property
    def rms(self) -> float:
        return math.sqrt(max(self.mean_sq, 0.0)) if self.count else math.nan
