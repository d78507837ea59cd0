"""Simulated positioner: the nominal plant of the config (``core.models.plant.Plant``) plus optional sensor noise."""
from __future__ import annotations

import numpy as np

from ...core.models.plant import Plant
from .base import Backend, BackendError


class SimBackend(Backend):
    """The paper's model chain U → Bouc-Wen → creep → G_L as the "hardware".

    Time in the simulator advances only with the samples written (a pause in the input freezes it).
    """

    name = "sim"

    def __init__(self, cfg, noise_std: float = 0.0, seed: int = 0):
        if not (np.isfinite(noise_std) and noise_std >= 0):
            raise BackendError(f"noise_std: must be a finite number ≥ 0, got {noise_std!r}")
        self.cfg = cfg
        self.noise_std = float(noise_std)
        self.seed = int(seed)
        self.plant: Plant | None = None
        self.samples = 0
        self.started = False

    @staticmethod
    def from_params(cfg, params: dict) -> "SimBackend":
        return SimBackend(cfg, noise_std=float(params.get("noise_std", 0.0)), seed=int(params.get("seed", 0)))

    def open(self) -> None:
        self.plant = Plant(self.cfg, noise_std=self.noise_std, seed=self.seed)
        # compile the kernels now, not on the first block
        self.plant.process(np.zeros((1, self.cfg.n_axes)))
        self.plant.reset()

    def start(self) -> None:
        if self.plant is None:
            raise BackendError("sim: start() before open()")
        self.started = True

    def write(self, voltage: np.ndarray) -> np.ndarray:
        if not self.started:
            raise BackendError("sim: write() before start()")
        self.samples += voltage.shape[0]
        return self.plant.process(voltage)

    def safe_state(self) -> None:
        pass  # the driver's ramp already brought the applied voltage to the safe value

    def reset(self) -> bool:
        if self.plant is not None:
            self.plant.reset()
        self.samples = 0
        return True

    def status(self) -> dict:
        return {"backend": self.name, "samples": self.samples, "noise_std": self.noise_std}
