"""The registry of extra effects the paper's model lacks: one descriptor per effect, read by everyone.

Each effect is a pure function ``term(x, **params)`` -- its contribution to the *measured
input-referred loss* ``T_loss,meas = (T_in·ω_in − T_out·ω_out)/|ω_in|`` [N·m], positive = more
loss -- plus an :class:`Effect` descriptor: its parameters (names in the parameter file and in
``calibrate --json`` / ``simulate --effect``, defaults, ranges), whether it is a physical loss or a
sensor error, which parameter is its linear coefficient, which one ``calibrate`` profiles on a
grid, the regressor scale of the online RLS, and which other effects the data may confuse it
with.  The functions use only ``abs``, ``*``, ``+`` and :func:`.floatops.power` (and ``math.exp``
where a batch repeats single steps) so they run on Python floats (the node's per-sample path) and
on numpy arrays (replay, calibration, simulation) alike -- and give the same floats on both.

=========================  ===========================================  ======================
effect                     contribution to the measured loss [N·m]      kind
=========================  ===========================================  ======================
``drag_constant``          ``c``                                        loss (seal, return track)
``drag_speed``             ``c·|ω|^p``                                  loss (churning, windage)
``load_dependent``         ``c·|T_load|^q``                             loss (bearing load, sliding)
``load_speed``             ``c·|T_load|·|ω|^p``                         loss (load × speed: mesh sliding, power loss)
``viscosity_temperature``  ``scale·T_Fr·(s(θ) − 1)``, ``s = (η(θ)/η0)^0.66``  loss (oil warming), scales Fr
``torque_offset``          ``b·sgn(ω)``                                 sensor zero error
``torque_gain``            ``g·T·sgn(ω)``                               sensor gain error
=========================  ===========================================  ======================

``T_load`` is the load on the output side, referred to the input: the torque the gearbox passes on,
``T_load = T − sgn(ω)·L`` with ``L`` the whole loss (the power balance ``T_load·ω_in = T_out·ω_out``).
A law in the load takes it, never the drive torque ``T``: under a light load the drive torque is mostly
the loss itself, and a law of it would explain the loss by the loss.  Calibration reads it from the
measured output torque (``T − sgn(ω)·L_meas``); the estimator, which has the drive torque only, solves
``T_load = T − sgn(ω)·(L_model + L_other + F(|T_load|))`` for it (:func:`.effectsum.output_load`: ``F`` the
laws in the load, ``L_other`` every other loss).

``T_Fr`` is the Fr part of the model (eq. 3, ∝ η^0.66 through U^0.66 of eq. 9) -- the only part
that depends on the viscosity, so ``T_Fr·(s − 1)`` is the whole model at ``η(θ)`` minus the model
at ``η0`` -- and ``η(θ) = η0·exp(B/(θ + C) − B/(θ_ref + C))`` (Vogel).  ``calibrate`` fits both B
and C with ``scale`` held at 1 (the model at ``η(θ)``, as ``interface.md`` defines the effect), then
reports ``scale`` fitted freely as a check of the model's η^0.66.  Sensor errors are not losses: they enter
the comparison with the measured loss (the residual), never the published loss torque; the two
torque-sensor errors also corrupt the model's input torque (:func:`corrected_torque`).

Adding an effect
----------------
1. Write its function below: ``def name(x: EffectInputs, coef, ...)`` returning N·m, linear in
   its coefficient, the formula and its cause in the docstring.
2. Add one :class:`Effect` entry to :data:`EFFECTS` (or call :func:`register`): parameters with
   their YAML key, short name, default, unit and range; ``physical``; ``coefficient``; for a
   nonlinear parameter ``member`` with its grid and bounds; ``regressor_scale`` when the RLS needs
   a normalised column; ``separated_from`` for effects whose columns look alike, with the data
   that tells them apart; ``plotted_against``, the variable the report draws its curve over.  Its
   kind is said by the descriptor too, never by its name elsewhere: a sensor error says how it
   corrupts the torque reading (``reading_error``), a factor on the model's Fr part sets
   ``scales_fr``, an effect with memory its ``state_step``/``state_steps``, the oil's own viscosity
   law ``viscosity_law``, a loss law in the output-side load (its term reads ``x.abs_load``) its
   ``load_exponent``.
3. Tests: the function against its formula, and a recording simulated with the effect declared
   that ``calibrate`` finds (``test/core/test_effects.py`` shows both, for a toy loss registered at
   run time, and a toy sensor error that simulate and the estimator take from its descriptor).

Everything else follows from the entry: the parameter file's ``effects.<name>.*`` keys and their
validation (:mod:`.params`), the estimator's terms and its RLS regressors (:mod:`.estimator`), the
candidate groups, fit parameters, intervals and written YAML of ``calibrate``, ``simulate
--effect``, the report, and ``docs/effects.md`` (``python -m rollergear_ros.core.effects``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple
from collections.abc import Callable, Mapping

from .floatops import power

FR_VISCOSITY_EXPONENT = 0.66  # Fr ∝ U^0.66 ∝ η^0.66 (eq. 3, 9)
#: regressors of the RLS are normalised at these operating points (a well-conditioned covariance)
SPEED_REF_RAD_S = 100.0
TORQUE_REF_NM = 100.0


class EffectInputs(NamedTuple):
    """What an effect's term may depend on, per sample (floats or equal-length arrays)."""

    abs_torque: Any  #: |T| of the model's input torque [N·m]
    abs_speed: Any  #: |ω| [rad/s]
    torque: Any  #: signed T [N·m]
    rot_sign: Any  #: direction of rotation as the loss opposes it (±1)
    temperature_c: Any = math.nan  #: oil temperature θ [°C]
    fr_part_nm: Any = 1.0  #: the model's Fr part T_Fr [N·m] (1: a relative change of it)
    #: the states of the effects with memory (effect -> its state at this sample, :attr:`Effect.state_step`);
    #: empty: their steady state (an operating point of a map, a steady dwell)
    state: Mapping[str, Any] = {}
    #: |T_load| [N·m], the load on the output side referred to the input, what the laws in the load take
    #: (None: not known; :func:`additive_terms` solves it from the drive torque and the other losses)
    abs_load: Any = None


