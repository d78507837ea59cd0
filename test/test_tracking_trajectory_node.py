"""Trajectory node parsing: the workspace check and table files."""
import numpy as np
import pytest

from piezo_ff_ros.core.config import ConfigError

trajectory_node = pytest.importorskip("piezo_ff_ros.nodes.trajectory")


def test_metre_radius_refused_naming_the_field():
    with pytest.raises(ConfigError, match=r"^trajectory\.radius: reaches 1 on axis x, outside the workspace ±0\.0001"):
        trajectory_node.parse_trajectory('{type: circle, radius: 1.0}', workspace_m=1e-4)
    assert trajectory_node.parse_trajectory('{type: circle, radius: 20, unit: um}', workspace_m=1e-4).radius == pytest.approx(20e-6)


def test_table_file_is_played_sample_exactly(tmp_path):
    vals = np.random.default_rng(2).normal(0, 1e-6, (333, 2))
    np.save(tmp_path / "path.npy", vals)
    traj = trajectory_node.parse_trajectory(file=str(tmp_path / "path.npy"), sample_rate=20000.0, workspace_m=1e-4)
    np.testing.assert_array_equal(traj.block(0, 333, 20000.0), vals)
    np.save(tmp_path / "far.npy", vals * 1e3)
    with pytest.raises(ConfigError, match=r"^trajectory\.values: reaches"):
        trajectory_node.parse_trajectory(file=str(tmp_path / "far.npy"), workspace_m=1e-4)
    (tmp_path / "bad.csv").write_text("x,q\n1,2\n")
    with pytest.raises(ConfigError, match=r"^trajectory_file\.file: .*no column named 'y'"):
        trajectory_node.parse_trajectory(file=str(tmp_path / "bad.csv"))


def test_voltage_segments_are_checked_in_volts():
    spec = ('{type: sequence, segments: [{name: s0, meta: {stage: hysteresis}, trajectory: {type: sine, amplitude: 200,'
            ' frequency: 0.1, duration: 10}}]}')
    trajectory_node.parse_trajectory(spec, workspace_m=1e-4, voltage_limit=200.0)
    with pytest.raises(ConfigError, match=r"segments\[0\]\.trajectory\.amplitude"):
        trajectory_node.parse_trajectory(spec, workspace_m=1e-4, voltage_limit=150.0)
