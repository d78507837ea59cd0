"""The nominal plant S0 (the paper's chain): ``Y = G_L(s)·[K + Cr(s)]·(Dp·U − h)``, h the Bouc-Wen state.

Discretised at the config's sample rate as the model's definition says: explicit discrete Bouc-Wen, every SISO
transfer function by zero-order hold on its own, blocks in cascade.  ``effects`` (from :mod:`.effects`) can be
inserted before (on the voltage) or after (on the displacement) the nominal chain, and sensor noise added, to build
"truth" plants that differ from the nominal model.
"""
from __future__ import annotations

from typing import Literal, Sequence, overload

import numpy as np

from ..config import PiezoConfig
from ..stage import Processor
from .bouc_wen import BoucWenModel
from .creep import CreepModel
from .dynamics import DynamicsModel

__all__ = ["Plant"]


class Plant:
    """Streaming ``U [V] → Y [m]``, the model chain with optional extra stages and sensor noise.

    Parameters
    ----------
    cfg : PiezoConfig
        Models and sample rate.
    pre, post : sequence of stages
        Extra streaming stages (``process``/``reset``) applied to the voltage before the chain, or to the
        displacement after it (unmodelled effects for truth plants).
    noise_std : float
        Standard deviation of white sensor noise added to the output [m] (0 = none).
    seed : int
        Seed of the noise generator (noise is drawn sample by sample from one stream: block-size invariant).
    stages : tuple of str
        Which of ``hysteresis``, ``creep``, ``dynamics`` to include (the intermediate systems of Fig. 3).
    """

    def __init__(self, cfg: PiezoConfig, pre: Sequence[Processor] = (), post: Sequence[Processor] = (), noise_std: float = 0.0,
                 seed: int = 0, stages: Sequence[str] = ("hysteresis", "creep", "dynamics")):
        self.cfg = cfg
        self.dt = cfg.dt
        self.stages = tuple(stages)
        self.hysteresis = BoucWenModel(cfg.hysteresis) if "hysteresis" in stages else None
        self.creep = CreepModel(cfg.creep, cfg.dt) if "creep" in stages else None
        self.dynamics = DynamicsModel(cfg.dynamics, cfg.dt) if "dynamics" in stages else None
        self.pre = list(pre)
        self.post = list(post)
        self.noise_std = float(noise_std)
        self.seed = seed
        self._rng = np.random.default_rng(seed)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return self.cfg.n_axes

    def reset(self) -> None:
        """All states back to rest."""
        for st in (self.hysteresis, self.creep, self.dynamics, *self.pre, *self.post):
            if st is not None:
                st.reset()
        self._rng = np.random.default_rng(self.seed)

    @overload
    def process(self, u: np.ndarray, taps: Literal[False] = ...) -> np.ndarray: ...
    @overload
    def process(self, u: np.ndarray, taps: Literal[True]) -> tuple[np.ndarray, dict[str, np.ndarray]]: ...

    def process(self, u: np.ndarray, taps: bool = False) -> np.ndarray | tuple[np.ndarray, dict[str, np.ndarray]]:
        """Run a block; with ``taps=True`` also return ``{'yh': Dp·U − h, 'yl': creep output}``.

        Parameters
        ----------
        u : ndarray
            Voltages [V], shape [N, axes].
        taps : bool
            Also return the intermediate signals.

        Returns
        -------
        y : ndarray
            Displacements [m], shape [N, axes] (with noise when ``noise_std`` > 0).
        taps : dict
            Only with ``taps=True``: ``yh`` and ``yl`` [N, axes].
        """
        x = np.ascontiguousarray(u, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n_axes:
            raise ValueError(f"expected a voltage block of shape [N, {self.n_axes}], got {x.shape}")
        for st in self.pre:
            x = st.process(x)
        out = {}
        if self.hysteresis is not None:
            x = self.hysteresis.process(x)
        out["yh"] = x
        if self.creep is not None:
            x = self.creep.process(x)
        out["yl"] = x
        if self.dynamics is not None:
            x = self.dynamics.process(x)
        for st in self.post:
            x = st.process(x)
        if self.noise_std > 0:
            x = x + self.noise_std * self._rng.standard_normal(x.shape)
        return (x, out) if taps else x
