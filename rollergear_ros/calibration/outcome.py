"""What ``calibrate`` found: accepted effects and model parameters, the decisions on every candidate,
the rig's nuisances, the errors before and after; :meth:`CalibrationResult.to_json` is the
``calibrate --json`` object of ``interface.md`` (plus documented extra keys).  No rclpy import."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .blocks import Blocks
from .forward import Decision
from .noise import MinimumEffect
from .nuisance import ChannelLag
from .selection import AmbiguousSet, ErrorStats, RejectedEffect
from .structure import Adequacy
from ..core.effects import EFFECTS
from ..core.modelparams import MODEL_PARAMETERS
from ..core.params import Config

__all__ = ["CalibrationResult", "Change", "FoundEffect", "FoundParameter"]


@dataclass(frozen=True)
class FoundEffect:
    """An accepted effect: its parameters (short names of the registry) with 95 % intervals."""

    name: str
    params: dict[str, float]
    ci95: dict[str, list[float]]  #: the coefficient's (covering the member's range) and the member's
    rms_contribution_nm: float
    rms_contribution_ci95_nm: list[float]
    at_bound: list[str] = field(default_factory=list)  #: members (p, q, B, C) at a bound of their range

    def to_json(self) -> dict:
        return {"name": self.name, "params": self.params, "ci95": self.ci95,
                "rms_contribution_nm": self.rms_contribution_nm,
                "rms_contribution_ci95_nm": self.rms_contribution_ci95_nm, "at_bound": self.at_bound}

    def bound_note(self) -> str | None:
        """A sentence when a member sits at a bound of its physical range (the data want a law the
        vocabulary lacks: the fit is the closest within it), else None."""
        if not self.at_bound:
            return None
        ranges = EFFECTS[self.name].profiled_ranges()
        said = ", ".join(f"{m} = {self.params[m]:.4g} at the bound of its range [{ranges[m][0]:g}, {ranges[m][1]:g}]"
                         for m in self.at_bound)
        return f"{self.name}: {said} -- the data want a law outside the vocabulary; this is the closest within it"


@dataclass(frozen=True)
class FoundParameter:
    """A parameter of the paper's model that calibrate changed (:mod:`core.modelparams`)."""

    name: str  #: its parameter-file key (``gearbox.eta0_pa_s``)
    file: float  #: the value in the parameter file calibrated
    fitted: float
    ci95: list[float]
    rms_contribution_nm: float  #: RMS of the change it makes to the model's loss
    same_part: list[str] = field(default_factory=list)  #: parameters of the same part, not told apart

    def to_json(self) -> dict:
        return {"name": self.name, "file": self.file, "fitted": self.fitted, "ci95": self.ci95,
                "label": MODEL_PARAMETERS[self.name].label, "unit": MODEL_PARAMETERS[self.name].unit,
                "rms_contribution_nm": self.rms_contribution_nm, "not_told_apart_from": self.same_part}

    def sentence(self) -> str:
        """``oil viscosity at the reference temperature: 0.13 Pa·s (file 0.1; 95 % 0.127–0.133)``."""
        p = MODEL_PARAMETERS[self.name]
        unit = f" {p.unit}" if p.unit else ""
        text = (f"{p.label} ({self.name}): {self.fitted:.4g}{unit} (file {self.file:.4g}; 95 % "
                f"{self.ci95[0]:.4g}–{self.ci95[1]:.4g})")
        if self.same_part:
            text += f"; {', '.join(self.same_part)} scales the same part: not told apart, left at the file's value"
        return text


@dataclass(frozen=True)
class Change:
    """A change of the gearbox inside the recordings (:mod:`.segments`): when, and by how much."""

    t_ns: int  #: the change point (the log time of the first sample after it)
    t_s: float  #: seconds after the first sample analysed (the recordings one after another)
    ci95_s: tuple[float, float]  #: where the split fits within the threshold of the best
    rms_change_nm: float  #: RMS over the samples of the difference between the two sides' fits
    heldout_one_nm: float  #: held-out RMSE of one fit across it
    heldout_two_nm: float  #: ... and of a fit on each side
    recording: int = 0  #: the recording it is in (the order given)
    temperature_c: float = math.nan  #: the oil temperature at the change (NaN: none recorded)
    between_recordings: bool = False  #: at the start of recording ``recording``

    def when(self) -> str:
        """``50.2 s (95 %: 49.8–50.5 s)``, or ``the start of recording 2``."""
        if self.between_recordings:
            return f"the start of recording {self.recording + 1} ({self.t_s:.1f} s, the recordings one after another)"
        return f"{self.t_s:.1f} s (95 %: {self.ci95_s[0]:.1f}–{self.ci95_s[1]:.1f} s)"

    def to_json(self) -> dict:
        return {"t_ns": self.t_ns, "t_s": self.t_s, "ci95_s": list(self.ci95_s), "recording": self.recording,
                "between_recordings": self.between_recordings,
                "temperature_c": self.temperature_c if math.isfinite(self.temperature_c) else None,
                "rms_change_nm": self.rms_change_nm, "heldout_one_fit_nm": self.heldout_one_nm,
                "heldout_two_fits_nm": self.heldout_two_nm}


