"""``piezo-ff feedforward`` refuses a trajectory the amplifier cannot follow (one line: which setting, how many
samples, by how much) and, with ``--clip``, writes it clipped with a loud count."""
import json

import numpy as np

from piezo_ff_ros.cli import main

MM_CIRCLE = "{type: circle, radius: 1.0e-3, frequency: 10, revolutions: 1}"


def test_a_trajectory_beyond_the_amplifier_is_refused_with_one_line(tmp_path, capsys):
    out = tmp_path / "u.npy"
    assert main(["feedforward", "--trajectory", MM_CIRCLE, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "cannot follow" in err and "exceed limits.voltage" in err and " by up to " in err and "--clip" in err, err
    assert not out.exists()


def test_clip_writes_the_clipped_voltages_and_counts_them_loudly(tmp_path, capsys):
    out, js = tmp_path / "u.npy", tmp_path / "s.json"
    assert main(["feedforward", "--trajectory", MM_CIRCLE, "--out", str(out), "--clip", "--json", str(js)]) == 0
    err = capsys.readouterr().err
    assert "CLIPPED" in err and "sample" in err
    s = json.loads(js.read_text())
    assert s["clipped"] is True
    assert s["beyond_voltage_samples"] + s["beyond_slew_samples"] + s["compensator_limited_samples"] > 1000
    u = np.load(out)
    assert np.abs(u).max() <= 200.0


def test_a_trajectory_within_the_limits_is_written_without_warning(tmp_path, capsys):
    out, js = tmp_path / "u.npy", tmp_path / "s.json"
    assert main(["feedforward", "--trajectory", "{type: circle, radius: 1.0e-5, frequency: 2, revolutions: 1}",
                 "--out", str(out), "--json", str(js)]) == 0
    assert "CLIPPED" not in capsys.readouterr().err
    assert json.loads(js.read_text())["clipped"] is False