# ------------------------------------------------------------------------------------ terms
def drag_constant(x: EffectInputs, c):
    """Constant drag: ``ΔT = c`` (seal friction, return-track friction, Coulomb drag)."""
    return c + 0.0 * x.abs_speed


def drag_speed(x: EffectInputs, c, p):
    """Speed drag: ``ΔT = c·|ω|^p`` (churning p≈1–2, viscous p=1, windage p≈2)."""
    return c * power(x.abs_speed, p)


def stribeck(x: EffectInputs, c, omega_s, delta):
    """Stribeck excess: ``ΔT = c·exp(−(|ω|/ω_s)^δ)`` (breakaway friction above Coulomb, fading with speed).

    With ``drag_constant`` (the Coulomb level ``Fc``) it is ``(Fc + (Fs − Fc)·exp(−(|ω|/ω_s)^δ))·sgn ω``;
    ``c = Fs − Fc`` the breakaway excess, ``ω_s`` the Stribeck speed, ``δ`` its shape (2: Gaussian).
    """
    return c * power(math.e, -power(x.abs_speed / omega_s, delta))


def load_dependent(x: EffectInputs, c, q):
    """Load-dependent friction: ``ΔT = c·|T_load|^q`` (bearing load friction, sliding; T_load the output-side load)."""
    return c * power(x.abs_load, q)


def drag_direction(x: EffectInputs, c, p):
    """Drag that differs by direction: ``ΔT = c·|ω|^p·sgn ω`` (forward c·|ω|^p more, in reverse as much less).

    Beside ``drag_speed`` it makes the speed drag ``(c_speed ± c)·|ω|^p`` per direction (a worn or
    preloaded screw, a seal whose lip points one way).  A Coulomb friction that differs by direction is
    ``torque_offset``'s column: its ``b`` reads as forward/reverse Coulomb friction ``c ± b``.
    """
    return c * power(x.abs_speed, p) * x.rot_sign


def stribeck_direction(x: EffectInputs, c, omega_s, delta):
    """Stribeck excess that differs by direction: ``ΔT = c·exp(−(|ω|/ω_s)^δ)·sgn ω`` (c of either sign).

    Near standstill forward c more, in reverse as much less; beside ``stribeck`` the breakaway excess
    is ``c_stribeck ± c`` per direction: a drive lifting and lowering a load whose lifting torque rises
    near standstill while its lowering torque falls (a worm, a lead screw under a payload).  Far above
    ``ω_s`` it vanishes, which tells it from ``torque_offset``'s constant ``b·sgn ω``.
    """
    return stribeck(x, c, omega_s, delta) * x.rot_sign


def backdrive(x: EffectInputs, c, q):
    """Back-driving friction: ``ΔT = c·|T_load|^q`` while the output drives the input (``T·ω < 0``), else 0.

    Friction that appears only when the power flows back (a self-locking tendency of the ball track, a
    one-way clutch, a worm's back-driving); motoring losses do not carry it.  Its size follows the
    output-side load ``T_load``, whether the power flows back the drive torque says.
    """
    return c * power(x.abs_load, q) * ((x.torque * x.rot_sign < 0) * 1.0)


def load_speed(x: EffectInputs, c, p):
    """Load-speed friction: ``ΔT = c·|T_load|·|ω|^p`` (a loss power ∝ transmitted power·|ω|^(p−1): mesh sliding)."""
    return c * x.abs_load * power(x.abs_speed, p)


def drag_viscous(x: EffectInputs, c, p, a, B, C, theta_ref):
    """Churning that follows the oil: ``ΔT = c·(η(θ)/η_ref)^a·|ω|^p`` (thick cold oil churns harder).

    ISO/TR 14179-2 writes no-load losses with the viscosity inside; ``η(θ)/η_ref = exp(B/(θ + C) −
    B/(θ_ref + C))`` is the calibrated oil's Vogel law (the model's rolling part follows the same oil).
    """
    return c * power(math.e, a * (B / (x.temperature_c + C) - B / (theta_ref + C))) * power(x.abs_speed, p)


