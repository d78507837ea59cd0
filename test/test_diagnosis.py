"""Gap diagnosis: a hidden effect is found with its parameters, noise alone gives `none`, JSON and CLI outputs."""
import dataclasses
import json

import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from bench.synthetic.in_family import make_runs
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose, json_ready
from piezo_ff_ros.core.diagnosis.replay import Windows, noise_floor, nrmse_percent, simulate
from piezo_ff_ros.core.recording.run import RunData

FS = 5000.0
DUR = 8.0
# a reduced library keeps the test fast; the benchmark script runs all ten candidates
FAST = ("gain_mismatch", "input_delay", "hysteresis_asymmetry", "amplifier_saturation", "thermal_drift")


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def _case(effect, params, seed=0):
    return {"name": effect, "effect": effect, "params": params, "level": "clear", "seed": seed}


def test_nrmse_and_noise_floor():
    rng = np.random.default_rng(1)
    t = np.arange(20000) / FS
    y = np.c_[np.sin(2 * np.pi * t), np.cos(2 * np.pi * 3 * t)] * 1e-5
    noise = 1e-7 * rng.standard_normal(y.shape)
    assert nrmse_percent(y, y) == 0.0
    assert nrmse_percent(y, np.full_like(y, y.mean())) == pytest.approx(100.0)
    sig = noise_floor(y + noise - y)  # the smooth part must not leak into the noise estimate
    assert np.allclose(noise_floor(noise + 0.01 * y), 1e-7, rtol=0.05)
    assert np.allclose(sig, 1e-7, rtol=0.05)


def test_windows_reproduce_whole_run_after_warmup(cfg):
    u = np.c_[100 * np.sin(2 * np.pi * 2 * np.arange(40000) / FS), np.zeros(40000)]
    whole = simulate(cfg, u)
    win = Windows.spread(len(u), 8000, n_windows=4, warmup=4000)
    assert not win.is_whole and win.n == 8000
    part = simulate(cfg, u, [], win)
    # after a 0.8 s warm-up the hysteresis has forgotten its start; creep has not entirely: small but not zero
    err = np.max(np.abs(part - win.take(whole)))
    assert 0 < err < 0.05 * np.max(np.abs(whole))


@pytest.mark.parametrize("effect,params,key", [
    ("input_delay", {"delay": 1.0e-3}, "delay"),
    ("hysteresis_asymmetry", {"Delta1": [0.004, 0.003], "Delta2": [0.0, 0.0]}, "Delta1"),
])
def test_hidden_effect_found_with_its_parameters(cfg, effect, params, key):
    train, test = make_runs(cfg, _case(effect, params), duration=DUR)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=FAST, max_stack=1))
    assert res["verdict"] == effect
    top = res["ranking"][0]
    assert top["effect"] == effect
    fitted = np.atleast_1d(top["params"][key]["value"])
    truth = np.atleast_1d(params[key])
    assert np.allclose(fitted, truth, rtol=0.1)
    stderr = np.atleast_1d(top["params"][key]["stderr"])
    assert np.all(np.isfinite(stderr)) and np.all(stderr < np.abs(truth))
    h = res["heldout"]
    assert h["after_nrmse_percent"] < 0.5 * h["before_nrmse_percent"]
    assert h["after_nrmse_percent"] < 1.2 * h["noise_floor_nrmse_percent"]


def test_noise_only_gives_none_and_json_contract(cfg):
    train, test = make_runs(cfg, {"name": "null", "effect": "none", "params": {}, "seed": 3}, duration=DUR)
    res = json_ready(diagnose(cfg, train, test, DiagnosisOptions(candidates=FAST)))
    assert res["verdict"] == "none"
    text = json.dumps(res)  # JSON-serialisable, no arrays
    d = json.loads(text)
    assert set(d["heldout"]) >= {"before_nrmse_percent", "after_nrmse_percent"}
    assert d["heldout"]["after_nrmse_percent"] == pytest.approx(d["heldout"]["before_nrmse_percent"])
    assert len(d["ranking"]) == len(FAST)
    for r in d["ranking"]:
        assert set(r) >= {"effect", "heldout_before_nrmse_percent", "heldout_after_nrmse_percent", "params"}
        assert not r["accepted"]
    w = d["where"]
    assert set(w) >= {"axis", "pair", "band", "amplitude", "branch", "regime", "summary"}
    assert "noise floor" in w["summary"]


