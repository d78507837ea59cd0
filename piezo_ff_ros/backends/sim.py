"""The ``sim`` backend: the config's nominal plant (``core.models.plant.Plant``, optional sensor noise) behind the
streaming contract, in ``lockstep`` (deterministic, time follows the samples written) or ``clocked`` mode (paced by
the wall clock like a DAQ: FIFO depth, transport latency, jitter, real underruns)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.hardware.simulated_device import ClockedSim, LockstepSim
from ..core.models.plant import Plant
from .base import BackendSpec, Param, float_range, int_range, one_of

if TYPE_CHECKING:
    from ..core.config import PiezoConfig


def create(cfg: PiezoConfig, p: dict[str, Any]) -> LockstepSim | ClockedSim:
    """The simulated device for the driver node (``BackendSpec.create``)."""
    model = Plant(cfg, noise_std=p["noise_std"], seed=p["seed"])
    model.process(np.zeros((1, cfg.n_axes)))   # compile the kernels now, not on the first block
    model.reset()
    # an amplifier without displacement sensor: the stage moves, nothing is measured
    plant = model if p["sensor"] else None
    if p["mode"] == "lockstep":
        return LockstepSim(cfg.sample_rate, cfg.n_axes, plant)
    return ClockedSim(cfg.sample_rate, cfg.n_axes, plant, fifo_depth=p["fifo_depth"],
                      latency_samples=p["latency_samples"], jitter_samples=p["jitter_samples"], seed=p["seed"],
                      time_scale=p["time_scale"])


SPEC = BackendSpec(
    name="sim",
    description="simulated positioner (the config's model), lockstep or clocked",
    parameters={
        "mode": Param("lockstep", "lockstep: time follows the samples written; clocked: paced by the wall clock",
                      one_of("lockstep", "clocked")),
        "noise_std": Param(0.0, "sensor noise standard deviation [m]", float_range(0.0, 1e-3)),
        "seed": Param(0, "seed of the sensor noise and jitter", int_range(0, 2 ** 31 - 1)),
        "fifo_depth": Param(20000, "clocked: output FIFO [samples] (≥ the driver's write_ahead)", int_range(16, 10_000_000)),
        "latency_samples": Param(2, "clocked: sensor transport latency [samples]", int_range(0, 1_000_000)),
        "jitter_samples": Param(0, "clocked: random extra sensor delivery delay, up to [samples]",
                                int_range(0, 1_000_000)),
        "sensor": Param(True, "false: a device without displacement sensor (open-loop amplifier only: no "
                              "displacement topic; commissioning refuses it)"),
        "time_scale": Param(1.0, "clocked: device seconds per wall second (1 = real time; >1 runs the simulated "
                                 "device faster, e.g. for long demos)", float_range(1e-3, 1e3)),
    },
    create=create,
)