def dahl(x: EffectInputs, c, presliding):
    """Coulomb friction with memory (Dahl): ``ΔT = c·z·sgn ω``, the bristle state ``z`` → ``sgn ω``.

    ``dz/dφ = sgn(ω) − z`` per ``presliding`` radians turned (:func:`dahl_step`): after a reversal
    the friction follows the motion since the reversal instead of flipping at once (presliding,
    hysteresis); in steady motion ``z = sgn ω`` and it is a constant drag ``c``.  Without a state
    (an operating point) it is that steady value.
    """
    return c * x.state.get("dahl", x.rot_sign) * x.rot_sign


#: an effect's memory steps on speeds beyond this many of the speed reading's noise widths σ from
#: standstill (where the direction is known, as for a measured loss): a reading at rest is noise, and
#: its magnitude summed sample by sample would turn the state as if the drive moved (a dwell of 1 s at
#: 500 Hz with σ = 0.002 rad/s relaxes a state of presliding 0.01 rad by a fifth)
STATE_STILL_WIDTHS = 3.0


def state_speed(speed_rad_s, sign_width_rad_s: float):
    """The speed an effect's memory steps on: the reading, 0 within :data:`STATE_STILL_WIDTHS` noise
    widths of standstill (a scalar or an array, as given)."""
    still = STATE_STILL_WIDTHS * sign_width_rad_s
    if isinstance(speed_rad_s, float):
        return speed_rad_s if abs(speed_rad_s) >= still else 0.0
    import numpy as np

    w = np.asarray(speed_rad_s, dtype=float)
    return np.where(np.abs(w) >= still, w, 0.0)


def dahl_step(z: float, speed_rad_s: float, dt_s: float, params: Mapping[str, float]) -> float:
    """The Dahl state after ``dt_s`` at ``speed_rad_s``: ``z → s + (z − s)·exp(−|ω|·dt/presliding)``,
    ``s = sgn ω`` -- exact for a speed constant over the step (0: no motion, no change)."""
    if speed_rad_s == 0.0 or dt_s <= 0.0:
        return z
    s = 1.0 if speed_rad_s > 0 else -1.0
    return s + (z - s) * math.exp(-abs(speed_rad_s) * dt_s / params["presliding"])


def dahl_steps(z: float, speed_rad_s, dt_s, params: Mapping[str, float]):
    """:func:`dahl_step` over a batch of samples in time order, ``dt_s`` each one's step: the same
    float operations one after the other (bit for bit the states of single steps), the exponentials
    of the moving samples at once (``math.exp``, as the single step)."""
    import numpy as np

    w, dt = np.asarray(speed_rad_s, dtype=float), np.asarray(dt_s, dtype=float)
    moving = (w != 0.0) & (dt > 0.0)
    decay = np.ones(len(w))
    decay[moving] = [math.exp(v) for v in (-np.abs(w[moving]) * dt[moving] / params["presliding"]).tolist()]
    out = []
    for move, s, a in zip(moving.tolist(), np.sign(w).tolist(), decay.tolist()):
        if move:
            z = s + (z - s) * a
        out.append(z)
    return np.array(out)


def viscosity_scale(b_k, c_k, theta_ref_c, theta_c):
    """``s = (η(θ)/η0)^0.66`` with Vogel ``η(θ)/η0 = exp(B/(θ + C) − B/(θ_ref + C))``."""
    return power(math.e, FR_VISCOSITY_EXPONENT * (b_k / (theta_c + c_k) - b_k / (theta_ref_c + c_k)))


def viscosity_temperature(x: EffectInputs, B, C, theta_ref, scale):
    """Oil viscosity at the oil temperature: ``ΔT = scale·T_Fr·((η(θ)/η0)^0.66 − 1)``.

    The model's Fr part evaluated at ``η(θ)`` instead of ``η0`` (``scale = 1``), Vogel ``η(θ)``
    (:func:`viscosity_scale`).  With ``x.fr_part_nm = 1`` it is the relative change of Fr that the
    estimator applies inside the model (:attr:`Effect.scales_fr`).
    """
    return scale * x.fr_part_nm * (viscosity_scale(B, C, theta_ref, x.temperature_c) - 1.0)


def torque_offset(x: EffectInputs, b):
    """Torque-sensor zero error, input-referred: ``ΔT = b·sgn(ω)`` (flips with direction)."""
    return b * x.rot_sign


def torque_gain(x: EffectInputs, g):
    """Torque-sensor gain error: ``ΔT = g·T·sgn(ω)`` (= g|T| motoring, −g|T| regenerating)."""
    return g * x.torque * x.rot_sign


def corrected_torque(torque_meas, offset_nm: float, gain: float):
    """Drive torque with the torque sensor's errors removed: ``T = (T_meas − b)/(1 + g)``.

    The model and the physical effects see this torque; the measured loss keeps the sensor's
    reading, so the errors appear there as ``(g·T + b)·sgn ω`` (:func:`torque_offset`,
    :func:`torque_gain`).
    """
    if offset_nm == 0.0 and gain == 0.0:
        return torque_meas
    return (torque_meas - offset_nm) / (1.0 + gain)


