"""Unmodelled effects as streaming stages: the vocabulary of the sim-to-real gap diagnosis.

Each effect is a physically meaningful extension of the nominal chain with few parameters.  It is either a stage
inserted before the chain on the voltage (``pre``: amplifier and timing effects), after it on the displacement
(``post``: sensor/structure/thermal effects), or a replacement of the hysteresis part (generalized or rate-dependent
Bouc-Wen).  Every stage has ``process(block[N, axes]) -> block`` and ``reset()``, carries its state between blocks
and gives bit-identical output whatever the block split.

:func:`build_plant` assembles ``Plant(cfg, pre=[...], post=[...])`` from a list of ``(name, params)``; the
per-effect parameter names, units and positions are in :data:`EFFECTS`.

Units are SI: volts, metres, seconds, hertz.

Layout: :mod:`.registry` (:data:`EFFECTS`, :class:`EffectSpec`, :func:`build_plant`), :mod:`.voltage` (amplifier
and timing stages), :mod:`.displacement` (gain, thermal drift, nonlinear creep), :mod:`.modes` (structural
resonances, fixed or level-dependent), :mod:`.hysteresis` (the generalized/rate-dependent Bouc-Wen and the loop-shape
terms), :mod:`.common` (reference scales, block checks).  Every name of the former single module is importable from
here, as before.
"""
from __future__ import annotations

from .common import CREEP_TAUS, CREEP_YREF, RATE_REF
from .common import DIRECTION_TAU as DIRECTION_TAU
from .common import LEVEL_REF as LEVEL_REF
from .common import LEVEL_TAU as LEVEL_TAU
from .common import RATE_SMOOTHING as RATE_SMOOTHING
from .common import _block as _block
from .common import _per_axis as _per_axis
from .displacement import CreepNonlinearity, GainMismatch, ThermalDrift
from .displacement import _lp_bank_run as _lp_bank_run
from .hysteresis import BranchEvenTerm, HysteresisStage, PlayWidthTerm, RelaxedHysteresisStage, VelocityTerm, LoopShapeTerm, RatePlayTerm, RelayPlaneTerm
from .hysteresis import _lp1_run as _lp1_run
from .hysteresis import _play_run as _play_run
from .hysteresis import _relax2_run as _relax2_run
from .hysteresis import asymmetric_hysteresis_config as asymmetric_hysteresis_config
from .modes import AmplitudeDependentDynamics, CubicAmplitudeDynamics, UnmodelledMode
from .modes import BaseExcitedNonlinearMode as BaseExcitedNonlinearMode
from .modes import _bandpass_coeffs as _bandpass_coeffs
from .modes import _biquad_run as _biquad_run
from .modes import _highpass_coeffs as _highpass_coeffs
from .modes import _level_run as _level_run
from .modes import _mode_gains as _mode_gains
from .modes import _modes_spec as _modes_spec
from .registry import EFFECT_NAMES, EFFECTS, EffectSpec, build_plant
from .registry import _stage as _stage
from .voltage import AmplifierBandwidth, AmplifierSaturation, AmplifierSlewLimit, AsymmetricSaturation, InputDelay
from .voltage import _ap2_run as _ap2_run
from .voltage import _frac_delay_run as _frac_delay_run
from .voltage import _pole_matched as _pole_matched

__all__ = [
    "InputDelay", "AmplifierSlewLimit", "AmplifierSaturation", "AmplifierBandwidth", "GainMismatch",
    "ThermalDrift", "CreepNonlinearity", "UnmodelledMode", "AmplitudeDependentDynamics", "BranchEvenTerm",
    "HysteresisStage", "EffectSpec", "EFFECTS", "AsymmetricSaturation", "RelaxedHysteresisStage", "PlayWidthTerm",
    "CubicAmplitudeDynamics", "VelocityTerm", "LoopShapeTerm", "RatePlayTerm", "RelayPlaneTerm",
    "EFFECT_NAMES", "build_plant", "RATE_REF", "CREEP_TAUS", "CREEP_YREF",
]
