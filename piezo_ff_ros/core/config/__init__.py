"""One frozen, validated configuration object per stage, built from YAML (``config/``) or a plain dict.

Every ``validate()`` raises :class:`ConfigError` whose message starts with the dotted name of the offending field
(``hysteresis.Dp: singular matrix …``) so that a rejected runtime change says exactly why.

Units: the YAML may give lengths in µm (``units: {length: um}``, as the paper prints them); everything is converted
to SI here and nowhere else.  Only the Bouc-Wen ``Dp`` and ``A`` carry a length per volt; ``B``, ``Gamma``, the
creep and the dynamics are ratios and do not scale.

Layout: :mod:`.validation` (:class:`ConfigError`, the shared value checks and plausibility bounds),
:mod:`.tf_entries` (transfer-function matrix entries ↔ YAML), :mod:`.stages` (the per-stage configs),
:mod:`.piezo` (:class:`PiezoConfig`, its YAML form, units and variants), :mod:`.loader` (:func:`load_config`, the
default file, duplicate-key refusal, :func:`flatten` / :func:`unflatten`).  Every public name of the former single
module is importable from here, as before.
"""
from __future__ import annotations

from .loader import DuplicateKeyError as DuplicateKeyError
from .loader import UniqueKeyLoader as UniqueKeyLoader
from .loader import default_config_path, flatten, load_config, unflatten
from .piezo import PiezoConfig
from .stages import BoucWenConfig, CascadeConfig, CreepConfig, DynamicsConfig, HinfConfig, LimitsConfig
from .validation import MAX_GAIN_M_PER_V as MAX_GAIN_M_PER_V
from .validation import MAX_HYSTERESIS_RATE as MAX_HYSTERESIS_RATE
from .validation import MAX_LIMIT_SLEW as MAX_LIMIT_SLEW
from .validation import MAX_LIMIT_VOLTAGE as MAX_LIMIT_VOLTAGE
from .validation import MAX_SAMPLE_RATE as MAX_SAMPLE_RATE
from .validation import MAX_STALE_TIMEOUT as MAX_STALE_TIMEOUT
from .validation import MIN_SAMPLE_RATE as MIN_SAMPLE_RATE
from .validation import VOLTAGE_UNITS as VOLTAGE_UNITS
from .validation import ConfigError
from .validation import Matrix as Matrix
from .validation import dataclass_from_mapping as dataclass_from_mapping

__all__ = [
    "ConfigError",
    "BoucWenConfig",
    "CreepConfig",
    "DynamicsConfig",
    "HinfConfig",
    "CascadeConfig",
    "LimitsConfig",
    "PiezoConfig",
    "load_config",
    "default_config_path",
    "flatten",
    "unflatten",
]