# ------------------------------------------------------------------------------------ descriptors
@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect."""

    short: str  #: name in ``calibrate --json`` ``params`` and in ``simulate --effect NAME:short=value``
    key: str  #: key under ``effects.<effect>.`` in the parameter file (SI unit in the name where one applies)
    default: float  #: in the parameter file
    description: str
    unit: str = ""
    low: float = -1e4
    high: float = 1e4
    low_open: bool = False
    simulated: float | None = None  #: ``simulate``'s value when ``--effect`` does not give one (None: default)


@dataclass(frozen=True)
class Effect:
    """Descriptor of one effect (see the module docstring for how the rest of the package uses it)."""

    name: str
    term: Callable[..., Any]  #: ``term(x: EffectInputs, **{short: value})`` -> N·m
    physical: bool  #: a loss (published) or a sensor error (only in the residual)
    summary: str  #: what enabling it does (the ``enabled`` parameter's description)
    cause: str  #: typical physical cause (docs, report)
    parameters: tuple[EffectParameter, ...]
    coefficient: str  #: short name of the parameter the term is linear in (fitted, adapted online)
    member: str | None = None  #: short name of the nonlinear parameter ``calibrate`` profiles
    member_grid: tuple[float, ...] = ()
    member_bounds: tuple[float, float] = (0.0, 0.0)
    #: a second nonlinear parameter ``calibrate`` profiles jointly with ``member`` (Vogel C with B),
    #: on its own grid, with the coefficient held at ``profile_coefficient`` while both are profiled
    second_member: str | None = None
    second_grid: tuple[float, ...] = ()
    second_bounds: tuple[float, float] = (0.0, 0.0)
    profile_coefficient: float | None = None
    regressor_scale: Callable[[Mapping[str, float]], float] = lambda params: 1.0
    adaptive: bool = True  #: the coefficient is adapted online by RLS when output torque is measured
    needs_temperature: bool = False  #: testable only when the oil temperature varies (≥ 3 °C)
    #: applied as a factor on the model's Fr part (the estimator's viscosity path); the factor
    #: depends on the oil temperature alone (``calibrate`` evaluates it once per distinct temperature)
    scales_fr: bool = False
    #: its Vogel law (``B``, ``C``, ``theta_ref``) is the calibrated oil's: the set's
    #: viscosity_temperature, else the oil's data sheet; ``calibrate`` does not search it
    oil_law: bool = False
    #: its term depends on the torque: no candidate on a spin test (nothing on the output, the drive
    #: torque is the loss itself) nor where the load does not vary at a fixed speed
    depends_on_load: bool = False
    #: a loss law in the output-side load (``x.abs_load``): its exponent in the load -- the parameter
    #: named here, or 1.0 (a law linear in the load) -- gives :func:`.effectsum.output_load` its slope
    load_exponent: str | float | None = None
    #: testable only where the data reach this slow: a share of the samples (:data:`MIN_SLOW_SHARE`)
    #: at |ω| at most this [rad/s] (a law of speeds near standstill)
    needs_speeds_below: float | None = None
    #: testable only where the power flows back (``T·ω < 0``) in a share of the samples
    #: (:data:`~calibration.blocks.MIN_SLOW_SHARE`)
    needs_regeneration: bool = False
    #: testable only where the drive turns both ways (a share of the samples in each direction)
    needs_both_directions: bool = False
    #: the coefficient may take either sign (a difference between directions, not a loss of its own):
    #: no "negative friction" is refused; the loss in each direction must stay a loss instead
    signed: bool = False
    #: the other reading of the same part of the loss: these effects together (a sensor error and a
    #: load friction for a back-driving friction; a torque offset for a drag that differs by direction).
    #: ``calibrate`` names both when both explain it, takes the one with fewer terms (between equally
    #: many, the other reading's), and ``--assume`` chooses
    alternative_to: tuple[str, ...] = ()
    #: what tells this effect from its ``alternative_to`` reading
    alternative_needs: str = ""
    #: an effect with memory: ``state_step(z, ω, dt, params) -> z`` advances its state sample by sample,
    #: in time order (the node, replay's batches, a fleet's time slices, calibrate); its term reads
    #: ``x.state[name]``
    state_step: Callable[..., float] | None = None
    #: the same over a batch, ``state_steps(z0, ω, dt, params) -> z`` (arrays), bit for bit the single
    #: steps' states (replay's batches, calibrate's columns)
    state_steps: Callable[..., Any] | None = None
    #: a state that relaxes towards the direction of motion over the angle turned, exponentially over
    #: the parameter named here (``z → s + (z − s)·exp(−Δφ/param)``, :func:`dahl_step`): ``calibrate``
    #: then computes its columns in closed form from the angle turned since each reversal, only where
    #: the state has not settled (the term depends on that parameter only through the state)
    relaxes_over: str | None = None
    #: ``vanishes_above(params) -> speed``: beyond this |ω| the term is below e^-40 of its level (a
    #: law that fades with speed): ``calibrate`` evaluates its columns only on the slower samples
    vanishes_above: Callable[[Mapping[str, float]], float] | None = None
    separated_from: Mapping[str, str] = field(default_factory=dict)  #: other effect -> data that tells them apart
    #: a torque-sensor error: how it corrupts the drive torque reading ``T_meas = (1 + g)·T + b``;
    #: "offset" (its coefficient adds to ``b``) or "gain" (to ``g``).  The estimator and calibrate
    #: evaluate the model at the corrected torque (:func:`reading_errors`), simulate corrupts the
    #: reading with it
    reading_error: str | None = None
    #: the oil's viscosity law itself (Vogel ``B``, ``C`` at ``theta_ref``): what ``--oil`` and an
    #: oil's data sheet set (:func:`viscosity_law`); one effect of the registry carries it
    viscosity_law: bool = False
    #: the report draws its fitted curve over "speed", "torque", "load" (the output-side load), "temperature",
    #: "speed_near_zero"
    #: (signed speed, standstill magnified) or "angle_since_reversal" (an effect with memory: per sample)
    plotted_against: str = "speed"
    #: the member that makes the law a line (p = 1: viscous, linear in the load): the form ``calibrate`` takes
    #: unless a curved one (the member profiled) predicts held-out operating points better (None: no line)
    linear: float | None = None

    def parameter(self, short: str) -> EffectParameter:
        return next(p for p in self.parameters if p.short == short)

    def profiled_ranges(self) -> dict[str, tuple[float, float]]:
        """Short name -> search bounds of each nonlinear parameter ``calibrate`` profiles."""
        pairs = ((self.member, self.member_bounds), (self.second_member, self.second_bounds))
        return {short: bounds for short, bounds in pairs if short is not None}

    def defaults(self) -> dict[str, float]:
        """Short name -> value in the parameter file's defaults."""
        return {p.short: p.default for p in self.parameters}

    def simulated_defaults(self) -> dict[str, float]:
        return {p.short: p.default if p.simulated is None else p.simulated for p in self.parameters}

    def column(self, x: EffectInputs, params: Mapping[str, float], member: float | None = None,
               second: float | None = None):
        """The term with coefficient 1 (the regressor it is linear in), at ``member`` and ``second``
        if given."""
        values = dict(params)
        values[self.coefficient] = 1.0
        if member is not None and self.member is not None:
            values[self.member] = member
        if second is not None and self.second_member is not None:
            values[self.second_member] = second
        return self.term(x, **values)

    def formula(self) -> str:
        """First line of the term's docstring."""
        return (self.term.__doc__ or self.name).strip().splitlines()[0]


