"""The measured efficiency: per sample, energy-weighted over a window or a cell, with its uncertainty.

Where both torques are measured, the gearbox's efficiency is the power it delivers over the power it
is given.  With ``P_in = T_in·ω_in`` and ``P_out = T_out·ω_out`` (``ω_out = ω_in/ratio`` where the
output speed is not measured)::

    motoring (P_in > 0):         η = P_out/P_in          (supplied P_in, delivered P_out)
    regeneration (P_in, P_out < 0): η = P_in/P_out       (supplied −P_out, delivered −P_in)

per sample (NaN where the model's efficiency is undefined too: below ``estimator.min_torque_for_efficiency_nm``
or ``min_speed_for_efficiency_rad_s``, or power leaving at both ends), and energy-weighted over many
samples as ``η_E = D/S``, ``D`` the energy delivered and ``S`` the energy supplied (Σ P·dt over both
quadrants) -- what a rig's efficiency figure is.

Its uncertainty follows the GUM's first-order propagation (GUM 5.1.2, 5.2.2) of the sensors' stated
accuracy (``sensors.*``, :mod:`.uncertainty`): a torque reading ``T_meas = T·(1 + g) + o`` with the
gain error ``g`` within ``± b %`` of the reading and the offset ``o`` within ``± a %`` of full scale,
rectangular (standard uncertainties ``b/100/√3`` and ``a·FS/100/√3``).  Both are *systematic*: one
value for every sample of a window, so they do not average out; their sensitivities are sums over the
window::

    ∂η/∂x = (∂D/∂x − η·∂S/∂x)/S,   e.g. ∂S/∂g_in = Σ_motoring P_in·dt,  ∂S/∂o_in = Σ_motoring ω_in·dt

A speed reading's resolution ``q`` is random from sample to sample (``q/√12`` each): its part adds in
quadrature over the samples.  The four torque errors and the speed readings are independent::

    u²(η) = Σ_k (∂η/∂x_k)²·u²(x_k) + Σ_i (∂η/∂ω_i)²·u²(ω)

Everything is a sum over samples, so a window is the sum of its pieces (:class:`EnergyBalance`
adds): :class:`MeasuredEfficiency` keeps them per run, per second of sample time (the node's rolling
window and replay's) and per operating-point cell (replay's summary, measured maps).  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .params import SensorParams

__all__ = ["EnergyBalance", "MeasuredEfficiency", "WindowValue", "balance_of", "gap_ns", "measured_efficiency",
           "powers"]

_RECTANGULAR = 1.0 / math.sqrt(3.0)
_QUANTISED = 1.0 / math.sqrt(12.0)
#: samples further apart than this many sample periods (and :data:`MIN_GAP_S`) are a gap: nothing is
#: integrated across it
GAP_PERIODS = 5.0
MIN_GAP_S = 0.1
#: delivered energy within this share of the supplied: no power leaves the output (a spin test), no efficiency
NO_OUTPUT_SHARE = 0.01


def powers(torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio: float):
    """``(P_in, P_out, ω_out)`` [W, W, rad/s]: ``ω_out`` measured, or ``ω_in/ratio`` where NaN."""
    w_in = np.asarray(speed_rad_s, dtype=float)
    w_out = np.asarray(out_speed_rad_s, dtype=float)
    w_out = np.where(np.isnan(w_out), w_in / ratio, w_out)
    return np.asarray(torque_nm, dtype=float) * w_in, np.asarray(out_torque_nm, dtype=float) * w_out, w_out


def _quadrants(p_in, p_out):
    """Masks of motoring (power in at the input) and regeneration (power in at the output)."""
    motoring = p_in > 0
    regenerating = (p_in < 0) & (p_out < 0)
    return motoring, regenerating


def measured_efficiency(torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio: float,
                        min_torque_nm: float = 0.0, min_speed_rad_s: float = 0.0):
    """Per-sample measured efficiency (module docstring): ``P_out/P_in`` motoring, ``P_in/P_out``
    regenerating; NaN without a measured output torque, below the thresholds, or where power leaves
    at both ends.  Not clipped: a reading above 1 is what the sensors said."""
    p_in, p_out, _ = powers(torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio)
    motoring, regenerating = _quadrants(p_in, p_out)
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(motoring, p_out / p_in, np.where(regenerating, p_in / p_out, np.nan))
    small = (np.abs(np.asarray(torque_nm, dtype=float)) < min_torque_nm) \
        | (np.abs(np.asarray(speed_rad_s, dtype=float)) < min_speed_rad_s)
    return np.where(small | ~np.isfinite(p_out), np.nan, eta)


@dataclass
class EnergyBalance:
    """Energy supplied to and delivered by the gearbox over some samples, with the sums its
    uncertainty needs (all additive: ``a + b`` is the balance of both sets of samples).

    Units: energies in J, angles in rad; ``*_speed_*`` sums are of squared torque·time [(N·m·s)²]."""

    supplied_j: float = 0.0
    delivered_j: float = 0.0
    samples: int = 0
    seconds: float = 0.0
    # sensitivities of supplied (s_) and delivered (d_) energy to each torque sensor's gain (per unit)
    # and offset (per N·m): Σ P·dt and Σ ω·dt over the quadrant the sensor's side supplies or delivers in
    s_gain_in: float = 0.0
    d_gain_in: float = 0.0
    s_offset_in: float = 0.0
    d_offset_in: float = 0.0
    s_gain_out: float = 0.0
    d_gain_out: float = 0.0
    s_offset_out: float = 0.0
    d_offset_out: float = 0.0
    # random speed readings: Σ a², Σ a·b, Σ b² of ∂D/∂ω_i = a_i, ∂S/∂ω_i = b_i (input speed, the output's
    # derived from it where not measured) and of the measured output speed
    in_aa: float = 0.0
    in_ab: float = 0.0
    in_bb: float = 0.0
    out_aa: float = 0.0
    out_ab: float = 0.0
    out_bb: float = 0.0
    #: the model's loss energy over the same samples (Σ loss power·dt), when it was given
    model_loss_j: float = 0.0
    angle_rad: float = 0.0  #: the input's angle turned over the samples (Σ |ω_in|·dt)

    def __add__(self, other: EnergyBalance) -> EnergyBalance:
        return EnergyBalance.from_list(np.add(self.as_list(), other.as_list()))

    @property
    def lost_j(self) -> float:
        """Energy lost in the gearbox (supplied − delivered)."""
        return self.supplied_j - self.delivered_j

    @property
    def no_output(self) -> bool:
        """No power leaves the output (a spin test: nothing on it): what is delivered is within
        :data:`NO_OUTPUT_SHARE` of what is supplied -- the drive power is all loss, and an efficiency says nothing."""
        return self.supplied_j > 0 and abs(self.delivered_j) <= NO_OUTPUT_SHARE * self.supplied_j

    @property
    def efficiency(self) -> float:
        """Energy-weighted efficiency ``D/S`` (NaN when nothing was supplied)."""
        return self.delivered_j / self.supplied_j if self.supplied_j > 0 else math.nan

    @property
    def model_efficiency(self) -> float:
        """The model's over the same samples: ``1 − L_model/S`` (NaN when nothing was supplied)."""
        return 1.0 - self.model_loss_j / self.supplied_j if self.supplied_j > 0 else math.nan

    def as_list(self) -> list[float]:
        """The fields in order (a table's cell; :meth:`from_list` reads it back)."""
        return [float(getattr(self, f.name)) for f in fields(self)]

    @classmethod
    def from_list(cls, values) -> EnergyBalance:
        """The balance of the fields in order (:meth:`as_list`, or summed rows: ``samples`` an integer count)."""
        return cls(*(int(round(v)) if f.name == "samples" else float(v) for f, v in zip(fields(cls), values)))

    def uncertainty(self, sensors: SensorParams) -> float:
        """Standard uncertainty of :attr:`efficiency` from the sensors' stated accuracy (module
        docstring); 0 when none is stated, NaN when the efficiency is."""
        eta = self.efficiency
        return self._spread(sensors, eta) / self.supplied_j if math.isfinite(eta) else math.nan

    @property
    def loss_nm(self) -> float:
        """The measured loss as an input-referred torque: energy lost over the input's angle turned
        (the energy-weighted mean loss torque; NaN without one)."""
        return self.lost_j / self.angle_rad if self.angle_rad > 0 else math.nan

    @property
    def model_loss_nm(self) -> float:
        """The model's, over the same samples and angle."""
        return self.model_loss_j / self.angle_rad if self.angle_rad > 0 else math.nan

    def loss_uncertainty_nm(self, sensors: SensorParams) -> float:
        """Standard uncertainty of :attr:`loss_nm`: ``u(S − D)/Θ`` by the same propagation (the angle
        Θ's own resolution left out: its part is ``L·q/|ω|``, far below the torque sensors')."""
        return self._spread(sensors, 1.0) / self.angle_rad if self.angle_rad > 0 else math.nan

    def _spread(self, sensors: SensorParams, eta: float) -> float:
        """Standard uncertainty of ``D − η·S`` [J] (:meth:`uncertainty` and :meth:`loss_uncertainty_nm`)."""
        u_g_in = sensors.input_torque_reading_pct / 100.0 * _RECTANGULAR
        u_o_in = sensors.input_torque_fs_pct * sensors.input_torque_full_scale_nm / 100.0 * _RECTANGULAR
        u_g_out = sensors.output_torque_reading_pct / 100.0 * _RECTANGULAR
        u_o_out = sensors.output_torque_fs_pct * sensors.output_torque_full_scale_nm / 100.0 * _RECTANGULAR
        u_w_in = sensors.input_speed_resolution_rad_s * _QUANTISED
        u_w_out = sensors.output_speed_resolution_rad_s * _QUANTISED
        var = sum(((d - eta * s_) * u) ** 2 for d, s_, u in (
            (self.d_gain_in, self.s_gain_in, u_g_in), (self.d_offset_in, self.s_offset_in, u_o_in),
            (self.d_gain_out, self.s_gain_out, u_g_out), (self.d_offset_out, self.s_offset_out, u_o_out)))
        var += (self.in_aa - 2 * eta * self.in_ab + eta * eta * self.in_bb) * u_w_in ** 2
        var += (self.out_aa - 2 * eta * self.out_ab + eta * eta * self.out_bb) * u_w_out ** 2
        return math.sqrt(max(var, 0.0))


