"""What `diagnose` takes in: inputs it cannot diagnose are refused with one line; the package's own recordings
(applied voltage, gaps between experiments, a held-out part that does not start at rest, one axis) go through."""
from __future__ import annotations

import json

import numpy as np
import pytest

from bench.synthetic.in_family import make_runs
from piezo_ff_ros.cli import main as cli_main
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording import blocks as B
from piezo_ff_ros.core.recording.mcap_io import McapRecorder
from piezo_ff_ros.core.recording.run import RunData

FS = 5000.0
FAST = ("gain_mismatch", "input_delay", "thermal_drift")
NULL = {"name": "null", "effect": "none", "params": {}, "seed": 0}


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


@pytest.fixture(scope="module")
def runs(cfg):
    return make_runs(cfg, NULL, duration=2.0)


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert ": error: " in err, err
    for n in needles:
        assert n in err, err
    return err


def _write_csv(path, run):
    cols = [f"u_{a}" for a in run.axes] + list(run.axes)
    np.savetxt(path, np.column_stack([run.t, run.u, run.y]), delimiter=",", header=",".join(["t", *cols]),
               comments="", fmt="%.12g")
    return path


# -- refusals ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("what", ["all_zero", "constant_u", "constant_y"])
def test_no_excitation_is_refused_not_a_confident_none(cfg, runs, what):
    train, test = runs
    if what == "all_zero":
        bad = RunData(test.t, np.zeros_like(test.u), np.zeros_like(test.y), test.axes)
    elif what == "constant_u":
        bad = RunData(test.t, np.full_like(test.u, 30.0), test.y, test.axes)
    else:
        bad = RunData(test.t, test.u, np.full_like(test.y, 1e-6), test.axes)
    with pytest.raises(ValueError, match="no excitation|constant"):
        diagnose(cfg, bad, bad, DiagnosisOptions(candidates=FAST))


def test_no_excitation_through_the_cli_is_one_line(cfg, runs, tmp_path, capsys):
    train, _ = runs
    zero = RunData(train.t, np.zeros_like(train.u), np.zeros_like(train.y), train.axes)
    path = _write_csv(tmp_path / "zero.csv", zero)
    assert cli_main(["diagnose", "--data", str(path), "--candidates", ",".join(FAST)]) == 2
    _one_line_error(capsys, "no excitation")


def test_displacement_in_micrometres_stored_as_metres_is_refused(cfg, runs):
    train, test = runs
    um = RunData(test.t, test.u, test.y * 1e6, test.axes)
    with pytest.raises(ValueError, match=r"scale.*1e\+?0?6|µm"):
        diagnose(cfg, RunData(train.t, train.u, train.y * 1e6, train.axes), um, DiagnosisOptions(candidates=FAST))


def _record(path, u, y, fs, *, metadata_rate=None, applied=None, gaps=(), markers=(), block=250, axes=("x", "y")):
    """An MCAP of the topic contract: ``voltage`` (commanded), optionally ``voltage_applied``, ``displacement``;
    ``gaps``: [start, stop) sample ranges with no block on any topic; ``markers``: {k0: experiment name}."""
    dt_ns = int(round(1e9 / fs))
    marks = dict(markers)
    with McapRecorder(path) as rec:
        rec.set_metadata({"sample_rate": metadata_rate or fs, "t0_ns": 0, "axes": list(axes)})
        topics = ["voltage", "displacement"] + (["voltage_applied"] if applied is not None else [])
        for t in topics:
            rec.register_topic(f"/{t}", B.BLOCK_TYPE)
        rec.register_topic("/experiment", "std_msgs/msg/String")
        for k0 in range(0, len(u), block):
            if any(a <= k0 < b for a, b in gaps):
                continue
            stamp = k0 * dt_ns
            if k0 in marks:
                rec.write("/experiment", B.serialize_message(
                    {"data": json.dumps({"k0": k0, "stages": [], "name": marks[k0]})}, "std_msgs/msg/String"), stamp)
            for t, sig in (("voltage", u), ("displacement", y), ("voltage_applied", applied)):
                if t in topics:
                    rec.write(f"/{t}", B.serialize_block(sig[k0:k0 + block], stamp, axes), stamp)
    return path


