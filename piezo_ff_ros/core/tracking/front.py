"""The tracking stages in front of the cascade, as the compensator node runs them: preview, then a learned
correction.  Runtime parameters (flat names, like every stage's):

- ``preview.enabled`` (bool, default false), ``preview.horizon_s``, ``preview.tail_s``, ``preview.bandwidth_hz``,
  ``preview.constrained`` — see :class:`~.preview.PreviewConfig`.  The reference must then arrive
  :attr:`TrackingFront.preview_s` ahead (the trajectory node's ``preview_s``).
- ``learning.file`` (str, default ""): a correction stored by :func:`~.ilc.save_correction` for the trajectory
  being played, added sample by sample from the stream start (the ``~/reset`` before each run).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..config import ConfigError, PiezoConfig
from .ilc import LearnedCorrection, load_correction
from .linear import ControllerABCD
from .preview import PreviewConfig, PreviewStage

__all__ = ["FRONT_DEFAULTS", "is_front_param", "front_settings", "TrackingFront"]

_P = PreviewConfig()
FRONT_DEFAULTS: dict[str, Any] = {
    "preview.enabled": False, "preview.horizon_s": _P.horizon_s, "preview.tail_s": _P.tail_s,
    "preview.bandwidth_hz": _P.bandwidth_hz, "preview.constrained": _P.constrained, "learning.file": "",
}


def is_front_param(name: str) -> bool:
    """True for the parameter names the tracking front owns (see ``FRONT_DEFAULTS``)."""
    return name in FRONT_DEFAULTS


def front_settings(values: Mapping[str, Any]) -> tuple[PreviewConfig | None, str]:
    """``(PreviewConfig or None when disabled, learning file)`` from the flat parameters; ConfigError naming the
    parameter otherwise."""
    v = {**FRONT_DEFAULTS, **values}
    if not isinstance(v["preview.enabled"], bool):
        raise ConfigError("preview.enabled", f"must be true or false, got {v['preview.enabled']!r}")
    if not isinstance(v["learning.file"], str):
        raise ConfigError("learning.file", f"must be a file path (string), got {v['learning.file']!r}")
    cfg = PreviewConfig.from_dict({k.split(".", 1)[1]: v[k] for k in FRONT_DEFAULTS
                                   if k.startswith("preview.") and k != "preview.enabled"})
    return (cfg if v["preview.enabled"] else None), v["learning.file"]


class TrackingFront:
    """Streaming ``reference → preview (optional) → + learned correction (optional)``; identity when both off."""

    def __init__(self, cfg: PiezoConfig, controller: ControllerABCD | None, values: Mapping[str, Any]) -> None:
        self.settings, self.learning_file = front_settings(values)
        self.preview = PreviewStage(cfg, controller, self.settings) if self.settings is not None else None
        self.learned = None
        if self.learning_file:
            corr, _ = load_correction(self.learning_file, cfg.sample_rate)
            if corr.shape[1] != cfg.n_axes:
                raise ConfigError("learning.file", f"{self.learning_file}: {corr.shape[1]} axes, expected {cfg.n_axes}")
            self.learned = LearnedCorrection(corr)
        self.fs = cfg.sample_rate

    @property
    def active(self) -> bool:
        """True when preview or learned correction is on (else the front is the identity)."""
        return self.preview is not None or self.learned is not None

    @property
    def preview_s(self) -> float:
        """How far ahead the reference must arrive [s] (0 without preview)."""
        return 0.0 if self.preview is None else self.preview.preview_samples / self.fs

    def reset(self) -> None:
        """Reset both stages (a new stream starts)."""
        for st in (self.preview, self.learned):
            if st is not None:
                st.reset()

    def continue_from(self, other: "TrackingFront") -> None:
        """Take over ``other``'s position in the learned correction (a rebuild for a new cascade: the correction
        belongs to the trajectory's sample index, not to the cascade)."""
        if self.learned is not None and other.learned is not None:
            self.learned.k = other.learned.k

    def process(self, block: np.ndarray) -> np.ndarray:
        """Reference block ``[N, axes]`` [m] through the preview, then plus the learned correction."""
        x = block
        if self.preview is not None:
            x = self.preview.process(x)
        if self.learned is not None:
            x = self.learned.process(x)
        return x
