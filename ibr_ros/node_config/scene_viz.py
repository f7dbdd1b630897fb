# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The scene_viz's parameter table and the configuration built from it (also ``ibr process``'s
output bag: the same topics)."""

from __future__ import annotations

from dataclasses import dataclass

from ibr_ros.core.viz import CloudConfig, FrameNames, VizConfig
from ibr_ros.errors import UserError
from ibr_ros.node_config.frame_subsampler import POSE_TYPE_CHOICES
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Topic,
    Values,
)

__all__ = ['SCENE_VIZ', 'SceneVizConfig']

_LATCHED = 'reliable, transient local, the latest'
_MODEL = 'reliable, transient local'


@dataclass(frozen=True)
class SceneVizConfig:
    """What the scene_viz node (and ``ibr process``'s output bag) show: ``viz`` (points, frames,
    frustums), the novel view's optical frame ``novel_view_frame``, the pose stream's ``pose_type``
    and at most ``max_keyframes`` keyframes."""

    viz: VizConfig
    novel_view_frame: str
    pose_type: str
    max_keyframes: int


def _build(v: Values) -> SceneVizConfig:
    frames = FrameNames(v.text('camera_frame'), v.text('body_frame'), v.text('keyframe_frame_prefix'))
    for name in ('camera_frame', 'novel_view_frame'):
        if not v.text(name):
            raise UserError(f'parameter {name} must not be empty')
    try:
        cloud = CloudConfig(v.integer('point_stride'), v.number('min_confidence'), v.integer('max_points'))
    except ValueError as exc:
        raise UserError(f'bad scene_viz parameter: {exc}') from exc
    return SceneVizConfig(
        viz=VizConfig(cloud, frames, v.number('frustum_depth_m')),
        novel_view_frame=v.text('novel_view_frame'),
        pose_type=v.text('pose_type'),
        max_keyframes=v.integer('max_keyframes'),
    )


SCENE_VIZ: ParamTable[SceneVizConfig] = ParamTable(
    node='scene_viz',
    summary=(
        'The model for RViz and Foxglove: the camera pose stream and the keyframes as TF, keyframe '
        "poses, frustums (and the novel view's while navigating) and a coloured point cloud of each "
        'refined keyframe (confident pixels only), latched so that a viewer that joins late sees the '
        'whole reconstruction. `ibr process` writes the same topics into its output bag. TF needs '
        '`tf2_msgs` (a ROS 2 install has it; `make install` builds it into a pip venv): without it '
        '/tf and /tf_static are not published live (a warning at start-up), the rest is.'
    ),
    params=(
        Param(
            'camera_frame',
            'camera_optical_frame',
            'TF frame of the live camera (pose stream), REP-103 optical',
        ),
        Param(
            'body_frame',
            'camera_link',
            "REP-103 body frame (x forward, z up) between the world and camera_frame; '' = none",
        ),
        Param(
            'keyframe_frame_prefix',
            'keyframe_',
            'keyframe TF frames are <prefix><stamp in ns>_optical_frame (on /tf_static)',
        ),
        Param(
            'novel_view_frame',
            'novel_view_optical',
            "TF frame of the novel view's camera (the view_renderer's frame_id)",
        ),
        Param(
            'pose_type',
            'pose',
            "camera/pose message: 'pose' (PoseStamped) or 'odometry' (nav_msgs/Odometry)",
            choices=POSE_TYPE_CHOICES,
        ),
        Param('point_stride', 2, 'keyframe points: every n-th pixel in x and y', (1, 64)),
        Param(
            'min_confidence',
            0.5,
            'keyframe points: only pixels whose depth confidence is at least this (0.5: MVS-backed depth; '
            'below: filled from monocular depth)',
            (0.0, 1.0),
        ),
        Param(
            'max_points',
            50000,
            'keyframe points: at most this many per keyframe, 0 = no limit',
            (0, 10000000),
        ),
        Param(
            'frustum_depth_m',
            0.0,
            'frustums are cut at this depth (m); 0 = 0.15 x the median refined depth (1 m before any)',
            (0.0, 1e6),
        ),
        Param('max_keyframes', 1000, 'keyframes kept (the oldest are forgotten)', (1, 100000)),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    subscribes=(
        Topic(
            'camera/pose',
            'geometry_msgs/PoseStamped or nav_msgs/Odometry',
            'the pose stream (`pose_type`)',
            'best effort or reliable',
        ),
        Topic('keyframes/pose', 'geometry_msgs/PoseStamped', 'keyframe poses', _MODEL),
        Topic('keyframes/camera_info', 'sensor_msgs/CameraInfo', 'keyframe intrinsics', _MODEL),
        Topic('keyframes/image', 'sensor_msgs/Image', 'keyframe images (colours of the points)', _MODEL),
        Topic('keyframes/depth', 'sensor_msgs/Image', 'refined depth, 32FC1 m or 16UC1 mm', _MODEL),
        Topic('keyframes/depth/confidence', 'sensor_msgs/Image', 'optional depth confidence', _MODEL),
        Topic('novel_view/query', 'geometry_msgs/PoseStamped', 'novel-view poses', 'reliable'),
        Topic(
            'novel_view/camera_info', 'sensor_msgs/CameraInfo', "the answered view's intrinsics", 'reliable'
        ),
    ),
    publishes=(
        Topic(
            '/tf',
            'tf2_msgs/TFMessage',
            'world -> body_frame -> camera_frame per pose; world -> novel_view_frame per query',
            'reliable',
        ),
        Topic('/tf_static', 'tf2_msgs/TFMessage', 'world -> every keyframe optical frame', _LATCHED),
        Topic(
            'keyframes/poses', 'geometry_msgs/PoseArray', 'every keyframe pose, in the world frame', _LATCHED
        ),
        Topic(
            'keyframes/frustums',
            'visualization_msgs/MarkerArray',
            'LINE_LIST per keyframe (ns `keyframes`, id in arrival order) and the latest answered novel '
            'view (ns `novel_view`, id 0), world frame',
            _LATCHED,
        ),
        Topic(
            'keyframes/points',
            'sensor_msgs/PointCloud2',
            'one per refined keyframe (its stamp): x, y, z, rgb (packed float32), world frame',
            _MODEL,
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=(
            'pose',
            'camera_info',
            'image',
            'depth',
            'depth/confidence',
            'camera_pose',
            'query',
            'view_info',
        ),
        outputs=('points', 'layout', 'tf'),
        latency='from the keyframe message that completed a cloud (usually its depth) to the cloud out',
        reasons=(
            ('<field>', 'a malformed message of that input (e.g. `depth`, `camera_pose`)'),
            ('size', "a keyframe's image, depth or confidence not of its camera's size"),
            ('model_full', 'the oldest keyframe forgotten beyond `max_keyframes`'),
            ('view_info', 'a novel_view/camera_info without a query of its stamp'),
            ('lost', 'messages DDS reports lost (best effort)'),
            ('incompatible_qos', 'a publisher whose QoS cannot match'),
        ),
        queues=(
            ('queries', 'novel-view queries waiting for their camera_info (bound 100, the oldest dropped)'),
        ),
        model=(
            ('keyframes', 'keyframes held'),
            ('posed', 'keyframes with a pose (on keyframes/poses, frustums, /tf_static)'),
            ('clouds', 'keyframe clouds published (a re-refined keyframe counts again)'),
            ('tf', '`on`, or `off` without tf2_msgs'),
        ),
    ),
)