def reading_errors(enabled: Mapping[str, Mapping[str, float]]) -> tuple[float, float]:
    """``(b, g)`` of the drive torque reading ``T_meas = (1 + g)·T + b`` from the enabled sensor
    errors (``enabled``: name -> short parameters; :attr:`Effect.reading_error`)."""
    offset, gain = 0.0, 0.0
    for name, params in enabled.items():
        effect = EFFECTS[name]
        if effect.reading_error == "offset":
            offset += params[effect.coefficient]
        elif effect.reading_error == "gain":
            gain += params[effect.coefficient]
    return offset, gain


def viscosity_law() -> Effect:
    """The registry's effect that is the oil's viscosity law (:attr:`Effect.viscosity_law`)."""
    return next(e for e in EFFECTS.values() if e.viscosity_law)


def _grid(start: float, stop: float, step: float) -> tuple[float, ...]:
    n = int(round((stop - start) / step))
    return tuple(round(start + k * step, 3) for k in range(n + 1))


EFFECTS: dict[str, Effect] = {}
#: bumped by :func:`register`, so that tables built from the registry (parameter specs) are rebuilt
REGISTRY_VERSION = [0]


#: the Stribeck speed and shape of ``stribeck`` and ``stribeck_direction``, and how calibrate searches them
_STRIBECK_SHAPE = (
    EffectParameter("omega_s", "omega_s_rad_s", 0.1, "Stribeck speed", "rad/s", low=1e-4, low_open=True, high=1e3),
    EffectParameter("delta", "delta", 2.0, "Stribeck shape exponent (2: Gaussian)", low=0.1, high=5.0))
_STRIBECK_SEARCH = dict(
    coefficient="c", member="omega_s", member_grid=(0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0),
    member_bounds=(0.001, 20.0), second_member="delta", second_grid=(0.5, 1.0, 2.0), second_bounds=(0.3, 3.0),
    vanishes_above=lambda p: p["omega_s"] * 40.0 ** (1.0 / p["delta"]), needs_speeds_below=5.0,
    plotted_against="speed_near_zero")


def register(effect: Effect) -> Effect:
    """Add (or replace) an effect in the registry; returns it."""
    EFFECTS[effect.name] = effect
    REGISTRY_VERSION[0] += 1
    return effect


