"""ros2 launch file for full ROS 2 installs (``ros2 launch piezo_ff_ros piezo_ff.launch.py``).

Not runnable from the pip wheels (launch/launch_ros are not published there): the project's own demo and tests use
``piezo_ff_ros/ros/launcher.py``.  Arguments: ``mode`` (realtime|lockstep), ``output`` (MCAP file), ``params_file``
(compensator parameters, default the packaged config/compensator.params.yaml), ``trajectory`` (JSON/YAML spec),
``namespace``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    share = get_package_share_directory("piezo_ff_ros")
    args = [
        DeclareLaunchArgument("mode", default_value="realtime", description="realtime | lockstep"),
        DeclareLaunchArgument("output", default_value="run.mcap", description="MCAP file written by the recorder"),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "compensator.params.yaml")),
        DeclareLaunchArgument("trajectory", default_value='{"type": "circle", "radius": 2.0e-5, "frequency": 1.0, '
                                                          '"revolutions": 5}'),
        DeclareLaunchArgument("namespace", default_value=""),
    ]
    ns = LaunchConfiguration("namespace")
    nodes = [
        Node(package="piezo_ff_ros", executable="recorder", namespace=ns, output="screen",
             parameters=[{"output": LaunchConfiguration("output")}]),
        Node(package="piezo_ff_ros", executable="driver", namespace=ns, output="screen"),
        Node(package="piezo_ff_ros", executable="compensator", namespace=ns, output="screen",
             parameters=[LaunchConfiguration("params_file")]),
        Node(package="piezo_ff_ros", executable="trajectory", namespace=ns, output="screen",
             parameters=[{"mode": LaunchConfiguration("mode"), "autostart": True, "min_subscribers": 2,
                          "trajectory": ParameterValue(LaunchConfiguration("trajectory"), value_type=str)}]),
    ]
    return LaunchDescription(args + nodes)
