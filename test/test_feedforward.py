"""``piezo-ff feedforward``: offline compensated voltages — the plant driven by them tracks the reference, the
three formats agree (CSV read by column name, .mat by scipy), the amplifier limits hold, bad input is one line."""
import json

import numpy as np
import pytest
import scipy.io

from piezo_ff_ros.cli import main
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models.plant import Plant
from piezo_ff_ros.core.trajectories import from_dict

SPEC = "{type: circle, radius: 1.0e-5, frequency: 2, revolutions: 1}"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("ff")
    out = {}
    for ext in ("csv", "npy", "mat"):
        out[ext] = d / f"u.{ext}"
        assert main(["feedforward", "--trajectory", SPEC, "--stages", "creep,hysteresis", "--out", str(out[ext]),
                     "--json", str(d / f"{ext}.json")]) == 0
    out["json"] = json.loads((d / "npy.json").read_text())
    return out


def test_formats_agree_and_csv_columns_are_named(files):
    u = np.load(files["npy"])
    rows = np.genfromtxt(files["csv"], delimiter=",", names=True)
    assert rows.dtype.names == ("t", "u_x", "u_y")
    np.testing.assert_array_equal(np.column_stack([rows["u_x"], rows["u_y"]]), u)
    m = scipy.io.loadmat(str(files["mat"]))
    np.testing.assert_array_equal(m["u"], u)
    assert float(m["sample_rate"].squeeze()) == 20000.0
    np.testing.assert_allclose(rows["t"], np.arange(u.shape[0]) / 20000.0, rtol=0, atol=1e-15)


def test_the_nominal_plant_driven_by_the_file_tracks_the_reference(files):
    """Independent check: the plant model (not the compensator code) fed with the file's voltages; hysteresis and
    creep inverses are exact on the nominal model, so the error left is the linear dynamics' (G_L(0) ≈ I)."""
    cfg = load_config()
    u = np.load(files["npy"])
    ref = from_dict({"type": "circle", "radius": 1e-5, "frequency": 2, "revolutions": 1}).block(0, u.shape[0], 2e4)
    y = Plant(cfg).process(u)
    err = np.sqrt(np.mean((y - ref) ** 2))
    y0 = Plant(cfg).process(ref / np.diag(np.array(cfg.hysteresis.Dp)))   # uncompensated: a plain gain
    err0 = np.sqrt(np.mean((y0 - ref) ** 2))
    assert err < 0.25 * err0, (err, err0)
    assert files["json"]["stages"] == ["creep", "hysteresis"] and files["json"]["samples"] == u.shape[0]


def test_limits_hold_on_an_impossible_trajectory(tmp_path):
    out = tmp_path / "u.npy"
    assert main(["feedforward", "--trajectory", "{type: circle, radius: 1.0e-3, frequency: 200, revolutions: 1}",
                 "--stages", "hysteresis", "--out", str(out), "--json", str(tmp_path / "s.json"), "--clip"]) == 0
    u = np.load(out)
    cfg = load_config()
    assert np.abs(u).max() <= cfg.limits.voltage
    assert np.abs(np.diff(np.vstack([[0.0, 0.0], u]), axis=0)).max() <= cfg.limits.slew / cfg.sample_rate + 1e-9
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["compensator_limited_samples"] + s["saturated_samples"] > 0
    assert np.isclose(np.abs(u).max(), cfg.limits.voltage)


@pytest.mark.parametrize("args, msg", [
    (["--trajectory", SPEC, "--out", "u.txt"], "--out"),
    (["--trajectory", "missing.yaml", "--out", "u.npy"], "no such file"),
    (["--trajectory", "[1, 2", "--out", "u.npy"], "--trajectory"),
    (["--trajectory", "{type: circle, radius: 1.0e-5, frequency: 1, revolutions: inf}", "--out", "u.npy"],
     "endless"),
    (["--trajectory", "{type: squircle}", "--out", "u.npy"], "trajectory.type"),
    (["--trajectory", SPEC, "--stages", "creep,foo", "--out", "u.npy"], "--stages"),
])
def test_bad_input_one_line(args, msg, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["feedforward", *args]) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
