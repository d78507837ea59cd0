"""Fitting the candidate unmodelled effects on the training run (scipy least squares, few parameters each).

Every candidate is fitted on top of a *base* model (the nominal one, or the nominal one with effects already
accepted) and returns its parameters, their standard errors from the Jacobian (inflated by the residual's
correlation, see :func:`.fit_common._stderr`) and the effect list to add to the base.

Displacement-side effects (gain, creep, drift, mode) act on the base model's output, so they are fitted by (mostly
linear) regression on that output: cheap, and run on the whole training run.  Voltage-side and hysteresis effects
need the model re-run for every trial value; they are fitted on :class:`~.replay.Windows` of the training run
(the whole run when it is short), with a coarse grid followed by a bounded refinement (1 parameter) or
``scipy.optimize.least_squares`` (several).

The fits live by family: :mod:`.fit_common` (context, result, standard errors, the one-parameter fit),
:mod:`.fit_output` (displacement side), :mod:`.fit_modes` (resonances), :mod:`.fit_voltage` (voltage side) and
:mod:`.fit_hysteresis`; this module is the registry the engine fits from.
"""
from __future__ import annotations

from typing import Callable

from .fit_common import MAX_REGRESSION_ROWS, FitContext, FitResult, n_eff_ratio
from .fit_hysteresis import PLAY_FRACTIONS, RELAX_MIN_GAIN, fit_hysteresis_asymmetry, fit_hysteresis_rate_dependence
from .fit_modes import (MAX_MODES, MODE_FMIN, MODE_MIN_GAIN, MODE_ZMAX, Mode, fit_amplitude_dependent_dynamics,
                        fit_unmodelled_mode)
from .fit_output import fit_creep_nonlinearity, fit_gain_mismatch, fit_thermal_drift
from .fit_saturation import fit_amplifier_saturation_any
from .fit_slew import fit_amplifier_slew_limit_any
from .fit_slew import fit_amplifier_slew_limit_any as fit_amplifier_slew_limit   # the name before the split
from .fit_voltage import (RAIL_MIN_GAIN, fit_amplifier_bandwidth, fit_amplifier_saturation,
                          fit_input_delay)

__all__ = ["FitContext", "FitResult", "fit_candidate", "CANDIDATES", "n_eff_ratio",
           # re-exported from the family modules (their home), importable from here as before the split
           "fit_hysteresis_asymmetry", "fit_hysteresis_rate_dependence", "fit_creep_nonlinearity", "fit_thermal_drift",
           "fit_input_delay", "fit_amplifier_slew_limit", "fit_amplifier_saturation", "fit_amplifier_bandwidth",
           "fit_unmodelled_mode", "fit_amplitude_dependent_dynamics", "fit_gain_mismatch", "MAX_REGRESSION_ROWS",
           "PLAY_FRACTIONS", "RELAX_MIN_GAIN", "MAX_MODES", "MODE_FMIN", "MODE_MIN_GAIN", "MODE_ZMAX", "Mode",
           "RAIL_MIN_GAIN"]


CANDIDATES: dict[str, Callable[[FitContext], FitResult]] = {
    "hysteresis_asymmetry": fit_hysteresis_asymmetry,
    "hysteresis_rate_dependence": fit_hysteresis_rate_dependence,
    "creep_nonlinearity": fit_creep_nonlinearity,
    "thermal_drift": fit_thermal_drift,
    "input_delay": fit_input_delay,
    "amplifier_slew_limit": fit_amplifier_slew_limit_any,   # one rate, or a rate per direction
    "amplifier_saturation": fit_amplifier_saturation_any,   # hard clip, or a soft knee per rail
    "amplifier_bandwidth": fit_amplifier_bandwidth,
    "unmodelled_mode": fit_unmodelled_mode,
    "amplitude_dependent_dynamics": fit_amplitude_dependent_dynamics,
    "gain_mismatch": fit_gain_mismatch,
}


def fit_candidate(name: str, ctx: FitContext) -> FitResult:
    """Fit one candidate (a name from :data:`CANDIDATES`) on the training data of ``ctx``."""
    if name not in CANDIDATES:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(CANDIDATES)}")
    return CANDIDATES[name](ctx)
