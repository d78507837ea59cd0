"""The graph case of ``piezo-ff track --graph``: the same circle through the ROS node graph, recorded, replayed.

Driver (simulated PT230.94 = the printed model: the nominal truth), compensator (cascade, with or without the
preview stage as a runtime parameter), trajectory (lockstep, reference fed ``preview_s`` ahead) and recorder run
as processes on a private domain (:class:`~piezo_ff_ros.ros.launcher.GraphLauncher`).  The MCAP is read back with
:func:`~piezo_ff_ros.core.recording.run.load_run` and cut into segments by the existing analysis
(:func:`~piezo_ff_ros.core.analysis.segment_signals`); the recorded reference is the one fed ahead, so it is
shifted back by the preview before the error is read (last revolution).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

CIRCLE = {"type": "sequence", "segments": [{"name": "circle20_10hz", "meta": {"input": "reference"}, "trajectory": {
    "type": "circle", "radius": 2.0e-5, "frequency": 10.0, "revolutions": 4}}]}


def run_graph_case(out_dir: Path, preview: bool, say=lambda s: None, timeout: float = 180.0,
                   domain_id: int | None = None) -> dict:
    """Play the 20 µm circle at 10 Hz through the graph; returns a case row (``truth: nominal``, ``graph: true``)."""
    from ..core.analysis import segment_signals
    from ..core.recording.run import load_run
    from ..core.tracking.preview import PreviewConfig
    from ..ros.launcher import GraphLauncher

    fs = 20000.0
    preview_s = PreviewConfig().preview_samples(fs) / fs if preview else 0.0
    out_dir.mkdir(parents=True, exist_ok=True)
    mcap = out_dir / "run.mcap"
    if mcap.exists():
        mcap.unlink()
    comp = ["-p", f"preview.enabled:={'true' if preview else 'false'}"]
    traj = ["-p", "mode:=lockstep", "-p", "autostart:=true", "-p", "min_subscribers:=2", "-p", f"preview_s:={preview_s}",
            "-p", "lockstep_timeout:=120.0",  # the compensator may still be synthesising H∞ on a loaded machine
            "-p", f"trajectory:='{json.dumps(CIRCLE)}'"]
    # lockstep on a shared machine: a first block (JIT compilation) may take longer than the 0.2 s stale timeout
    drv = ["-p", "limits.stale_timeout:=5.0"]
    g = GraphLauncher({"recorder": ["-p", f"output:={mcap}"], "driver": drv, "compensator": comp, "trajectory": traj},
                      log_dir=out_dir / "logs", domain_id=domain_id)
    t0 = time.monotonic()
    g.start()
    try:
        while "trajectory finished" not in g.procs["trajectory"].log():
            g.check_alive()
            if "trajectory failed" in g.procs["trajectory"].log() or time.monotonic() - t0 > timeout:
                raise RuntimeError(f"graph case: the trajectory did not finish:\n{g.procs['trajectory'].log()[-800:]}")
            time.sleep(0.2)
    finally:
        g.stop()
    run = load_run(mcap)
    recorded, warnings = segment_signals(run)
    if "circle20_10hz" not in recorded:
        raise RuntimeError(f"graph case: segment not recorded ({warnings})")
    _, ref_ahead, u, y = recorded["circle20_10hz"]
    L = int(round(preview_s * fs))
    n = len(y)
    r = np.full_like(ref_ahead, np.nan)
    r[L:] = ref_ahead[: n - L]                      # the reference at k was published at k − L
    last = slice(n - int(round(fs / 10.0)), n)
    e = np.linalg.norm(y[last] - r[last], axis=1)
    say(f"graph {'preview' if preview else 'cascade'}: {n} samples, {time.monotonic() - t0:.1f} s")
    return {"trajectory": "circle", "size_um": 20, "frequency_hz": 10.0, "method": "preview" if preview else "cascade",
            "truth": "nominal", "graph": True, "rms_error_um": float(np.sqrt(np.mean(e ** 2)) * 1e6),
            "max_error_um": float(e.max() * 1e6), "peak_voltage_v": float(np.abs(u).max()),
            "peak_slew_v_per_s": float(np.abs(np.diff(u, axis=0)).max() * fs), "mcap": str(mcap),
            "preview_s": preview_s}