def gap_ns(period_ns: float) -> float:
    """The longest step integrated: :data:`GAP_PERIODS` sample periods, at least :data:`MIN_GAP_S`."""
    return max(GAP_PERIODS * period_ns, MIN_GAP_S * 1e9)


def energy_steps_s(t_ns: np.ndarray, previous_ns: int | None, period_ns: float) -> tuple[np.ndarray, float]:
    """Each sample's time step [s] over which replay's summary and ``predict`` integrate the loss
    power: from the sample before (``previous_ns`` before the first; without one the first has
    none), nothing across a gap longer than five sample periods (missing data).  ``period_ns``:
    the period seen so far, renewed from the median step of these samples; returns it too."""
    dt = _steps_ns(t_ns, previous_ns)
    period_ns = _median_step_ns(dt, period_ns)
    return _within(dt, 5 * max(period_ns, 1.0)), period_ns


def _integration_steps_s(t_ns, previous_ns: int | None = None, period_ns: float | None = None) -> np.ndarray:
    """Each sample's time step [s] from the one before (``previous_ns`` before the first; without
    one the first has none), none across a gap (:func:`gap_ns` of ``period_ns``, else of the median step)."""
    dt = _steps_ns(t_ns, previous_ns)
    return _within(dt, gap_ns(period_ns or _median_step_ns(dt, 0.0)))