def unregister(name: str) -> None:
    """Remove an effect (tests that register a toy effect)."""
    EFFECTS.pop(name, None)
    REGISTRY_VERSION[0] += 1


for _effect in (
    Effect("drag_constant", drag_constant, True, "add a constant drag torque c",
           "seal friction, return-track friction, Coulomb drag",
           (EffectParameter("c", "c_nm", 0.0, "constant drag torque c", "N*m", simulated=0.05),),
           coefficient="c",
           separated_from={"torque_offset": "reverse rotation (or a standstill zero reading of the torque sensors)",
                           "drag_speed": "a wider speed range",
                           "load_dependent": "a wider torque range, including light load"}),
    Effect("drag_speed", drag_speed, True, "add a speed drag c*|w|^p", "oil churning, viscous drag, windage",
           (EffectParameter("c", "c", 0.0, "speed drag coefficient c (N*m/(rad/s)^p)", simulated=2e-4),
            EffectParameter("p", "p", 1.0, "speed drag exponent p", low=0.0, high=4.0, simulated=1.5)),
           coefficient="c", member="p", member_grid=_grid(0.5, 3.0, 0.1), member_bounds=(0.3, 3.5),
           regressor_scale=lambda params: SPEED_REF_RAD_S ** params["p"], linear=1.0,
           separated_from={"viscosity_temperature": "the same speeds at different oil temperatures"}),
    Effect("drag_viscous", drag_viscous, True, "add a churning drag that follows the oil: c*(eta/eta_ref)^a*|w|^p",
           "churning and splash losses of an oil whose viscosity changes with its temperature",
           (EffectParameter("c", "c", 0.0, "churning coefficient c at the reference viscosity (N*m/(rad/s)^p)",
                            simulated=3e-4),
            EffectParameter("p", "p", 1.5, "speed exponent p", low=0.0, high=4.0),
            EffectParameter("a", "a", 0.5, "viscosity exponent a", low=0.0, high=3.0),
            EffectParameter("B", "B_k", 0.0, "the oil's Vogel B (the calibrated law; 0: no law, the drag at "
                            "eta_ref)", "K", low=0.0, high=1e5, simulated=900.0),
            EffectParameter("C", "C_k", 95.0, "the oil's Vogel C", "K", low=-273.0, low_open=True, high=1e4),
            EffectParameter("theta_ref", "theta_ref_c", 40.0, "the law's reference temperature", "degC",
                            low=-100.0, high=400.0)),
           coefficient="c", member="p", member_grid=_grid(0.5, 3.0, 0.25), member_bounds=(0.3, 3.5),
           second_member="a", second_grid=_grid(0.25, 1.5, 0.25), second_bounds=(0.05, 2.5),
           regressor_scale=lambda params: SPEED_REF_RAD_S ** params["p"], needs_temperature=True, oil_law=True,
           separated_from={"drag_speed": "the same speeds at different oil temperatures",
                           "viscosity_temperature": "several speeds at light load (churning does not follow the "
                                                    "load; the rolling part does)"}),
    Effect("stribeck", stribeck, True, "add a Stribeck excess c*exp(-(|w|/omega_s)^delta) near standstill",
           "breakaway friction of lubricated contacts at low speed (boundary and mixed lubrication)",
           (EffectParameter("c", "c_nm", 0.0, "breakaway excess Fs - Fc", "N*m", simulated=0.05), *_STRIBECK_SHAPE),
           **_STRIBECK_SEARCH,
           separated_from={"drag_constant": "speeds near standstill (down to a few times the speed noise)",
                           "torque_offset": "speeds near standstill in both directions"}),
    Effect("dahl", dahl, True, "add a Coulomb friction with memory (Dahl): c*z*sign(w), the state z following "
           "the motion since the last reversal", "presliding of rolling contacts and seals: friction that lags a "
           "reversal",
           (EffectParameter("c", "c_nm", 0.0, "Coulomb level c", "N*m", simulated=0.1),
            EffectParameter("presliding", "presliding_rad", 0.01, "presliding angle: the turn over which the "
                            "friction follows a reversal (1/e)", "rad", low=1e-6, low_open=True, high=10.0)),
           coefficient="c", member="presliding",
           member_grid=(1e-4, 3e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1, 0.3), member_bounds=(3e-5, 1.0),
           state_step=dahl_step, state_steps=dahl_steps, relaxes_over="presliding",
           plotted_against="angle_since_reversal",
           separated_from={"drag_constant": "reversals: the torque's lag after each one (a constant drag flips at "
                                            "once)"}),
    Effect("drag_direction", drag_direction, True, "add a drag that differs by direction c*|w|^p*sign(w)",
           "friction that differs by direction: a worn or preloaded screw, a seal lip that points one way",
           (EffectParameter("c", "c", 0.0, "forward minus mean drag coefficient c (N*m/(rad/s)^p; negative: more "
                            "drag in reverse)", simulated=-1e-4),
            EffectParameter("p", "p", 1.0, "speed exponent p of the difference", low=0.0, high=4.0)),
           coefficient="c", member="p", member_grid=_grid(0.5, 3.0, 0.1), member_bounds=(0.3, 3.5),
           regressor_scale=lambda params: SPEED_REF_RAD_S ** params["p"], signed=True, needs_both_directions=True,
           alternative_to=("torque_offset",), linear=1.0,
           alternative_needs="a standstill zero reading of the torque sensor (the zero error flips the loss by the "
                             "same amount at every speed; a drag that differs by direction grows with speed)",
           separated_from={"drag_speed": "both directions of rotation"}),
    Effect("stribeck_direction", stribeck_direction, True,
           "add a Stribeck excess that differs by direction c*exp(-(|w|/omega_s)^delta)*sign(w)",
           "breakaway friction that differs by direction: a load lifted and lowered through a worm or a screw",
           (EffectParameter("c", "c_nm", 0.0, "forward minus mean breakaway excess c (negative: more in reverse)",
                            "N*m", simulated=-0.02), *_STRIBECK_SHAPE),
           **_STRIBECK_SEARCH, signed=True, needs_both_directions=True,
           separated_from={"torque_offset": "speeds near standstill and far from it, in both directions",
                           "stribeck": "speeds near standstill in both directions"}),
    Effect("backdrive", backdrive, True,
           "add a friction c*|T_load|^q that appears only while the output drives the input",
           "friction only under back-driving: a self-locking tendency, a one-way clutch, a worm's back-driving",
           (EffectParameter("c", "c", 0.0, "back-driving friction coefficient c (N*m/(N*m)^q)", simulated=3e-3),
            EffectParameter("q", "q", 1.0, "back-driving friction exponent q", low=0.0, high=4.0)),
           coefficient="c", member="q", member_grid=_grid(0.5, 2.5, 0.1), member_bounds=(0.3, 3.0),
           regressor_scale=lambda params: TORQUE_REF_NM ** params["q"], plotted_against="load", depends_on_load=True,
           load_exponent="q", needs_regeneration=True, alternative_to=("torque_gain", "load_dependent"), linear=1.0,
           alternative_needs="a calibration of the torque sensors (a known torque at standstill: a gain error shows "
                             "in it, a friction does not)",
           separated_from={"load_dependent": "motoring and regeneration at the same loads"}),
    Effect("load_dependent", load_dependent, True, "add a load friction c*|T_load|^q", "bearing load friction, sliding",
           (EffectParameter("c", "c", 0.0, "load friction coefficient c (N*m/(N*m)^q)", simulated=2e-3),
            EffectParameter("q", "q", 1.0, "load friction exponent q", low=0.0, high=4.0)),
           coefficient="c", member="q", member_grid=_grid(0.5, 2.5, 0.1), member_bounds=(0.3, 3.0),
           regressor_scale=lambda params: TORQUE_REF_NM ** params["q"], plotted_against="load", depends_on_load=True,
           load_exponent="q", linear=1.0,
           separated_from={"torque_gain": "regeneration (torque and speed of opposite sign)",
                           "viscosity_temperature": "the same torques at different oil temperatures"}),
    Effect("load_speed", load_speed, True, "add a load-speed friction c*|T_load|*|w|^p",
           "load- and speed-dependent sliding (gear mesh), a loss power proportional to the transmitted power",
           (EffectParameter("c", "c", 0.0, "load-speed coefficient c (N*m/(N*m*(rad/s)^p))", simulated=2e-5),
            EffectParameter("p", "p", 1.0, "load-speed exponent p of |w|", low=0.0, high=4.0)),
           coefficient="c", member="p", member_grid=_grid(0.5, 2.0, 0.1), member_bounds=(0.3, 2.5),
           regressor_scale=lambda params: TORQUE_REF_NM * SPEED_REF_RAD_S ** params["p"], depends_on_load=True,
           load_exponent=1.0, plotted_against="load", linear=1.0,
           separated_from={"load_dependent": "the same torques at several speeds",
                           "drag_speed": "the same speeds at several torques, including light load",
                           "torque_gain": "regeneration (torque and speed of opposite sign)"}),
    Effect("viscosity_temperature", viscosity_temperature, True,
           "evaluate the model at the Vogel viscosity eta(theta) instead of eta0", "oil warming / cooling",
           (EffectParameter("B", "B_k", 0.0, "Vogel B: eta = eta0*exp(B/(theta+C) - B/(theta_ref+C))", "K",
                            low=0.0, high=1e5, simulated=900.0),
            EffectParameter("C", "C_k", 95.0, "Vogel C", "K", low=-273.0, low_open=True, high=1e4),
            EffectParameter("theta_ref", "theta_ref_c", 40.0, "oil temperature at which the viscosity is eta0",
                            "degC", low=-100.0, high=400.0),
            EffectParameter("scale", "scale", 1.0, "scale of the viscosity correction: "
                            "Fr·(1 + scale·((eta/eta0)^0.66 − 1)); 1 = the model at eta(theta)", low=0.0, high=10.0)),
           coefficient="scale", member="B", member_grid=_grid(100.0, 4000.0, 100.0), member_bounds=(1.0, 6000.0),
           second_member="C", second_grid=_grid(50.0, 250.0, 25.0), second_bounds=(20.0, 400.0),
           profile_coefficient=1.0, adaptive=False, needs_temperature=True, scales_fr=True, viscosity_law=True,
           plotted_against="temperature"),
    Effect("torque_offset", torque_offset, False,
           "input torque sensor zero error (adds offset*sign(w) to the input-referred loss)", "sensor zero error",
           (EffectParameter("b", "offset_nm", 0.0, "input-referred torque offset", "N*m", simulated=0.05),),
           coefficient="b", separated_from={"torque_gain": "a wider torque range in both directions"},
           reading_error="offset", plotted_against="torque"),
    Effect("torque_gain", torque_gain, False,
           "torque sensor gain error (adds gain*T*sign(w) to the input-referred loss)", "sensor calibration",
           (EffectParameter("g", "gain", 0.0, "relative gain error", low=-0.5, high=0.5, simulated=0.01),),
           coefficient="g", regressor_scale=lambda params: TORQUE_REF_NM, plotted_against="torque",
           depends_on_load=True, reading_error="gain"),
):
    register(_effect)


