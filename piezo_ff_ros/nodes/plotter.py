"""Plot node: the block streams thinned to a plot rate as messages every plotting tool plots without extensions.

Subscribes ``reference``, ``voltage_applied`` and ``displacement`` (PointCloud2 blocks, 20 kHz) and publishes, at
``rate`` Hz on one grid of instants shared by all of them (:class:`piezo_ff_ros.core.plot_decimator.PlotDecimator`),
``geometry_msgs/PointStamped`` messages stamped with the sample's own time (axis i of the config → ``point.x``,
``point.y``, ``point.z``; unused fields 0; SI units):

- ``plot_reference`` [m] — what the stage was asked to do;
- ``plot_voltage`` [V] — what the driver applied (``voltage_applied``: holds, clamps and ramps included);
- ``plot_displacement`` [m] — what the sensor measured;
- ``plot_error`` [m] — reference − displacement at the same instant (the tracking error).

Foxglove plots them as ``/plot_reference.point.x``; PlotJuggler as ``/plot_reference/point/x``.  The recorder records
them; ``share/piezo_ff_ros/foxglove/piezo_ff.layout.json`` is a Foxglove layout showing them.

Parameters: ``rate`` [Hz] (default 200; at most the sample rate), ``config_file``/``variant`` (axes, sample rate).
"""
from __future__ import annotations

import sys
from typing import Any

import numpy as np

from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from ..core.config import ConfigError, load_config
from ..core.plot_decimator import PlotDecimator
from .common import BLOCK_QOS, BlockFormatError, run_node, stamp_to_ns, unpack_block

#: input block topic → decimator stream
INPUTS = {"reference": "reference", "voltage_applied": "voltage", "displacement": "displacement"}
#: decimator output → published topic
OUTPUTS = {"reference": "plot_reference", "voltage": "plot_voltage", "displacement": "plot_displacement",
           "error": "plot_error"}


class PlotterNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("plotter", **kwargs)

        def param(name: str, default: Any, description: str) -> Any:
            return self.declare_parameter(name, default, ParameterDescriptor(description=description,
                                                                              read_only=True)).value

        cfg_file = param("config_file", "", "configuration YAML ('' = the paper's): axes and sample rate")
        variant = param("variant", "", "config variant")
        rate = param("rate", 200.0, "plot samples per second per topic [Hz]")
        cfg = load_config(cfg_file or None, variant or None)
        self.axes = list(cfg.axes)
        if len(self.axes) > 3:
            raise ConfigError("axes", f"{len(self.axes)} axes: PointStamped carries at most 3 (x, y, z)")
        try:
            self.dec = PlotDecimator(float(cfg.sample_rate), rate)
        except ValueError as exc:
            raise ConfigError("rate", str(exc).split(": ", 1)[-1]) from None
        self.pubs = {s: self.create_publisher(PointStamped, t, 50) for s, t in OUTPUTS.items()}
        for topic, stream in INPUTS.items():
            self.create_subscription(PointCloud2, topic, lambda m, s=stream: self.on_block(s, m), BLOCK_QOS)
        self.bad_blocks = 0
        fields = "/".join("xyz"[:len(self.axes)])
        self.get_logger().info(f"plotter ready: {sorted(OUTPUTS.values())} at "
                               f"{self.dec.sample_rate / self.dec.every:g} Hz (one sample in {self.dec.every}), axes "
                               f"{self.axes} → point.{fields}")

    def on_block(self, stream: str, msg: PointCloud2) -> None:
        try:
            block = unpack_block(msg, self.axes)
        except BlockFormatError as exc:
            self.bad_blocks += 1
            if self.bad_blocks == 1:
                self.get_logger().error(f"{stream} block not plotted: {exc}")
            return
        for topic, stamp, x in self.dec.feed(stream, stamp_to_ns(msg.header.stamp), block):
            self.pubs[topic].publish(_point(stamp, x))


def _point(stamp_ns: int, x: np.ndarray) -> PointStamped:
    m = PointStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000
    m.header.frame_id = "piezo"
    v = [float(a) for a in x] + [0.0] * (3 - len(x))
    m.point.x, m.point.y, m.point.z = v[0], v[1], v[2]
    return m


def main(argv: list[str] | None = None) -> int:
    return run_node("plotter", PlotterNode, None, argv)


if __name__ == "__main__":
    sys.exit(main())
