# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Launch the ibr_ros node graph on a real ROS 2 install (``ros2 launch ibr_ros ibr_graph.launch.py``).

Arguments: ``bag`` (path; empty = no bag_player, feed live topics), ``rate`` (replay rate, 0 = as
fast as possible: nothing is lost, the player waits for the frame_subsampler), ``refiners`` (sharded
depth_refiner processes), ``image_transport`` (``auto`` / ``raw`` / ``compressed``), ``pose_source``
(``auto`` / ``topic`` / ``none``), ``scene_depth_m`` (0 = estimate), ``max_neighbours`` (MVS
source views), ``config_dir`` (parameter files, default: the installed share/ibr_ros/config),
``viewer`` (``true``: also the web_viewer, a browser page to fly through the model). The
bag_player starts playing once the frame_subsampler subscribes the bag's camera topics. ``ibr graph``
starts the same processes where ``ros2 launch`` is missing.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: name -> (default, description) of the launch arguments besides bag and config_dir.
ARGUMENTS = {
    'rate': ('1.0', 'replay rate; 0 = as fast as possible (lossless)'),
    'refiners': ('1', 'sharded depth_refiner processes'),
    'image_transport': ('auto', "frame_subsampler camera images: 'auto', 'raw' or 'compressed'"),
    'pose_source': ('auto', "frame_subsampler poses: 'auto', 'topic' or 'none' (SfM)"),
    'scene_depth_m': ('0.0', 'typical scene depth (m) for keyframe spacing and MVS; 0 = estimate'),
    'max_neighbours': ('4', 'MVS source views per keyframe'),
    'viewer': ('false', 'also start the web_viewer (fly through the model in a browser)'),
}


def _nodes(context, *args, **kwargs):
    from ibr_ros.graph import wait_for_subsampler

    arg = {name: LaunchConfiguration(name).perform(context) for name in ('config_dir', 'bag', *ARGUMENTS)}
    config, bag, refiners = arg['config_dir'], arg['bag'], int(arg['refiners'])
    scene_depth = float(arg['scene_depth_m'])

    def params(name, extra=None):
        return [os.path.join(config, f'{name}.yaml'), *([extra] if extra else [])]

    actions = []
    if bag:
        player = {
            'bag': bag,
            'rate': float(arg['rate']),
            **wait_for_subsampler(bag, arg['image_transport'], arg['pose_source']),
        }
        actions.append(
            Node(package='ibr_ros', executable='bag_player', name='bag_player',
                 parameters=params('bag_player', player), output='screen')
        )  # fmt: skip
    subsampler = {
        'image_transport': arg['image_transport'],
        'pose_source': arg['pose_source'],
        'scene_depth_m': scene_depth,
    }
    actions.append(
        Node(package='ibr_ros', executable='frame_subsampler', name='frame_subsampler',
             parameters=params('frame_subsampler', subsampler), output='screen')
    )  # fmt: skip
    for i in range(refiners):
        refiner = {'max_neighbours': int(arg['max_neighbours']), 'scene_depth_m': scene_depth}
        if refiners > 1:
            refiner.update(worker_index=i, num_workers=refiners)
        actions.append(
            Node(package='ibr_ros', executable='depth_refiner',
                 name=f'depth_refiner_{i}' if refiners > 1 else 'depth_refiner',
                 parameters=params('depth_refiner', refiner), output='screen')
        )  # fmt: skip
    actions.append(
        Node(package='ibr_ros', executable='view_renderer', name='view_renderer',
             parameters=params('view_renderer'), output='screen')
    )  # fmt: skip
    actions.append(  # the model for RViz / Foxglove (config/ibr.rviz, config/foxglove_layout.json)
        Node(package='ibr_ros', executable='scene_viz', name='scene_viz',
             parameters=params('scene_viz'), output='screen')
    )  # fmt: skip
    if arg['viewer'].lower() in ('true', '1'):
        actions.append(
            Node(package='ibr_ros', executable='web_viewer', name='web_viewer',
                 parameters=params('web_viewer'), output='screen')
        )  # fmt: skip
    return actions


def generate_launch_description():
    share = get_package_share_directory('ibr_ros')
    return LaunchDescription(
        [
            DeclareLaunchArgument('bag', default_value='', description='bag to replay (empty: live topics)'),
            *(DeclareLaunchArgument(n, default_value=d, description=t) for n, (d, t) in ARGUMENTS.items()),
            DeclareLaunchArgument(
                'config_dir', default_value=os.path.join(share, 'config'), description='parameter files'
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