def test_mcap_whose_metadata_rate_disagrees_with_its_stamps_is_refused(runs, tmp_path, capsys):
    train, _ = runs
    path = _record(tmp_path / "rate.mcap", train.u, train.y, FS, metadata_rate=2 * FS)
    assert cli_main(["diagnose", "--data", str(path), "--candidates", ",".join(FAST)]) == 2
    _one_line_error(capsys, "sample rate", "10000", "5000")


# -- the package's own recordings ----------------------------------------------------------------------------------

def _applied_from(u, fs):
    """What a driver applies for the commanded ``u``: a 0.2 s ramp from 0 V at the start (slew-limited start) and
    two dropped blocks during which the last voltage is held."""
    applied = u.copy()
    n_ramp = int(0.2 * fs)
    applied[:n_ramp] *= (np.arange(n_ramp) / n_ramp)[:, None]
    for a in (3000, 7250):
        applied[a:a + 250] = applied[a - 1]
    return applied


def test_the_applied_voltage_is_replayed_where_it_was_recorded(cfg, runs, tmp_path):
    train, test = runs
    u = np.vstack([train.u, test.u])
    applied = _applied_from(u, FS)
    y = build_plant(cfg, [], noise_std=2e-9, seed=4).process(applied)   # model = plant, driven by what was applied
    path = _record(tmp_path / "run.mcap", u, y, FS, applied=applied)
    out = tmp_path / "out.json"
    assert cli_main(["diagnose", "--data", str(path), "--json", str(out), "--quiet",
                     "--candidates", ",".join(FAST)]) == 0
    d = json.loads(out.read_text())
    assert d["input"]["voltage"] == "voltage_applied"
    assert d["where"]["train_nrmse_percent"] < 1.0
    assert d["heldout"]["before_nrmse_percent"] < 1.0
    assert d["verdict"] == "none"


def test_gaps_between_experiments_are_segments_not_nan(cfg, runs, tmp_path, capsys):
    train, test = runs
    u = np.vstack([train.u, test.u])
    y = build_plant(cfg, [], noise_std=2e-9, seed=5).process(u)
    # the driver holds its last voltage between experiments; nothing is recorded there
    gaps = [(6000, 7000), (14000, 14500)]
    for a, b in gaps:
        u[a:b] = u[a - 1]
    y = build_plant(cfg, [], noise_std=2e-9, seed=5).process(u)
    path = _record(tmp_path / "commission.mcap", u, y, FS, gaps=gaps,
                   markers={0: "sines", 7000: "steps", 14500: "multisine"})
    out = tmp_path / "out.json"
    assert cli_main(["diagnose", "--data", str(path), "--json", str(out), "--quiet",
                     "--candidates", ",".join(FAST)]) == 0
    d = json.loads(out.read_text())
    seg = d["input"]["segments"]
    assert [(s["start"], s["stop"]) for s in seg["stretches"]] == [(0, 6000), (7000, 14000), (14500, 20000)]
    assert seg["train"] != seg["test"]
    assert d["heldout"]["before_nrmse_percent"] < 1.0 and d["verdict"] == "none"


def test_a_test_run_that_does_not_start_at_rest_is_named(cfg, runs):
    train, test = runs
    k = len(test) // 3
    late = test.slice(k, len(test))
    assert np.max(np.abs(late.u[0])) > 5.0
    res = diagnose(cfg, train, late, DiagnosisOptions(candidates=FAST))
    assert any(w.startswith("test starts") and "not at rest" in w for w in res["warnings"])
    res = diagnose(cfg, train, late, DiagnosisOptions(candidates=FAST), test_history=test.slice(0, k))
    assert not any(w.startswith("test starts") for w in res["warnings"])


