"""Commissioning refuses an identification whose held-out fit is below the floor, on the core sequence, the
``--sim-only`` command and the command through the ROS graph; ``--accept-poor-fit`` keeps it with a warning.

The untrustworthy identification is made by physics, not by a fake: a displacement sensor whose noise (50 µm rms)
exceeds the motion it measures (the held-out hysteresis run moves about ±20 µm).
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from piezo_ff_ros.core.characterisation import CharacterisationSettings
from piezo_ff_ros.core.commissioning import (FIT_FLOOR_PERCENT, PoorFitError, SimRig, below_floor, commission)
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
#: short characterisation (the sequence, not the figures, is tested)
SHORT = CharacterisationSettings(creep_duration=3.0, sine_frequency=1.0, sine_periods=1, plant_validation_duration=2.0,
                                 plant_validation_hold=0.5)
NOISE_M = 50e-6   # sensor noise larger than the motion: no model can predict the measured output


class PlayLog(SimRig):
    """The core simulated rig, noting which runs were played and which configurations were put in front."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.played, self.configured = [], []

    def play(self, runs, meta=None):
        self.played += [r.name for r in runs]
        return super().play(runs, meta)

    def configure(self, cfg, stages, bypass=False):
        self.configured.append((sorted(stages), bypass))
        super().configure(cfg, stages, bypass)


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def test_below_floor_names_the_entries_below_it_or_undefined():
    assert below_floor("plant", {"x": 99.0, "y": 98.0}, ("x", "y")) is None
    assert below_floor("hysteresis", {"x": 99.0, "y": -9776542.385}, ("x", "y")) == \
        "hysteresis held-out fit y: -9776542.385 % (floor 50 %)"
    # an off-diagonal entry is not checked; an undefined fit is refused
    assert below_floor("dynamics", {"xx": 97.0, "xy": -1303.0, "yx": 10.0, "yy": None}, ("xx", "yy")) == \
        "dynamics (G_L) held-out fit yy: undefined (floor 50 %)"
    assert FIT_FLOOR_PERCENT >= 0


def test_core_refuses_a_hysteresis_model_below_the_floor_before_putting_it_in_front_of_the_plant():
    cfg = load_config()
    rig = PlayLog(Plant(cfg, noise_std=NOISE_M, seed=1), cfg.sample_rate, cfg.axes)
    with pytest.raises(PoorFitError) as exc:
        commission(rig, base=cfg, settings=SHORT, synthesize=False)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith("hysteresis held-out fit x: ") and ", y: " in msg and "(floor 50 %)" in msg
    assert "--sine-periods" in msg and "--accept-poor-fit" in msg
    # refused as soon as it was identified: nothing but the hysteresis runs played, only ever bypassed
    assert rig.played == ["sine_x", "sine_y", "sine_all", "sine_validation"]
    assert rig.configured == [([], True)]


def test_core_keeps_a_poor_identification_on_request_and_says_so():
    cfg = load_config()
    rig = SimRig(Plant(cfg, noise_std=NOISE_M, seed=1), cfg.sample_rate, cfg.axes)
    res = commission(rig, base=cfg, settings=SHORT, synthesize=False, accept_poor_fit=True)
    kept = res.report.accepted_poor_fits
    stages = [k.split(" held-out")[0] for k in kept]
    assert stages == ["hysteresis", "creep", "hysteresis (refitted once creep is known)", "dynamics (G_L)", "plant"]
    assert res.report.to_json()["accepted_poor_fits"] == kept
    assert "BELOW THE FLOOR" in res.report.format_fits()


def test_a_sound_identification_passes_the_floor_and_reports_nothing_kept():
    cfg = load_config()
    res = commission(SimRig(Plant(cfg), cfg.sample_rate, cfg.axes), base=cfg, settings=SHORT, synthesize=False)
    assert res.report.accepted_poor_fits is None and "accepted_poor_fits" not in res.report.to_json()
    assert min(res.report.fit_percent["hysteresis"].values()) > 90


def test_cli_sim_only_refuses_with_one_line_and_a_nonzero_exit_writing_nothing(tmp_path):
    out = tmp_path / "c"
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--sim-only", "--out", str(out),
                        "--quiet", "--creep-duration", "2", "--noise-nm", str(NOISE_M * 1e9)],
                       env=_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 3, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert lines[0].startswith("piezo-ff commission: refused: hysteresis held-out fit x: ")
    assert "(floor 50 %)" in lines[0] and "--accept-poor-fit" in lines[0]
    assert not (out / "config.yaml").exists() and not (out / "commission.json").exists()


def test_cli_floor_in_the_help_is_the_cores():
    from piezo_ff_ros.cli import commission as cli

    assert cli.FIT_FLOOR == FIT_FLOOR_PERCENT


def test_graph_refuses_the_identification_of_a_noisy_driver_before_applying_it(tmp_path):
    """Commissioning through the graph against a running simulated driver whose sensor noise swamps the motion:
    refused after the hysteresis runs (exit 3, one line), no config written, the compensator never given it."""
    pytest.importorskip("rclpy")
    from test_nodes_integration import Probe, start_node, stop_node

    driver = start_node("driver", "-p", f"noise_std:={NOISE_M}", log_dir=tmp_path)
    try:
        probe = Probe("noisy_probe")
        try:
            probe.spin_until(lambda: probe.node.count_subscribers("/voltage") > 0, 90, "the driver configured")
        finally:
            probe.close()
        out = tmp_path / "c"
        r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--out", str(out), "--quiet",
                            "--creep-duration", "2", "--sine-frequency", "1", "--sine-periods", "1",
                            "--probe-timeout", "5", "--domain-id", os.environ["ROS_DOMAIN_ID"]],
                           env=_env(), capture_output=True, text=True, timeout=300)
    finally:
        assert stop_node(driver) == 0
    assert r.returncode == 3, r.stderr[-3000:] + "\n--- stdout:\n" + r.stdout[-2000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("piezo-ff commission: refused: hysteresis held-out fit x: "), r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    assert not (out / "config.yaml").exists() and not (out / "commission.json").exists()
    # the recording holds the hysteresis runs only: refused before the plant record and the creep steps
    from piezo_ff_ros.core.recording.mcap_io import read_run

    names = [s["name"] for s in read_run(out / "commission.mcap").meta["segments"]]
    assert names == ["sine_x", "sine_y", "sine_all", "sine_validation"]


def test_cli_sim_only_accept_poor_fit_completes_and_lists_what_it_kept(tmp_path):
    out = tmp_path / "c"
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "commission", "--sim-only", "--out", str(out),
                        "--quiet", "--no-compare", "--creep-duration", "2", "--sine-frequency", "1",
                        "--sine-periods", "1", "--noise-nm", str(NOISE_M * 1e9), "--accept-poor-fit"],
                       env=_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    kept = json.loads((out / "commission.json").read_text())["accepted_poor_fits"]
    assert kept[0].startswith("hysteresis held-out fit x: ") and any(k.startswith("plant held-out") for k in kept)
    assert "BELOW THE FLOOR" in r.stdout and (out / "config.yaml").exists()
