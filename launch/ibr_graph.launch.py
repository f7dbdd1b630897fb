"""Launch the ibr_ros node graph on a real ROS 2 install (``ros2 launch ibr_ros ibr_graph.launch.py``).

Arguments: ``bag`` (path; empty = no bag_player, feed live topics), ``rate`` (replay rate),
``refiners`` (sharded depth_refiner processes), ``config_dir`` (parameter files, default: the
installed share/ibr_ros/config). ``ibr graph`` starts the same processes where ``ros2 launch``
is missing.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context, *args, **kwargs):
    config = LaunchConfiguration('config_dir').perform(context)
    bag = LaunchConfiguration('bag').perform(context)
    rate = float(LaunchConfiguration('rate').perform(context))
    refiners = int(LaunchConfiguration('refiners').perform(context))

    def params(name, extra=None):
        return [os.path.join(config, f'{name}.yaml'), *([extra] if extra else [])]

    actions = []
    if bag:
        actions.append(
            Node(
                package='ibr_ros',
                executable='bag_player',
                name='bag_player',
                parameters=params('bag_player', {'bag': bag, 'rate': rate}),
                output='screen',
            )
        )
    actions.append(
        Node(package='ibr_ros', executable='frame_subsampler', name='frame_subsampler',
             parameters=params('frame_subsampler'), output='screen')
    )  # fmt: skip
    for i in range(refiners):
        shard = {'worker_index': i, 'num_workers': refiners} if refiners > 1 else None
        actions.append(
            Node(package='ibr_ros', executable='depth_refiner',
                 name=f'depth_refiner_{i}' if refiners > 1 else 'depth_refiner',
                 parameters=params('depth_refiner', shard), output='screen')
        )  # fmt: skip
    actions.append(
        Node(package='ibr_ros', executable='view_renderer', name='view_renderer',
             parameters=params('view_renderer'), output='screen')
    )  # fmt: skip
    return actions


def generate_launch_description():
    share = get_package_share_directory('ibr_ros')
    return LaunchDescription(
        [
            DeclareLaunchArgument('bag', default_value='', description='bag to replay (empty: live topics)'),
            DeclareLaunchArgument('rate', default_value='1.0', description='replay rate'),
            DeclareLaunchArgument(
                'refiners', default_value='1', description='sharded depth_refiner processes'
            ),
            DeclareLaunchArgument(
                'config_dir', default_value=os.path.join(share, 'config'), description='parameter files'
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