@dataclass
class CalibrationResult:
    """What ``calibrate`` found; :meth:`to_json` is the ``calibrate --json`` object."""

    verdict: str  #: effects_found | no_missing_effect | inconclusive
    effects: list[FoundEffect]
    error_before: ErrorStats  #: held-out, the parameter file as given
    error_after: ErrorStats  #: held-out, what the result writes
    holdout: str  #: how the held-out data was chosen
    samples: int
    delta_nm: float  #: the practical minimum effect size
    rejected: list[RejectedEffect]
    ambiguous: list[AmbiguousSet]
    unavailable: list[str]
    log: list[str]
    sample_level: dict[str, ErrorStats]  #: before/after per sample (sensor noise included)
    config: Config  #: the input parameters with the accepted effects
    adequacy: Adequacy | None = None
    blocks: Blocks | None = None
    pred_after: np.ndarray | None = None
    parameters: list[FoundParameter] = field(default_factory=list)
    written: bool = True  #: ``config`` is what --out writes (False: it would predict worse than the file)
    notes: list[str] = field(default_factory=list)  #: what was decided and why (paper model off, not written)
    negative: list[str] = field(default_factory=list)  #: candidates whose fit needed a negative friction
    structure: dict | None = None  #: the unexplained residual against each input (:mod:`.structure`)
    before_residual: np.ndarray | None = None  #: per sample, the file as given (the "before" errors)
    after_residual: np.ndarray | None = None  #: per sample, after the accepted terms (held out, per block)
    decisions: list[Decision] = field(default_factory=list)  #: every candidate's, with its reasons
    minimum: MinimumEffect | None = None  #: δ and where it came from
    lags: list[ChannelLag] = field(default_factory=list)  #: each channel's lag behind the drive torque
    inertia: dict | None = None  #: the drive's inertia seen in the measured loss (J, its interval)
    speed_noise: str = ""  #: the speed reading's noise used, and where it came from
    from_file: list[str] = field(default_factory=list)  #: the parameter file's accepted effects (the start)
    changes: list[Change] = field(default_factory=list)  #: changes found inside the recordings
    stretch: str = ""  #: which samples were fitted (all; the latest stretch after a change; a window)
    untestable: dict[str, str] = field(default_factory=dict)  #: candidate -> why the data cannot test it
    segments: list[dict] = field(default_factory=list)  #: each stretch's own result (``--segments``)
    #: the least-squares line weighed against the selection (:mod:`.handfit`): its error, whether it was written
    hand_fit: dict | None = None
    #: the held-out error of what the file writes at each operating point (:mod:`.grouping`), the worst first
    groups: list[dict] = field(default_factory=list)
    drift: object | None = None  #: a loss that moved one way in time (:class:`~.drift.Drift`), not steps
    #: the analysis's fits and its final terms (what the search for changes fits on each side)
    calibrator: object | None = field(default=None, repr=False)
    terms: list = field(default_factory=list, repr=False)

    def to_json(self) -> dict:
        """The ``interface.md`` object (plus extra keys: delta, decisions, nuisances, ...)."""
        return {
            "verdict": self.verdict,
            "effects": [e.to_json() for e in self.effects],
            "parameters": [p.to_json() for p in self.parameters],
            "error_before": self.error_before.to_json(),
            "error_after": self.error_after.to_json(),
            "holdout": self.holdout,
            "samples": self.samples,
            "delta_nm": self.delta_nm,
            "delta": self.minimum.to_json() if self.minimum else None,
            "decisions": [d.to_json() for d in self.decisions],
            "rejected": [r.to_json() for r in self.rejected],
            "ambiguous": [a.to_json() for a in self.ambiguous],
            "unavailable": self.unavailable,
            "untestable": self.untestable,
            "nuisances": {"lags": [lag.to_json() for lag in self.lags], "inertia": self.inertia,
                          "speed_noise": self.speed_noise},
            "from_file": self.from_file,
            "changes": [c.to_json() for c in self.changes],
            "drift": _json_safe(self.drift.to_json()) if self.drift is not None else None,
            "stretch": self.stretch,
            "segments": self.segments,
            "hand_fit": _json_safe(self.hand_fit),
            "heldout_by_operating_point": _json_safe(self.groups),
            "sample_level_errors": {k: v.to_json() for k, v in self.sample_level.items()},
            "adequacy": self.adequacy.to_json() if self.adequacy else None,
            "written": self.written,
            "notes": self.notes,
            "residual_structure": _json_safe(self.structure),
        }


def _json_safe(value):
    """NaN and infinities as null (JSON has neither)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def segment_summary(result: CalibrationResult, start_s: float, end_s: float) -> dict:
    """One stretch's result in a few keys (``calibrate --segments``)."""
    return {"start_s": start_s, "end_s": end_s, "samples": result.samples, "verdict": result.verdict,
            "effects": [e.to_json() for e in result.effects], "parameters": [p.to_json() for p in result.parameters],
            "error_before": result.error_before.to_json(), "error_after": result.error_after.to_json()}
