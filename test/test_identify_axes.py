"""``piezo-ff identify`` on single-axis and single-stage (hysteresis-only) records, and refused stage tags."""
import json
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.cli import main as cli_main
from piezo_ff_ros.core.config import load_config

CONFIG = Path(__file__).resolve().parents[1] / "config"


def _csv(path, t, u, y):
    rows = np.column_stack([t, u, y])
    np.savetxt(path, rows, delimiter=",", header="t,u_x,x", comments="")
    return path


def _dbo_cycles():
    from piezo_ff_ros.bench.datasets import load_dbo

    try:
        d = load_dbo()
    except FileNotFoundError:
        pytest.skip("the shared micromanipulator data set is not on this machine")
    return d


def test_a_hysteresis_only_single_axis_record_is_identified(tmp_path, capsys):
    """The measured micromanipulator loops (1 axis, 200 Hz, µm sensor with an offset, one sample of lag) identified
    as a Bouc-Wen alone, with a single-axis base; creep and dynamics kept from the base and switched off."""
    d = _dbo_cycles()
    r = d.model
    k0 = d.segments["model_cycle_start"]
    fit = _csv(tmp_path / "loops_fit.csv", r.t[k0:k0 + 2000] - r.t[k0], r.u[k0:k0 + 2000], r.y[k0:k0 + 2000])
    val = _csv(tmp_path / "loops_val.csv", r.t[k0 + 2000:k0 + 3000] - r.t[k0 + 2000], r.u[k0 + 2000:k0 + 3000],
               r.y[k0 + 2000:k0 + 3000])
    out = tmp_path / "stack.yaml"
    code = cli_main(["identify", "--data", str(fit), str(val), "--stage", "hysteresis", "hysteresis:validation",
                     "--base", str(CONFIG / "single_stack.yaml"), "--fit-offset", "--delay", "1", "--quiet",
                     "--out", str(out), "--json", str(tmp_path / "r.json")])
    assert code == 0, capsys.readouterr().err
    rep = json.loads((tmp_path / "r.json").read_text())
    assert set(rep["fit_percent"]) == {"hysteresis"} and set(rep["not_identified"]) == {"creep", "dynamics"}
    assert rep["fit_percent"]["hysteresis"]["x"] > 80   # held-out loops of a real actuator
    cfg = load_config(out)
    assert cfg.axes == ("x",) and cfg.cascade.hysteresis and not cfg.cascade.creep and not cfg.cascade.vibration
    assert "dynamics kept from single_stack" in cfg.source and cfg.creep.Cr[0, 0].is_zero()


