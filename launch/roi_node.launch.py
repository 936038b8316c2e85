"""Start the live ROI node with its parameters file, as ROS users start nodes.

    ros2 launch roi_node roi_node.launch.py rig:=/path/to/my_rig.yaml
    ros2 launch roi_node roi_node.launch.py rig:=rig_tiago_head.yaml params_file:=/path/to/params.yaml namespace:=left_cell

Arguments: `rig`, the rig config (a path, or the name of a bundled rig; default rig_demo_bimanual.yaml), which
overrides the parameters file's `config`; `params_file` (default: the package's config/roi_node.params.yaml);
`namespace` (default: none; topic names are relative, so the node's topics move with it). Needs launch and
launch_ros, which a system ROS 2 install has (they are not on PyPI).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare("roi_node"), "config", "roi_node.params.yaml"])
    return LaunchDescription([
        DeclareLaunchArgument("rig", default_value="rig_demo_bimanual.yaml",
                              description="rig config: a path, or the name of a bundled rig"),
        DeclareLaunchArgument("params_file", default_value=default_params, description="the node's parameters file"),
        DeclareLaunchArgument("namespace", default_value="", description="the node's namespace"),
        Node(
            package="roi_node",
            executable="roi_node",
            name="roi_node",
            namespace=LaunchConfiguration("namespace"),
            parameters=[LaunchConfiguration("params_file"), {"config": LaunchConfiguration("rig")}],
            output="screen",
            emulate_tty=True,
        ),
    ])
