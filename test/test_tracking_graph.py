"""The preview stage as a runtime parameter of the compensator node, through the recorded node graph."""
import os

import numpy as np

import pytest

from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros.core.tracking.front import front_settings
from piezo_ff_ros.ros.graph_session import GraphClient


@pytest.mark.parametrize("values,field", [({"preview.enabled": "yes"}, "preview.enabled"),
                                          ({"preview.horizon_s": -1.0}, "preview.horizon_s"),
                                          ({"learning.file": 3}, "learning.file")])
def test_front_parameters_refused_naming_the_parameter(values, field):
    with pytest.raises(ConfigError, match=rf"^{field}"):
        front_settings(values)


def test_preview_through_the_graph_recorded_and_replayed(tmp_path):
    pytest.importorskip("rclpy")
    from piezo_ff_ros.cli.track_graph import run_graph_case

    row = run_graph_case(tmp_path, preview=True, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    assert row["graph"] and row["method"] == "preview" and row["preview_s"] == pytest.approx(0.02)
    assert row["rms_error_um"] < 0.05          # the cascade alone: ≈ 10 µm on this circle
    assert row["peak_voltage_v"] <= 200.0


def test_learning_through_the_graph_beats_the_cascade_and_the_preview(tmp_path):
    """Learned through the graph from the measured displacement (asymmetric truth in the driver, printed model in
    the compensator), stored to a file and played by the compensator node (learning.file): the error falls far
    below the cascade's and the preview's, measured on the same recorded, replayed graph."""
    pytest.importorskip("rclpy")
    from piezo_ff_ros.cli.track_graph import run_graph_case, run_graph_learning
    from piezo_ff_ros.core.tracking.ilc import load_correction

    dom = int(os.environ["ROS_DOMAIN_ID"])
    cascade = run_graph_case(tmp_path / "cascade", preview=False, truth="asymmetric", domain_id=dom)
    preview, learning = run_graph_learning(tmp_path / "learning", "asymmetric", iterations=1, domain_id=dom)
    assert cascade["graph"] and preview["graph"] and learning["graph"] and learning["method"] == "learning"
    assert cascade["rms_error_um"] > 5.0                          # W_r's lag: ≈ 10 µm on this circle
    assert 0.2 < preview["rms_error_um"] < 2.0                    # the model mismatch the preview cannot see
    assert learning["rms_error_um"] < preview["rms_error_um"] / 5  # ≈ 0.026 µm after one update
    assert learning["rms_error_um"] < cascade["rms_error_um"] / 5
    assert learning["peak_voltage_v"] <= 200.0
    corr, info = load_correction(learning["correction_file"], 20000.0)
    assert info["meta"]["source"] == "graph" and corr.shape == (10000, 2) and np.any(corr)


class _FakeGraph:
    """GraphLauncher stand-in: every node alive."""

    procs: dict = {}

    def check_alive(self):
        pass


class _Readers:
    """The client node's view of the graph: readers per block topic."""

    def __init__(self, readers):
        self.readers = readers

    def count_subscribers(self, topic):
        return self.readers[topic]


class _SteppedClient(GraphClient):
    """The real GraphClient's waiting logic without ROS: at each spin the recorder's status and the nodes'
    diagnostics move one step on (as DDS matches endpoints, one by one, on a loaded machine)."""

    def __init__(self, steps, readers):   # no rclpy: the transport is the steps
        self.recorder, self.diag, self.states, self.start = {}, {}, [{"state": "idle"}], "/trajectory/start"
        self.node = _Readers(readers)
        self._steps = list(steps)
        self.started_with = None

    def spin_until(self, cond, timeout, what):
        while not cond():
            if not self._steps:
                raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")
            self.recorder, self.diag = self._steps.pop(0)

    def trigger(self, client):
        assert client == self.start
        self.started_with = (dict(self.recorder.get("publishers", {})), {k: dict(v) for k, v in self.diag.items()})
        self.states += [{"state": "playing"}, {"state": "finished", "unanswered_blocks": 0}]


_ALL_RECORDED = {"publishers": {"/reference": 1, "/voltage": 1, "/displacement": 1}}
_READERS = {"/voltage": 2, "/voltage_applied": 2, "/displacement": 2}   # next node + recorder


def _diag(voltage, applied, displacement):
    return {"compensator": {"matched.voltage": str(voltage)},
            "driver": {"matched.voltage_applied": str(applied), "matched.displacement": str(displacement),
                       "has_sensor": "True"}}


def test_the_graph_case_starts_only_once_the_recorder_and_every_block_writer_matched():
    """CI lost the first blocks of a graph case (and a commissioning run lost its first run, sine_x, on a loaded
    machine): the recorder's *readers* had matched the writers, but a *writer* had not matched the recorder yet, and
    a volatile writer sends nothing to a reader it has not matched.  The start waits until the recorder reports
    every block publisher and every writer reports every reader of its topic matched."""
    from piezo_ff_ros.cli.track_graph import _play_when_recorded

    steps = [({"publishers": {"/reference": 1}}, {}),
             (_ALL_RECORDED, {}),                                  # writers not reporting yet
             (_ALL_RECORDED, _diag(2, 2, 1)),                      # the driver's displacement writer: 1 of 2
             (_ALL_RECORDED, _diag(2, 2, 2))]
    client = _SteppedClient(steps, _READERS)
    _play_when_recorded(_FakeGraph(), client, timeout=1.0)
    assert client.started_with == (_ALL_RECORDED["publishers"], _diag(2, 2, 2))

    never = _SteppedClient([(_ALL_RECORDED, _diag(2, 1, 2))], _READERS)  # voltage_applied never matches both
    with pytest.raises(RuntimeError, match=r"block writers to match.*driver\.voltage_applied.*matched 1 of 2"):
        _play_when_recorded(_FakeGraph(), never, timeout=1.0)
    assert never.started_with is None

    no_sensor = _diag(2, 2, 0)
    no_sensor["driver"]["has_sensor"] = "False"   # a driver without a sensor writes no displacement
    client = _SteppedClient([(_ALL_RECORDED, no_sensor)], _READERS)
    _play_when_recorded(_FakeGraph(), client, timeout=1.0)
    assert client.started_with is not None


def test_the_graph_case_is_of_the_configured_stage():
    """The reference the graph plays is built on the config's axes: a 20 µm, 10 Hz sine on a single stack, the
    circle in the x-y plane (z at rest) on the XYZ tube, the paper's circle (bit for bit) on the paper's stage."""
    from pathlib import Path

    from piezo_ff_ros.cli.track_graph import graph_case
    from piezo_ff_ros.core.config import load_config

    cfgs = Path(__file__).resolve().parents[1] / "config"
    case1, r1, m1 = graph_case(load_config(cfgs / "single_stack.yaml"))
    assert case1.trajectory == "sine" and r1.shape[1] == 1 and m1.any()
    assert np.max(np.abs(r1)) == pytest.approx(20e-6)
    case3, r3, _ = graph_case(load_config(cfgs / "xyz_tube.yaml"))
    assert case3.trajectory == "circle" and r3.shape[1] == 3 and not np.any(r3[:, 2])
    case2, r2, _ = graph_case(load_config(None, None))
    _, r_paper, _ = graph_case()
    assert case2.trajectory == "circle" and np.array_equal(r2, r_paper)


def test_a_single_axis_stage_through_the_graph(tmp_path):
    """``track --graph`` with a 1-axis ``--config``: driver, compensator and recorder run that stage (not the
    paper's), and the preview tracks its 10 Hz sine as closely as the paper's circle."""
    pytest.importorskip("rclpy")
    from pathlib import Path

    from piezo_ff_ros.cli.track_graph import run_graph_case

    cfg_file = str(Path(__file__).resolve().parents[1] / "config" / "single_stack.yaml")
    row = run_graph_case(tmp_path, preview=True, domain_id=int(os.environ["ROS_DOMAIN_ID"]), config_file=cfg_file)
    assert row["graph"] and row["trajectory"] == "sine" and row["axes"] == ["x"]
    assert row["rms_error_um"] < 0.05 and row["peak_voltage_v"] <= 200.0