def test_runs_of_other_axes_than_the_base_are_refused_in_one_line(tmp_path, capsys):
    t = np.arange(4000) / 2000.0
    u = 100 * np.sin(2 * np.pi * t)
    f = _csv(tmp_path / "hyst.csv", t, u, 1.6e-7 * u)
    code = cli_main(["identify", "--data", str(f), "--stage", "hysteresis", "--quiet", "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "['x', 'y']" in err[0] and "['x']" in err[0] and "--base" in err[0]


@pytest.mark.parametrize("tag", ["hysteresis:valdiation", "hyst", "plant:fit:extra"])
def test_an_unknown_stage_or_role_is_refused_in_one_line(tmp_path, capsys, tag):
    t = np.arange(4000) / 2000.0
    u = 100 * np.sin(2 * np.pi * t)
    f = _csv(tmp_path / "run.csv", t, u, 1.6e-7 * u)
    code = cli_main(["identify", "--data", str(f), "--stage", tag, "--quiet", "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and tag in err[0], err
    assert not (tmp_path / "c.yaml").exists()


def test_a_run_tagged_with_an_unknown_role_is_refused():
    from piezo_ff_ros.core.identification.pipeline import split_runs
    from piezo_ff_ros.core.recording.run import RunData

    t = np.arange(10) / 100.0
    r = RunData(t=t, u=np.zeros((10, 1)), y=np.zeros((10, 1)), axes=("x",), meta={"stage": "creep", "role": "test"})
    with pytest.raises(ValueError, match="role"):
        split_runs([r])


def test_npy_realizations_layout(tmp_path):
    """The periodic-record layout ``u_<tag>.npy``/``y_<tag>.npy`` ``[samples, channels, realizations, periods]``:
    one run per realization, its periods end to end; what cannot be read is refused in one line."""
    from piezo_ff_ros.core.recording.importers import load_npy_realizations

    rng = np.random.default_rng(1)
    u = 0.1 * rng.standard_normal((64, 3, 2, 2))
    y = 1e-6 * rng.standard_normal((64, 3, 2, 2))
    np.save(tmp_path / "u_lvl.npy", u)
    np.save(tmp_path / "y_lvl.npy", y)
    runs = load_npy_realizations(tmp_path / "y_lvl.npy", sample_rate=6400.0)
    assert len(runs) == 2 and runs[1].axes == ("x", "y", "z") and runs[1].sample_rate == pytest.approx(6400.0)
    assert np.array_equal(runs[1].u, np.concatenate([u[:, :, 1, 0], u[:, :, 1, 1]]))
    assert np.array_equal(runs[1].y[64:], y[:, :, 1, 1])
    with pytest.raises(ValueError, match="sample rate"):
        load_npy_realizations(tmp_path / "u_lvl.npy")
    np.save(tmp_path / "u_solo.npy", u)
    with pytest.raises(ValueError, match="y_solo.npy"):
        load_npy_realizations(tmp_path / "u_solo.npy", sample_rate=6400.0)
    np.save(tmp_path / "u_bad.npy", u)
    np.save(tmp_path / "y_bad.npy", y[:, :2])
    with pytest.raises(ValueError, match="differ in shape"):
        load_npy_realizations(tmp_path / "u_bad.npy", sample_rate=6400.0)
    np.save(tmp_path / "u_um.npy", u)
    np.save(tmp_path / "y_um.npy", y * 1e6)   # µm stored as m
    with pytest.raises(ValueError, match="not plausible in metres"):
        load_npy_realizations(tmp_path / "u_um.npy", sample_rate=6400.0)


def test_input_gain_states_the_parameters_per_actuator_volt(tmp_path, capsys):
    """The same loops recorded at an amplifier's input (×1/10): with --input-gain 10 the identified Dp is the
    actuator's again and the held-out fit the same."""
    from piezo_ff_ros.core.config import load_config as load
    from piezo_ff_ros.core.models.bouc_wen import BoucWenModel

    stack = load(CONFIG / "single_stack.yaml")
    t = np.arange(8000) / 2000.0
    u = 150 * np.sin(2 * np.pi * 1.0 * t)[:, None]
    y = BoucWenModel(stack.hysteresis).process(u)
    fits = {}
    for gain, scale in ((1.0, 1.0), (10.0, 0.1)):
        fit = _csv(tmp_path / f"hyst_{gain:g}.csv", t[:4000], scale * u[:4000], y[:4000])
        val = _csv(tmp_path / f"hyst_val_{gain:g}.csv", t[:4000], scale * u[4000:], y[4000:])
        out = tmp_path / f"c{gain:g}.yaml"
        assert cli_main(["identify", "--data", str(fit), str(val), "--stage", "hysteresis", "hysteresis:validation",
                         "--base", str(CONFIG / "single_stack.yaml"), "--input-gain", str(gain), "--quiet",
                         "--out", str(out), "--json", str(tmp_path / f"r{gain:g}.json")]) == 0, capsys.readouterr()
        fits[gain] = json.loads((tmp_path / f"r{gain:g}.json").read_text())["fit_percent"]["hysteresis"]["x"]
        assert load(out).hysteresis.Dp[0][0] == pytest.approx(stack.hysteresis.Dp[0][0], rel=0.02)
    assert fits[10.0] == pytest.approx(fits[1.0], abs=0.5) and fits[1.0] > 95
