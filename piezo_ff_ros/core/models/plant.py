"""The nominal plant S0 (the paper's chain): ``Y = G_L(s)·[K + Cr(s)]·(Dp·U − h)``, h the Bouc-Wen state.

Discretised at the config's sample rate as the model's definition says: the Bouc-Wen integrated along each sample's
straight voltage path (one explicit step for small steps, equal sub-steps for large ones: rate independent, see
:mod:`.bouc_wen`), every SISO transfer function by zero-order hold on its own, blocks in cascade.  ``effects`` (from :mod:`.effects`) can be
inserted before (on the voltage) or after (on the displacement) the nominal chain, and sensor noise added, to build
"truth" plants that differ from the nominal model.  The plant is a :class:`~piezo_ff_ros.core.chain.Chain`: the
nominal stages run as one fused compiled pass.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..chain import Chain
from ..config import PiezoConfig
from ..stage import Processor, as_block
from .bouc_wen import BoucWenModel
from .creep import CreepModel
from .dynamics import DynamicsModel

__all__ = ["Plant", "SensorNoise"]


class SensorNoise:
    """White sensor noise ``x + std·N(0, 1)``, drawn sample by sample from one seeded stream (block-size invariant)."""

    def __init__(self, std: float, seed: int = 0) -> None:
        self.std = float(std)
        self.seed = seed
        self._rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """The stream back to its seed."""
        self._rng = np.random.default_rng(self.seed)

    def process(self, x: np.ndarray) -> np.ndarray:
        """``x`` plus the next ``x.size`` draws (row by row)."""
        y: np.ndarray = x + self.std * self._rng.standard_normal(x.shape)
        return y


class Plant(Chain):
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

    Notes
    -----
    Stage names (taps of :meth:`process_with_taps`): ``pre0 …``, ``yh`` (after the hysteresis: ``Dp·U − h``), ``yl``
    (after the creep), ``y`` (after the dynamics), ``post0 …``, ``noise``.
    """

    def __init__(self, cfg: PiezoConfig, pre: Sequence[Processor] = (), post: Sequence[Processor] = (),
                 noise_std: float = 0.0, seed: int = 0,
                 stages: Sequence[str] = ("hysteresis", "creep", "dynamics")) -> None:
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
        self.noise = SensorNoise(self.noise_std, seed) if self.noise_std > 0 else None
        entries: list[tuple[str, Processor | None]] = [(f"pre{i}", st) for i, st in enumerate(self.pre)]
        entries += [("yh", self.hysteresis), ("yl", self.creep), ("y", self.dynamics)]
        entries += [(f"post{i}", st) for i, st in enumerate(self.post)]
        entries.append(("noise", self.noise))
        super().__init__(entries, n_in=cfg.n_axes, n_out=cfg.n_axes)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return self.cfg.n_axes

    def _check(self, block: np.ndarray) -> np.ndarray:
        x = as_block(block, self.n_axes, "voltage")
        return x

    def process_with_taps(self, block: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Run a block; also return ``{'yh': Dp·U − h, 'yl': creep output}``.

        Parameters
        ----------
        block : ndarray
            Voltages [V], shape [N, axes].

        Returns
        -------
        y : ndarray
            Displacements [m], shape [N, axes] (with noise when ``noise_std`` > 0).
        taps : dict
            ``yh`` and ``yl`` [N, axes].
        """
        y, taps = super().process_with_taps(block)
        return y, {"yh": taps["yh"], "yl": taps["yl"]}
