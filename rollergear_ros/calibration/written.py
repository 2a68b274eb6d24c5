"""The parameter file ``calibrate`` writes: the file given with exactly the accepted effects and the
fitted model parameters, its header, and why a calibration is not written.

The coefficients are held as calibrated (``estimator.adapt: false``): the claims are of exactly
this file.  No rclpy import.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from ..core.effects import EFFECTS
from ..core.lagalign import LAG_CHANNELS
from ..core.modelform import ModelForm
from ..core.modelparams import MODEL_PARAMETERS
from ..core.params import Config, config_to_yaml, validate
from .outcome import CalibrationResult, FoundEffect, FoundParameter
from .selection import ErrorStats

__all__ = ["calibrated_config", "calibrated_yaml", "changed", "describing", "not_written_because"]


def describing(config: Config, stretch: str) -> Config:
    """``config`` saying in its model form which stretch of the recordings it describes."""
    form = ModelForm.from_text(config.calibration.model_form)
    if form is None:
        return config
    return config.with_values({"calibration.model_form": replace(form, segment=stretch).to_text()})


def changed(config: Config, new: Config) -> bool:
    """Whether the calibrated file differs from the one given in an effect, a model parameter or a
    channel lag calibrate fits (not in what it only states: a table's ratio, the recordings' speed noise)."""
    a, b = config.to_flat(), new.to_flat()
    keys = [k for k in a if k.startswith("effects.")] + [p.key for p in MODEL_PARAMETERS.values()] \
        + [f"estimator.{c}_lag_s" for c in LAG_CHANNELS]
    return any(a[k] != b[k] for k in keys)


def not_written_because(error_before: ErrorStats, error_after: ErrorStats, anything_changed: bool) -> str | None:
    """Why a calibration is not written (None: it is): when it changes anything, it would predict the
    held-out data no better than the parameter file calibrated (nothing changed: the file as it was)."""
    if anything_changed and error_after.rmse_nm >= error_before.rmse_nm:
        return (f"not written: the calibrated parameters would predict the held-out data no better than the "
                f"parameter file as given (RMSE {error_after.rmse_nm:.4g} >= {error_before.rmse_nm:.4g} N·m)")
    return None


def calibrated_config(config: Config, effects: list[FoundEffect], parameters: list[FoundParameter],
                      kept: Sequence[str] = ()) -> Config:
    """``config`` with exactly the accepted effects enabled, at their fitted parameters (and the file's
    ``kept`` ones as they are: this data could not test them), the model's parameters calibrate
    changed, and its coefficients held (``estimator.adapt: false``)."""
    flat = {k: v for k, v in config.to_flat().items()}
    for name in EFFECTS:
        if name not in kept:
            flat[f"effects.{name}.enabled"] = False
    for e in effects:
        flat[f"effects.{e.name}.enabled"] = True
        for q in EFFECTS[e.name].parameters:
            flat[f"effects.{e.name}.{q.key}"] = e.params[q.short]
    for p in parameters:
        flat[p.name] = p.fitted
    # the coefficients as calibrated, held: what the claims are of (online adaptation follows each
    # sample's noise); a node that should track them sets estimator.adapt: true
    flat["estimator.adapt"] = False
    return validate(flat)


def calibrated_yaml(result: CalibrationResult, sources: Sequence[str]) -> str:
    """The calibrated file's text: a header (its sources, verdict, held-out errors, the model parameters
    it changed and the notes) and the parameter set."""
    header = (
        "# Written by `rollergear calibrate` from " + ", ".join(map(str, sources)) + "\n"
        f"# verdict: {result.verdict}; held-out RMSE {result.error_before.rmse_nm:.4g} -> "
        f"{result.error_after.rmse_nm:.4g} N·m\n"
        + "".join(f"# {p.name}: {p.fitted:.6g} (was {p.file:.6g}), calibrated: {MODEL_PARAMETERS[p.name].label}\n"
                  for p in result.parameters)
        + "".join(f"# {n}\n" for n in result.notes)
    )
    return config_to_yaml(result.config, header)
