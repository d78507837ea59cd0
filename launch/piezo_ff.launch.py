"""ros2 launch file for full ROS 2 installs (``ros2 launch piezo_ff_ros piezo_ff.launch.py``).

Not runnable from the pip wheels (launch/launch_ros are not published there): the project's own demo and tests use
``piezo_ff_ros/ros/launcher.py``, which steps the driver the same way.  Arguments: ``mode`` (realtime|lockstep),
``output`` (MCAP file), ``params_file`` (compensator parameters, default the packaged
config/compensator.params.yaml), ``trajectory`` (JSON/YAML spec), ``namespace``, ``activate`` (true: the managed
driver is configured, then activated once configured; false: it waits unconfigured for
``ros2 lifecycle set /driver configure`` / ``activate``).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.parameter_descriptions import ParameterValue
from lifecycle_msgs.msg import Transition


def generate_launch_description():
    share = get_package_share_directory("piezo_ff_ros")
    args = [
        DeclareLaunchArgument("mode", default_value="realtime", description="realtime | lockstep"),
        DeclareLaunchArgument("output", default_value="run.mcap", description="MCAP file written by the recorder"),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "compensator.params.yaml")),
        DeclareLaunchArgument("trajectory", default_value='{"type": "circle", "radius": 2.0e-5, "frequency": 1.0, '
                                                          '"revolutions": 5}'),
        DeclareLaunchArgument("namespace", default_value=""),
        DeclareLaunchArgument("activate", default_value="true",
                              description="configure and activate the managed driver (false: step it by hand)"),
    ]
    ns = LaunchConfiguration("namespace")
    # the driver is a managed node: started unconfigured, stepped here (configure → inactive → activate)
    driver = LifecycleNode(package="piezo_ff_ros", executable="driver", name="driver", namespace=ns, output="screen",
                           parameters=[{"autostart": False}])
    configure = EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(driver),
                                            transition_id=Transition.TRANSITION_CONFIGURE),
                          condition=IfCondition(LaunchConfiguration("activate")))
    activate_once_configured = RegisterEventHandler(OnStateTransition(
        target_lifecycle_node=driver, start_state="configuring", goal_state="inactive",
        entities=[EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(driver),
                                              transition_id=Transition.TRANSITION_ACTIVATE))]),
        condition=IfCondition(LaunchConfiguration("activate")))
    nodes = [
        Node(package="piezo_ff_ros", executable="recorder", namespace=ns, output="screen",
             parameters=[{"output": LaunchConfiguration("output")}]),
        driver,
        Node(package="piezo_ff_ros", executable="compensator", namespace=ns, output="screen",
             parameters=[LaunchConfiguration("params_file")]),
        Node(package="piezo_ff_ros", executable="plotter", namespace=ns, output="screen"),
        Node(package="piezo_ff_ros", executable="trajectory", namespace=ns, output="screen",
             parameters=[{"mode": LaunchConfiguration("mode"), "autostart": True, "min_subscribers": 2,
                          "trajectory": ParameterValue(LaunchConfiguration("trajectory"), value_type=str)}]),
    ]
    return LaunchDescription(args + [activate_once_configured] + nodes + [configure])
