"""The preview stage as a runtime parameter of the compensator node, through the recorded node graph."""
import os

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
