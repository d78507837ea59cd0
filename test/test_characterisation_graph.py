"""Characterisation presets made graph-playable (core/characterisation_graph.py): a signal with no graph
type (the plant-validation multisine) travels as a .npy table and is played sample-exactly at the run's rate, after
the round trip through the spec the trajectory node parses (``to_dict`` → JSON → ``from_dict``)."""
import json

import numpy as np
import pytest

from piezo_ff_ros.core.characterisation import CharacterisationSettings, plant_validation_trajectory
from piezo_ff_ros.core.characterisation_graph import graph_playable
from piezo_ff_ros.core.trajectories import Table, from_dict


@pytest.mark.parametrize("fs", [20000.0, 5000.0])
def test_plant_validation_multisine_is_played_bit_exactly_as_a_table(tmp_path, fs):
    traj = plant_validation_trajectory(CharacterisationSettings())
    playable = graph_playable(traj, fs, tmp_path / "tables")
    node_side = from_dict(json.loads(json.dumps(playable.to_dict())))    # what the trajectory node builds
    assert node_side.n_samples(fs) == traj.n_samples(fs)
    _, want = traj.sample(fs)
    n = int(traj.n_samples(fs))
    got = np.vstack([node_side.block(k, min(997, n - k), fs) for k in range(0, n, 997)])   # any block split
    np.testing.assert_array_equal(got, want)
    tables = [t for _, t, _ in playable.segments_ if isinstance(t, Table)]
    assert tables and len(sorted((tmp_path / "tables").glob("*.npy"))) == len(tables)
    spec = json.dumps(playable.to_dict())
    assert len(spec) < 10_000, len(spec)     # the samples are in the file, not in the spec


def test_every_characterisation_run_plays_the_same_samples_through_the_graph_spec(tmp_path):
    """Every run of the commissioning plan (sines, circles, creep and dynamics steps with their ramps, the multisine
    table), through ``to_dict`` → JSON → ``from_dict``: the samples of the direct path (bit for bit; a circle, the
    quarter-period sine pair, within rounding)."""
    from piezo_ff_ros.core.commissioning import characterisation_plan

    fs = 20000.0
    plan = characterisation_plan(CharacterisationSettings(creep_duration=5.0), ("x", "y"))
    for run in (r for runs in plan.values() for r in runs):
        node_side = from_dict(json.loads(json.dumps(graph_playable(run.trajectory, fs, tmp_path).to_dict())))
        _, want = run.trajectory.sample(fs)
        assert node_side.n_samples(fs) == want.shape[0], run.name
        np.testing.assert_allclose(node_side.block(0, want.shape[0], fs), want, rtol=0,
                                   atol=1e-14 * np.max(np.abs(want)), err_msg=run.name)