def separating_data(a: str, b: str) -> str | None:
    """The data that tells effects ``a`` and ``b`` apart, from either one's descriptor."""
    return EFFECTS[a].separated_from.get(b) or EFFECTS[b].separated_from.get(a)


def takes_load(effect: Effect) -> bool:
    """Whether ``effect`` is a loss law in the output-side load (:attr:`Effect.load_exponent`)."""
    return effect.physical and effect.load_exponent is not None


def with_temperature(x: EffectInputs, params: Mapping[str, float]) -> EffectInputs:
    """``x`` with a missing oil temperature (NaN) at the effect's reference temperature (``theta_ref``):
    an effect that follows the oil is then at its reference viscosity, as the model's Fr part is."""
    theta = x.temperature_c
    ref = params.get("theta_ref", 40.0)
    if isinstance(theta, float):
        return x if theta == theta else x._replace(temperature_c=ref)
    import numpy as np

    return x._replace(temperature_c=np.where(np.isnan(theta), ref, theta))


#: how the report's ``effect_<name>.png`` draws an effect (:attr:`Effect.plotted_against`)
_DRAWN_OVER = {"speed": "drive speed", "torque": "drive torque", "temperature": "oil temperature",
               "load": "output-side load referred to the input",
               "speed_near_zero": "signed drive speed, standstill magnified (symmetric log axis)",
               "angle_since_reversal": "the angle turned since the last reversal, per sample"}