def test_single_axis_hysteresis_only_record_through_the_cli(tmp_path, capsys):
    from piezo_ff_ros.core.config import PiezoConfig

    w = 2 * np.pi * 1000.0
    one = PiezoConfig.from_dict({
        "name": "one_axis_hysteresis", "axes": ["x"], "sample_rate": 200.0, "units": {"length": "um"},
        "hysteresis": {"Dp": [[0.5]], "A": [[0.2]], "B": [[0.01]], "Gamma": [[0.002]]},
        "creep": {"K": [[1.0]], "Cr": {}}, "dynamics": {"G_L": {"xx": {"k": w, "num": [], "den": [[1, w]]}}},
        "vibration": {"W2": [1.0]}, "cascade": {"vibration": False}})
    model = tmp_path / "one.yaml"
    one.to_yaml(model)
    t = np.arange(12000) / 200.0
    rng = np.random.default_rng(0)
    u = 40 * np.sin(2 * np.pi * 0.5 * t)[:, None] * (1 + 0.5 * np.sin(2 * np.pi * 0.01 * t))[:, None]
    y = build_plant(one, [], noise_std=1e-9, seed=1).process(u) + 0 * rng.standard_normal(u.shape)
    path = _write_csv(tmp_path / "dbo.csv", RunData(t, u, y, ("x",)))
    out = tmp_path / "out.json"
    assert cli_main(["diagnose", "--model", str(model), "--data", str(path), "--json", str(out), "--quiet",
                     "--candidates", "gain_mismatch,thermal_drift"]) == 0
    d = json.loads(out.read_text())
    assert d["model"]["axes"] == ["x"] and d["verdict"] == "none"
    # the default (two-axis) model on a one-axis record: one line saying what to give
    assert cli_main(["diagnose", "--data", str(path), "--quiet"]) == 2
    _one_line_error(capsys, "1 input", "--model")


def test_a_stated_sample_rate_settles_the_disagreement(runs, tmp_path):
    train, _ = runs
    path = _record(tmp_path / "rate.mcap", train.u, train.y, FS, metadata_rate=2 * FS)
    out = tmp_path / "out.json"
    assert cli_main(["diagnose", "--data", str(path), "--sample-rate", str(FS), "--json", str(out), "--quiet",
                     "--candidates", ",".join(FAST)]) == 0
    assert json.loads(out.read_text())["model"]["sample_rate"] == FS


def test_periodic_npy_records_go_through_the_cli(cfg, runs, tmp_path, capsys):
    """A ``u_<tag>.npy``/``y_<tag>.npy`` pair (the fine steering mirror set's layout, ``[N, channels, R, P]``) is
    diagnosed like any run: the realization asked, at the stated rate; an absent realization is one line."""
    train, test = runs
    for tag, r in (("train", train), ("test", test)):
        u2 = np.stack([r.u, r.u[::-1]], axis=-1)[..., None]          # two realizations, one period each
        y2 = np.stack([build_plant(cfg, [], noise_std=2e-9, seed=7).process(u2[..., k, 0]) for k in range(2)],
                      axis=-1)[..., None]
        np.save(tmp_path / f"u_{tag}.npy", u2)
        np.save(tmp_path / f"y_{tag}.npy", y2)
    out = tmp_path / "out.json"
    assert cli_main(["diagnose", "--train", str(tmp_path / "u_train.npy"), "--test", str(tmp_path / "y_test.npy"),
                     "--sample-rate", str(FS), "--realization", "1", "--json", str(out), "--quiet",
                     "--candidates", ",".join(FAST)]) == 0
    d = json.loads(out.read_text())
    assert d["model"]["sample_rate"] == FS
    assert d["heldout"]["before_nrmse_percent"] < 1.0 and d["verdict"] == "none"
    capsys.readouterr()   # the reversed realization does not start at rest: its warnings are not what is checked
    assert cli_main(["diagnose", "--train", str(tmp_path / "u_train.npy"), "--test", str(tmp_path / "u_test.npy"),
                     "--sample-rate", str(FS), "--realization", "2", "--quiet"]) == 2
    _one_line_error(capsys, "realization 2", "holds 2")