def _steps_ns(t_ns, previous_ns: int | None) -> np.ndarray:
    """Each sample's step [ns] from the one before (``previous_ns`` before the first, else 0)."""
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) == 0:
        return np.zeros(0)
    return np.diff(t, prepend=t[0] if previous_ns is None else previous_ns).astype(float)


def _median_step_ns(dt: np.ndarray, otherwise: float) -> float:
    """The median of the positive steps, ``otherwise`` when there is none."""
    positive = dt[dt > 0]
    return float(np.median(positive)) if len(positive) else otherwise


def _within(dt: np.ndarray, longest_ns: float) -> np.ndarray:
    """The steps in seconds, 0 where a step is none or longer than ``longest_ns`` (a gap)."""
    return np.where((dt > 0) & (dt <= longest_ns), dt, 0.0) * 1e-9


def _terms(torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio: float, dt_s, model_loss_w=None):
    """Per-sample contributions to each field of :class:`EnergyBalance` (arrays, NaN-free), and
    the mask of the motoring samples."""
    t_in = np.asarray(torque_nm, dtype=float)
    w_in = np.asarray(speed_rad_s, dtype=float)
    t_out = np.asarray(out_torque_nm, dtype=float)
    w_out_meas = np.asarray(out_speed_rad_s, dtype=float)
    derived = np.isnan(w_out_meas)
    p_in, p_out, w_out = powers(t_in, w_in, t_out, w_out_meas, ratio)
    ok = np.isfinite(p_in) & np.isfinite(p_out) & np.isfinite(w_out)
    motoring, regenerating = _quadrants(p_in, p_out)
    mot = np.where(ok & motoring, dt_s, 0.0)
    reg = np.where(ok & regenerating, dt_s, 0.0)
    t_in, w_in, t_out, w_out = (np.where(ok, a, 0.0) for a in (t_in, w_in, t_out, w_out))
    p_in, p_out = np.where(ok, p_in, 0.0), np.where(ok, p_out, 0.0)
    # ∂D/∂ω and ∂S/∂ω per sample: motoring D = T_out·ω_out, S = T_in·ω_in; regenerating D = −T_in·ω_in,
    # S = −T_out·ω_out; a derived output speed ω_in/ratio moves with ω_in
    gear = np.where(derived, 1.0 / ratio, 0.0)
    a_in = mot * t_out * gear - reg * t_in
    b_in = mot * t_in - reg * t_out * gear
    a_out = np.where(derived, 0.0, mot * t_out)
    b_out = np.where(derived, 0.0, -reg * t_out)
    model = np.zeros_like(mot) if model_loss_w is None else \
        np.nan_to_num(np.abs(np.asarray(model_loss_w, dtype=float))) * (mot + reg)
    return {
        "model_loss_j": model, "angle_rad": np.abs(w_in) * (mot + reg),
        "supplied_j": mot * p_in - reg * p_out, "delivered_j": mot * p_out - reg * p_in,
        "samples": (mot > 0) | (reg > 0), "seconds": mot + reg,
        "s_gain_in": mot * p_in, "d_gain_in": -reg * p_in, "s_offset_in": mot * w_in, "d_offset_in": -reg * w_in,
        "s_gain_out": -reg * p_out, "d_gain_out": mot * p_out, "s_offset_out": -reg * w_out,
        "d_offset_out": mot * w_out,
        "in_aa": a_in * a_in, "in_ab": a_in * b_in, "in_bb": b_in * b_in,
        "out_aa": a_out * a_out, "out_ab": a_out * b_out, "out_bb": b_out * b_out,
    }, mot > 0