def test_where_locates_a_one_axis_gain_error(cfg):
    train, test = make_runs(cfg, _case("gain_mismatch", {"gains": [1.0, 1.06]}), duration=DUR)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("gain_mismatch",)))
    w = res["where"]
    assert w["axis"]["y"]["energy_share"] > 0.9
    assert w["pair"]["y->y"]["energy_share_of_axis"] > 0.8 and w["pair"]["y->y"]["kind"] == "direct"
    assert "axis y" in w["summary"]
    g = res["ranking"][0]["params"]["gains"]["value"]
    assert g == pytest.approx([1.0, 1.06], abs=0.005)


def test_bad_input_is_a_clear_error(cfg):
    train, test = make_runs(cfg, _case("gain_mismatch", {"gains": [1.0, 1.0]}), duration=1.0)
    bad = RunData(test.t, test.u.copy(), test.y.copy(), test.axes)
    bad.y[100, 1] = np.nan
    with pytest.raises(ValueError, match="test: y has NaN"):
        diagnose(cfg, train, bad)
    one_axis = RunData(test.t, test.u[:, :1], test.y[:, :1], ("x",))
    with pytest.raises(ValueError, match="2 axes"):
        diagnose(cfg, one_axis, one_axis)


def _write_csv(path, run):
    data = np.column_stack([run.t, run.u, run.y])
    np.savetxt(path, data, delimiter=",", header="t,u_x,u_y,x,y", comments="", fmt="%.10g")


def test_cli_on_csv_writes_json_report_and_corrected_config(cfg, tmp_path, capsys):
    from piezo_ff_ros.cli import main

    train, test = make_runs(cfg, _case("gain_mismatch", {"gains": [1.05, 0.97]}), duration=4.0)
    _write_csv(tmp_path / "train.csv", train)
    _write_csv(tmp_path / "test.csv", test)
    model = tmp_path / "model.yaml"
    # no vibration stage: the tracking comparison then needs no H∞ synthesis (keeps the test fast)
    dataclasses.replace(cfg, cascade=dataclasses.replace(cfg.cascade, vibration=False)).to_yaml(model)
    rc = main(["diagnose", "--model", str(model), "--train", str(tmp_path / "train.csv"),
               "--test", str(tmp_path / "test.csv"), "--json", str(tmp_path / "out.json"),
               "--report", str(tmp_path / "rep"), "--apply", str(tmp_path / "fixed.yaml"),
               "--candidates", "gain_mismatch,input_delay"])
    assert rc == 0
    d = json.loads((tmp_path / "out.json").read_text())
    assert d["verdict"] == "gain_mismatch"
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "gain_mismatch" in md and "Where" in md
    for f in ("residual_spectra.png", "loops.png", "residual_time.png", "tracking.png"):
        assert (tmp_path / "rep" / f).stat().st_size > 5000
    fixed = load_config(tmp_path / "fixed.yaml")
    assert np.allclose(np.array(fixed.creep.K)[0], 1.05 * np.array(cfg.creep.K)[0], rtol=0.01)
    assert d["apply"]["tracking_rms_um"]["after"] < 0.5 * d["apply"]["tracking_rms_um"]["before"]
    out = capsys.readouterr().out
    assert "verdict: gain_mismatch" in out
    # a malformed file is a clean error, not a traceback
    (tmp_path / "bad.csv").write_text("t,u_x,u_y,x,y\n0,1,2,3\n")
    assert main(["diagnose", "--data", str(tmp_path / "bad.csv")]) == 2
    assert "error" in capsys.readouterr().err


def test_result_is_a_frozen_mapping_of_its_json_with_the_arrays_apart(cfg):
    """The result is a frozen mapping of its JSON with the arrays kept apart (it used to be a dict carrying arrays
    under "_arrays" inside its "JSON-ready" report)."""
    from piezo_ff_ros.core.diagnosis import DiagnosisResult

    train, test = make_runs(cfg, _case("gain_mismatch", {"gains": [1.0, 1.06]}), duration=DUR)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("gain_mismatch",)))
    assert isinstance(res, DiagnosisResult) and "_arrays" not in res
    assert res["verdict"] == res.to_json()["verdict"] and set(res) == set(res.to_json())
    assert res.arrays.y_test_nom.shape == test.y.shape and res.arrays.cfg is cfg
    json.dumps(res.to_json(), allow_nan=False)              # plain JSON, no NaN
    with pytest.raises(TypeError):
        res.report["verdict"] = "none"                       # read-only
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.arrays = None
