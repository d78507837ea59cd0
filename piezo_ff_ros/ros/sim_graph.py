"""The simulated node graph as the commands start it (``piezo-ff demo``, ``piezo-ff commission``).

:func:`sim_graph` is a :class:`~piezo_ff_ros.ros.launcher.GraphLauncher` for driver (simulated PT230.94),
compensator, trajectory (lockstep) and recorder, with the driver and compensator enforcing the same limits.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

from .launcher import GraphLauncher


def sim_graph(out_dir: Path, mcap_path: Path, *, fs: float, voltage_limit: float, slew_limit: float,
              block_size: int = 2000, window: int = 4, config: str | Path | None = None, variant: str | None = None,
              metadata: dict[str, Any] | None = None,
              nodes: Iterable[str] = ("driver", "compensator", "trajectory", "recorder"),
              env: Mapping[str, str] | None = None, clocked: float | None = None) -> GraphLauncher:
    """A launcher for the sim graph recording to ``mcap_path`` (not started).

    The trajectory node always runs in lockstep (window flow control: lossless).  The simulated device is lockstep
    too (time follows the samples written), unless ``clocked`` is a time scale: then the driver runs the clocked
    simulator (FIFO, write-ahead, sensor latency, underruns — every timing path of a DAQ) with its device clock
    ``clocked`` times faster than the wall clock, and the device's pace sets the graph's.
    """
    cfg_args = []
    if config:
        cfg_args += ["-p", f"config_file:={Path(config).resolve()}"]
    if variant:
        cfg_args += ["-p", f"variant:={variant}"]
    meta = json.dumps(metadata or {})
    args = {
        "recorder": ["-p", f"output:={Path(mcap_path).resolve()}", "-p", f"metadata:='{meta}'", *cfg_args],
        "driver": [*cfg_args, "-p", f"limits.voltage:={float(voltage_limit)}",
                   "-p", f"limits.slew:={float(slew_limit)}",
                   # the lockstep simulator's time stands still while the graph waits (the driver suspends its
                   # watchdog while a lockstep run plays); with --clocked the device's clock runs (scaled): a
                   # wall-clock stale timeout there only needs to catch a dead compensator
                   "-p", "limits.stale_timeout:=5.0", *_clocked_driver_args(clocked, fs, block_size, window)],
        "compensator": [*cfg_args, "-p", "cascade.vibration:=false"],
        "trajectory": ["-p", "mode:=lockstep", "-p", f"block_size:={block_size}",
                       "-p", f"window:={_clocked_window(clocked, fs, block_size, window)}",
                       "-p", "min_subscribers:=2", "-p", f"sample_rate:={fs}", "-p", "lockstep_timeout:=30.0"],
    }
    return GraphLauncher({n: a for n, a in args.items() if n in nodes}, log_dir=Path(out_dir) / "logs",
                         env=os.environ if env is None else env)


#: wall-clock margin the clocked device is written ahead of its clock (absorbs the graph's delivery jitter)
CLOCKED_MARGIN_S = 0.25


def _clocked_window(scale: float | None, fs: float, block_size: int, window: int) -> int:
    """The lockstep window in front of a clocked device: a block is answered only once the device has *played* it,
    so the blocks in flight must cover the write-ahead margin twice over, or the FIFO drains."""
    if scale is None:
        return window
    return max(window, math.ceil(2 * CLOCKED_MARGIN_S * scale * fs / block_size))


def _clocked_driver_args(scale: float | None, fs: float, block_size: int, window: int) -> list[str]:
    """Driver parameters for the clocked simulator at ``scale``× real time: a write-ahead margin of
    :data:`CLOCKED_MARGIN_S` of wall time (device seconds = wall seconds × scale) and a FIFO that holds it plus the
    trajectory's window."""
    if scale is None:
        return []
    if not (math.isfinite(scale) and 1e-3 <= scale <= 1e3):
        raise ValueError(f"clocked time scale must be in [0.001, 1000], got {scale!r}")
    write_ahead = CLOCKED_MARGIN_S * scale
    window = _clocked_window(scale, fs, block_size, window)
    fifo = int(2 * (window * block_size + write_ahead * fs)) + 16
    return ["-p", "sim.mode:=clocked", "-p", f"sim.time_scale:={float(scale)}", "-p", f"write_ahead:={write_ahead}",
            "-p", f"low_water:={write_ahead / 4}", "-p", f"sim.fifo_depth:={fifo}"]
