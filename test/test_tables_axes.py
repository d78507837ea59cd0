"""Tables I/II per axis and per ordered pair, circles and replay tracking on stages of one, two and three axes."""
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.experiments import paper_experiments, select_experiments
from piezo_ff_ros.core.reproduce import format_tables, reproduce

CONFIG = Path(__file__).resolve().parents[1] / "config"


def _short(cfg, only):
    exps = paper_experiments(cfg, creep_duration=2.0)
    return select_experiments(exps, ",".join(n for n in only if n in {e.name for e in exps}))


def test_three_axes_table_two_has_every_ordered_pair():
    cfg = load_config(CONFIG / "xyz_tube.yaml")
    names = [f"{k}_{a}" for k in ("hyst_S0", "step_T") for a in cfg.axes] + ["circle20_T"]
    res, rec = reproduce(cfg, experiments=_short(cfg, names))
    pairs = res.cross_coupling_pairs_percent
    assert set(pairs["before"]) == set(pairs["after"]) == {"xy", "xz", "yx", "yz", "zx", "zy"}
    assert all(v is not None and np.isfinite(v) for ph in pairs.values() for v in ph.values())
    # z is decoupled from x and y in this stage; x and y couple as in the paper's 2-axis tables
    assert max(abs(pairs["before"][k]) for k in ("xz", "yz", "zx", "zy")) < 0.05
    assert abs(pairs["before"]["xy"]) > 0.3 and abs(pairs["before"]["yx"]) > 0.3
    # per axis: the largest of its row
    assert res.before["cross_coupling_percent"]["x"] == max((pairs["before"]["xy"], pairs["before"]["xz"]), key=abs)
    assert res.to_json()["cross_coupling_pairs_percent"] == pairs
    # the circle in the x-y plane, z held at rest
    assert rec["circle20_T"].reference.shape[1] == 3 and np.all(rec["circle20_T"].reference[:, 2] == 0)
    text = format_tables(res, axes=cfg.axes)
    for pair in ("x←z", "z←x", "z←y", "y←x"):
        assert f"  {pair} " in text
    assert "  z  this run" in text and "  z  paper" not in text


def test_one_axis_tables_and_no_circle():
    cfg = load_config(CONFIG / "single_stack.yaml")
    exps = paper_experiments(cfg, creep_duration=2.0, hysteresis_periods=1)
    assert not [e for e in exps if e.metric == "tracking"]
    res, _ = reproduce(cfg, experiments=_short(cfg, ["hyst_S0_x", "step_SL_x", "step_T_x"]))
    assert res.before["cross_coupling_percent"] == {"x": None} and res.cross_coupling_pairs_percent is None
    assert 40 < res.before["overshoot_percent"]["x"] < 50
    text = format_tables(res, axes=cfg.axes)
    assert "one axis: no cross-coupling" in text and "  x  paper" in text


def test_two_axes_keep_one_pair_per_axis_and_no_pair_key():
    cfg = load_config()
    res, _ = reproduce(cfg, experiments=_short(cfg, ["hyst_S0_x", "hyst_S0_y"]))
    assert res.cross_coupling_pairs_percent is None and "cross_coupling_pairs_percent" not in res.to_json()
    assert set(res.before["cross_coupling_percent"]) == {"x", "y"}
    assert all(v is not None for v in res.before["cross_coupling_percent"].values())


def test_analyze_reads_a_circle_error_after_its_lead_in(tmp_path):
    """A circle played from rest starts a radius away from the stage: the replay's tracking error of the segment
    is read after the lead-in its experiment names (the last revolution), not over the radius-sized start."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_analyze import FS, UM, _record

    from piezo_ff_ros.core.analysis import analyze_run
    from piezo_ff_ros.core.recording.mcap_io import read_run

    n = 2 * FS   # two revolutions at 1 Hz; the stage lags 1 ms behind and starts at rest
    t = np.arange(n) / FS
    ref = 20 * UM * np.column_stack([np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)])
    y = np.vstack([np.zeros((20, 2)), ref[:-20]])
    mark = {"name": "circle20_T", "metric": "tracking", "params": {"skip": 1.0, "radius": 20 * UM}}
    path = _record(tmp_path / "c.mcap", ref, np.zeros_like(ref), y, markers={0: mark})
    seg = analyze_run(read_run(path)).to_json()["replay"]["segments"][0]
    lag = 2 * np.pi * 20 * UM * 20 / FS   # the 1 ms lag's error on a 20 µm circle at 1 Hz ≈ 0.126 µm
    assert max(seg["tracking"]["max"]) == pytest.approx(lag, rel=0.01)   # was the radius, 20 µm
    assert seg["tracking_from_s"] == 1.0


def test_feedforward_on_three_and_one_axes(tmp_path):
    """A plane circle on an XYZ stage (z at rest), a helix spec per axis, and a sine on a single-axis stack."""
    from piezo_ff_ros.cli import main

    xyz, one = str(CONFIG / "xyz_tube.yaml"), str(CONFIG / "single_stack.yaml")
    circle = "{type: circle, radius: 1.0e-5, frequency: 10, revolutions: 1}"
    helix = ("{type: per_axis, axes: [x, y, z], parts: [{type: circle, axes: [x, y], radius: 1.0e-5, frequency: 10,"
             " revolutions: 1}, {type: ramp, axes: [z], start: 0, end: 5.0e-6, duration: 0.1}]}")
    sine = "{type: sine, axes: [x], axis: x, amplitude: 1.0e-5, frequency: 10, duration: 0.1}"
    for name, cfg, spec, n_axes in (("c", xyz, circle, 3), ("h", xyz, helix, 3), ("s", one, sine, 1)):
        out = tmp_path / f"{name}.npy"
        assert main(["feedforward", "--config", cfg, "--trajectory", spec, "--out", str(out)]) == 0
        u = np.load(out)
        assert u.shape == (2000, n_axes) and np.all(np.isfinite(u))
        if name == "c":
            assert np.abs(u[:, 2]).max() < 1e-6 and np.abs(u[:, :2]).max() > 30
        if name == "h":
            assert u[-1, 2] > 25   # 5 µm up on z (0.16 µm/V)