def balance_of(t_ns, torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio: float,
               previous_ns: int | None = None, period_ns: float | None = None) -> EnergyBalance:
    """The :class:`EnergyBalance` of the samples (times in ns; ``previous_ns``: the sample before
    the first, which the first integrates from; ``period_ns``: the sample period, else the median step)."""
    dt = _integration_steps_s(t_ns, previous_ns, period_ns)
    return EnergyBalance.from_list(_rows(_terms(torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, ratio, dt)[0],
                                         len(dt)).sum(axis=1))


@dataclass(frozen=True)
class WindowValue:
    """The measured efficiency over one window: what the node publishes and replay writes once a second."""

    end_ns: int  #: the window ends here (a whole second of sample time: the samples before it)
    efficiency: float  #: energy-weighted (NaN: nothing supplied in the window)
    uncertainty: float  #: its standard uncertainty (0: no accuracy stated in ``sensors.*``)
    samples: int
    window_s: float


class MeasuredEfficiency:
    """Running :class:`EnergyBalance` sums over samples that come in time order, in any batches:
    the whole run (:attr:`total`), one per second of sample time (for the rolling window of the last
    ``window_s``: :meth:`window`) and, with ``speed_step_rpm`` and ``torque_step_nm``, one per
    operating-point cell (the nearest node of that grid: :meth:`cells`); :attr:`motoring` and
    :attr:`regenerating` split the total by the end power came in at.

    A sample more than :func:`gap_ns` after the one before starts a new stretch: nothing is
    integrated across the gap (a pause of the rig, the next recording)."""

    def __init__(self, ratio: float, period_s: float, window_s: float = 10.0, speed_step_rpm: float | None = None,
                 torque_step_nm: float | None = None) -> None:
        """``period_s``: the sample period (the estimator's): steps beyond :func:`gap_ns` of it are gaps."""
        self.ratio = ratio
        self._period_ns = float(period_s) * 1e9
        self.window_s = float(window_s)
        # the sums as rows of the balance's fields (:data:`_FIELDS`), made balances when asked for
        self._total = np.zeros(len(_FIELDS))
        self._motoring = np.zeros(len(_FIELDS))
        self.last_ns: int | None = None
        self._seconds: dict[int, np.ndarray] = {}  # whole second of sample time -> its sums
        self._first_s: int | None = None
        self._grid = (speed_step_rpm, torque_step_nm) if speed_step_rpm and torque_step_nm else None
        self._cells: dict[tuple[int, int], np.ndarray] = {}

    @property
    def total(self) -> EnergyBalance:
        """Every sample added."""
        return EnergyBalance.from_list(self._total)

    @property
    def motoring(self) -> EnergyBalance:
        """The part of :attr:`total` where power came in at the input."""
        return EnergyBalance.from_list(self._motoring)

    @property
    def regenerating(self) -> EnergyBalance:
        """... and where it came in at the output."""
        return EnergyBalance.from_list(self._total - self._motoring)

    def add(self, t_ns, torque_nm, speed_rad_s, out_torque_nm, out_speed_rad_s, model_loss_w=None) -> None:
        """Samples in time order (arrays alike; a NaN output torque: not measured, left out);
        ``model_loss_w``: the model's loss power at each, for :attr:`EnergyBalance.model_loss_j`."""
        if out_torque_nm is None:
            return
        t = np.asarray(t_ns, dtype=np.int64)
        out = np.asarray(out_torque_nm, dtype=float)
        keep = np.isfinite(out)
        if not keep.any():
            return
        if not keep.all():
            t, out = t[keep], out[keep]
            torque_nm, speed_rad_s = np.asarray(torque_nm)[keep], np.asarray(speed_rad_s)[keep]
            out_speed_rad_s = np.asarray(out_speed_rad_s)[keep]
            model_loss_w = None if model_loss_w is None else np.asarray(model_loss_w)[keep]
        dt = _integration_steps_s(t, self.last_ns, self._period_ns)
        terms, motoring = _terms(torque_nm, speed_rad_s, out, out_speed_rad_s, self.ratio, dt, model_loss_w)
        rows = _rows(terms, len(t))  # (fields, samples)
        self._total += rows.sum(axis=1)
        self._motoring += rows[:, motoring].sum(axis=1)  # (no BLAS: its threads would spin beside the writer)
        second = t // 1_000_000_000
        starts = np.flatnonzero(np.diff(second, prepend=second[0] - 1))
        _accumulate(self._seconds, second[starts].tolist(), np.add.reduceat(rows, starts, axis=1))
        if self._first_s is None:
            self._first_s = int(second[0])
        self.last_ns = int(t[-1])
        if self._grid is not None:
            rpm = np.asarray(speed_rad_s, dtype=float) * (30.0 / math.pi)
            i = np.rint(rpm / self._grid[0]).astype(np.int64)
            j = np.rint(np.asarray(torque_nm, dtype=float) / self._grid[1]).astype(np.int64)
            order = np.lexsort((j, i))  # the samples by cell
            i, j = i[order], j[order]
            starts = np.flatnonzero(np.diff(i, prepend=i[0] - 1) | np.diff(j, prepend=j[0] - 1))
            _accumulate(self._cells, list(zip(i[starts].tolist(), j[starts].tolist())),
                        np.add.reduceat(rows[:, order], starts, axis=1))

    def prime(self, last_ns: int) -> None:
        """A sample before the first added (a time slice's): the first integrates from it."""
        self.last_ns = last_ns

    def boundaries(self, since_s: int | None) -> list[int]:
        """The second boundaries completed after ``since_s`` (None: after the first sample's second)
        up to the last sample's second whose last second holds samples: the windows to publish -- once
        per second while samples come, none for the seconds of an idle gap (their windows would all
        be published at once when the samples resume, each of stale or no samples)."""
        if self.last_ns is None or self._first_s is None:
            return []
        first = self._first_s if since_s is None else since_s
        return [b for b in range(first + 1, self.last_ns // 1_000_000_000 + 1) if b - 1 in self._seconds]

    def forget(self, boundary_s: int) -> None:
        """Drop the seconds no window ending at ``boundary_s`` or later holds (after publishing it)."""
        first = boundary_s - math.ceil(self.window_s)
        for key in [k for k in self._seconds if k < first]:
            del self._seconds[key]

    def window(self, boundary_s: int) -> EnergyBalance:
        """The balance of the ``window_s`` before the second boundary ``boundary_s`` (whole seconds:
        a window of 10 s at 20 s holds seconds 10 … 19)."""
        first = boundary_s - math.ceil(self.window_s)
        return EnergyBalance.from_list(sum((row for k, row in self._seconds.items() if first <= k < boundary_s),
                                           np.zeros(len(_FIELDS))))

    def window_value(self, boundary_s: int, sensors: SensorParams) -> WindowValue:
        """:meth:`window` as the value published: efficiency, uncertainty, samples."""
        b = self.window(boundary_s)
        return WindowValue(boundary_s * 1_000_000_000, b.efficiency, b.uncertainty(sensors), b.samples, self.window_s)

    def cells(self) -> list[tuple[float, float, EnergyBalance]]:
        """``(input speed [rpm], input torque [N·m], balance)`` of each operating-point cell (the
        grid's node its samples are nearest to), by speed then torque."""
        if self._grid is None:
            return []
        ds, dt = self._grid
        return [(i * ds, j * dt, EnergyBalance.from_list(self._cells[(i, j)])) for i, j in sorted(self._cells)]


_FIELDS = tuple(f.name for f in fields(EnergyBalance))
_FIELD_INDEX = {name: k for k, name in enumerate(_FIELDS)}


def _rows(terms: dict[str, np.ndarray], n: int) -> np.ndarray:
    """The per-sample terms as rows in :data:`_FIELDS` order (a field without a term: zeros)."""
    rows = np.zeros((len(_FIELDS), n))
    for k, v in terms.items():
        rows[_FIELD_INDEX[k]] = v
    return rows


def _accumulate(table: dict, keys: list, sums: np.ndarray) -> None:
    """Add each column of ``sums`` to ``table[key]`` (a new key gets its own copy)."""
    for key, piece in zip(keys, sums.T):
        if key in table:
            table[key] += piece
        else:
            table[key] = piece.copy()