def markdown_table() -> str:
    """``docs/effects.md``: the registry as a table (regenerate with ``python -m rollergear_ros.core.effects``)."""
    lines = ["# Effects the model lacks (the registry)\n",
             "Generated from `rollergear_ros/core/effects.py` by "
             "`python -m rollergear_ros.core.effects > docs/effects.md`; "
             "a test keeps it current. Parameters: short name (in `calibrate --json` and `simulate --effect`) → "
             "key under `effects.<effect>.` in the parameter file.\n",
             "| effect | term | kind | parameters | fitted | cause | told apart from | the report draws it over |",
             "|---|---|---|---|---|---|---|---|"]
    for e in EFFECTS.values():
        params = ", ".join(f"`{p.short}` → `{p.key}`" + (f" [{p.unit}]" if p.unit else "") for p in e.parameters)
        fitted = f"`{e.coefficient}` (linear" + (", adapted online)" if e.adaptive else ")")
        if e.member:
            fitted += f", `{e.member}` on {e.member_grid[0]:g}…{e.member_grid[-1]:g}"
        if e.second_member and e.profile_coefficient is not None:
            fitted += (f" with `{e.second_member}` on {e.second_grid[0]:g}…{e.second_grid[-1]:g}, both at "
                       f"`{e.coefficient}` = {e.profile_coefficient:g}, then `{e.coefficient}` freely as a check")
        elif e.second_member:
            fitted += f" with `{e.second_member}` on {e.second_grid[0]:g}…{e.second_grid[-1]:g}"
        if e.oil_law:
            fitted += "; its Vogel law is the calibrated oil's (viscosity_temperature's, else `--oil`'s)"
        kind = "loss" if e.physical else "sensor error"
        if e.needs_temperature:
            kind += "; needs a varying oil temperature"
        if e.needs_speeds_below is not None:
            kind += f"; needs samples at \\|ω\\| ≤ {e.needs_speeds_below:g} rad/s"
        if e.state_step is not None:
            kind += "; has memory (a state stepped in time order)"
        apart = "; ".join(f"{o}: {d}" for o, d in e.separated_from.items()) or "—"
        formula = e.formula().replace("``", "`").replace("|", "\\|")
        drawn = _DRAWN_OVER[e.plotted_against] + (", coloured by the oil temperature"
                                                  if e.needs_temperature and e.plotted_against != "temperature" else "")
        lines.append(f"| `{e.name}` | {formula} | {kind} | {params} | {fitted} | {e.cause} | {apart} | {drawn} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_table(), end="")
