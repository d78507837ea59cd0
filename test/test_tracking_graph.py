"""The preview stage as a runtime parameter of the compensator node, through the recorded node graph."""
import os

import numpy as np

import pytest

from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros.core.tracking.front import front_settings


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

