# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``scene_viz``: the keyframe model for standard viewers (RViz, Foxglove).

Topics, parameters and behaviour: ``doc/nodes.md`` (generated from
:data:`ibr_ros.node_config.SCENE_VIZ`). What is shown is core policy
(:class:`~ibr_ros.core.viz.VizModel`: points, frustums, TF frames); this node converts the model
topics into it and publishes. The aggregate topics (``keyframes/poses``, ``keyframes/frustums``,
``/tf_static``) are republished whole on every change, latched (the latest), so a viewer that joins
late gets everything; ``keyframes/points`` keeps one cloud per keyframe (transient local, deep as
the model). TF needs ``tf2_msgs`` (a ROS 2 install has it; no PyPI wheel, so ``make install`` builds
``vendor/tf2_msgs`` into a pip venv): without it /tf and /tf_static are not published (a warning at
start-up; the poses are still on ``keyframes/poses``).
"""

from __future__ import annotations

import sys
from collections import OrderedDict
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseArray, PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import MarkerArray

import msg_utils
from ibr_ros.core.diagnostics import Queue
from ibr_ros.core.viz import VizModel
from ibr_ros.node_config.scene_viz import SCENE_VIZ
from ibr_ros.nodes.common import (
    BAD_MESSAGE,
    POSE_MESSAGES,
    BadInput,
    declare_table,
    latched_qos,
    model_qos,
    reliable_qos,
    run_node,
    sensor_qos,
    start_diagnostics,
    subscribe_field,
)

#: Novel-view queries kept until their camera_info comes (the newest).
MAX_QUERIES = 100


class SceneViz(Node):
    """Viewer topics of the model (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('scene_viz')
        cfg = SCENE_VIZ.build(declare_table(self, SCENE_VIZ))
        self.cfg = cfg
        self.model = VizModel(cfg.viz)
        self.bad = BadInput(self)
        self.clouds = 0
        self.cloud_sent: set[int] = set()
        self.queries: OrderedDict[int, np.ndarray] = OrderedDict()
        qos = model_qos()
        self.pub_points = self.create_publisher(PointCloud2, 'keyframes/points', qos)
        self.pub_poses = self.create_publisher(PoseArray, 'keyframes/poses', latched_qos())
        self.pub_frustums = self.create_publisher(MarkerArray, 'keyframes/frustums', latched_qos())
        self.pub_tf = self.pub_tf_static = None
        self.diag = start_diagnostics(self, SCENE_VIZ.diagnostics, self._diagnostics)
        if msg_utils.tf_available():
            from tf2_msgs.msg import TFMessage

            self.pub_tf = self.create_publisher(TFMessage, '/tf', reliable_qos(100))
            self.pub_tf_static = self.create_publisher(TFMessage, '/tf_static', latched_qos())
        else:
            self.get_logger().warning(
                'tf2_msgs is not installed (no PyPI wheel; a ROS 2 install has it, `make install` builds '
                'it into a venv): /tf and /tf_static are not published; keyframes/poses, '
                'keyframes/frustums and keyframes/points are'
            )
        for msg_type, field, convert in (
            (
                PoseStamped,
                'pose',
                lambda m: (msg_utils.pose_stamped_to_matrix(m), m.header.frame_id or 'map'),
            ),
            (CameraInfo, 'camera_info', msg_utils.camera_info_to_pinhole),
            (Image, 'image', lambda m: np.array(msg_utils.image_to_rgb(m))),
            (Image, 'depth', lambda m: np.array(msg_utils.depth_image_to_m(m))),
            (Image, 'depth/confidence', lambda m: np.array(msg_utils.image_to_confidence(m))),
        ):
            subscribe_field(
                self, msg_type, f'keyframes/{field}', qos, field, convert, self._put, self.bad, self.diag
            )
        pose_type, to_matrix = POSE_MESSAGES[cfg.pose_type]
        subscribe_field(
            self, pose_type, 'camera/pose', sensor_qos(), 'camera_pose',
            lambda m: (to_matrix(m), m.header.frame_id or 'map'), self._on_camera_pose, self.bad, self.diag,
        )  # fmt: skip
        subscribe_field(
            self, PoseStamped, 'novel_view/query', reliable_qos(MAX_QUERIES), 'query',
            msg_utils.pose_stamped_to_matrix, self._on_query, self.bad, self.diag,
        )  # fmt: skip
        subscribe_field(
            self, CameraInfo, 'novel_view/camera_info', reliable_qos(), 'view_info',
            msg_utils.camera_info_to_pinhole, self._on_view_info, self.bad, self.diag,
        )  # fmt: skip
        c = cfg.viz
        self.get_logger().info(
            f'showing the model: points every {c.cloud.stride} px with confidence >= '
            f'{c.cloud.min_confidence:g}; TF {"on" if self.pub_tf else "off"} (camera {c.frames.camera!r}, '
            f'body {c.frames.body!r}, keyframes {c.frames.keyframe_prefix!r}<stamp>_optical_frame)'
        )

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        return {
            'rejected': self.bad.counts,
            'queues': {'queries': Queue(len(self.queries), MAX_QUERIES)},
            'model': {
                'keyframes': len(self.model.keyframes),
                'posed': len(self.model.posed()),
                'clouds': self.clouds,
                'tf': 'on' if self.pub_tf is not None else 'off',
            },
        }

    # -- keyframes ------------------------------------------------------------------------------
    def _put(self, stamp: int, field: str, value: Any) -> None:
        m = self.model
        self.diag.started(stamp)
        try:
            if field == 'pose':
                if m.put_pose(stamp, *value):
                    self._publish_layout(stamp)
            elif field == 'camera_info':
                if m.put_camera(stamp, value):
                    self._publish_layout(stamp)
                    self.cloud_sent.discard(stamp)
            elif field == 'image':
                m.put_image(stamp, value)
            elif field == 'depth':
                if m.put_depth(stamp, value):
                    self.cloud_sent.discard(stamp)
                    self._publish_layout(stamp)  # the automatic frustum depth follows the depths
            elif m.put_confidence(stamp, value):
                self.cloud_sent.discard(stamp)
        except ValueError as exc:  # another world frame, a pose or a size that does not fit
            self.bad(field, f'keyframe {stamp} ns: {exc}')
            return
        self._forget_oldest()
        if stamp in m.keyframes and stamp not in self.cloud_sent:
            self._publish_points(stamp)

    def _forget_oldest(self) -> None:
        while len(self.model.keyframes) > self.cfg.max_keyframes:
            oldest = min(self.model.keyframes)
            self.model.drop(oldest)
            self.cloud_sent.discard(oldest)
            self.bad(
                'model_full', f'more than {self.cfg.max_keyframes} keyframes: keyframe {oldest} ns forgotten'
            )

    def _publish_points(self, stamp: int) -> None:
        try:
            points = self.model.points(stamp)
        except ValueError as exc:  # image, depth or confidence not of the camera's size
            self.bad('size', f'keyframe {stamp} ns: {exc}')
            return
        if points is None:
            return
        header = msg_utils.make_header(stamp, self.model.world)
        self.pub_points.publish(msg_utils.points_to_cloud(*points, header))
        self.cloud_sent.add(stamp)
        self.clouds += 1
        self.diag.published('points')
        self.diag.finished(stamp)
        self.get_logger().info(f'keyframe {stamp} ns: {len(points[0])} points published')

    def _publish_layout(self, stamp: int) -> None:
        """keyframes/poses, keyframes/frustums and /tf_static, each whole (latched)."""
        m = self.model
        header = msg_utils.make_header(stamp, m.world)
        self.pub_poses.publish(msg_utils.matrices_to_pose_array(m.poses(), header))
        self._publish_frustums(stamp)
        self.diag.published('layout')
        if self.pub_tf_static is not None:
            self.pub_tf_static.publish(msg_utils.transforms_to_tf(m.static_transforms()))

    def _publish_frustums(self, stamp: int) -> None:
        m = self.model
        header = msg_utils.make_header(stamp, m.world or 'map')
        self.pub_frustums.publish(
            msg_utils.frustums_to_marker_array(m.frustum_lines(), header, width=m.line_width())
        )

    # -- the live camera and the novel views -----------------------------------------------------
    def _on_camera_pose(self, stamp: int, field: str, value: tuple[np.ndarray, str]) -> None:
        if self.pub_tf is None:
            return
        t_wc, world = value
        chain = self.model.camera_transforms(t_wc, world)
        self.pub_tf.publish(msg_utils.transforms_to_tf([(stamp, p, c, t) for p, c, t in chain]))
        self.diag.published('tf')

    def _on_query(self, stamp: int, field: str, t_wc: np.ndarray) -> None:
        self.queries[stamp] = t_wc
        while len(self.queries) > MAX_QUERIES:  # never answered (refused): no camera_info follows
            self.queries.popitem(last=False)

    def _on_view_info(self, stamp: int, field: str, camera: Any) -> None:
        t_wc = self.queries.pop(stamp, None)
        if t_wc is None:
            self.bad('view_info', f'novel_view/camera_info {stamp} ns: no query with its stamp received')
            return
        try:
            self.model.set_novel_view(camera, t_wc)
        except BAD_MESSAGE as exc:
            self.bad('query', f'query {stamp} ns: {exc}')
            return
        self._publish_frustums(stamp)
        if self.pub_tf is not None:
            world = self.model.world or 'map'
            tf = [(stamp, world, self.cfg.novel_view_frame, t_wc)]
            self.pub_tf.publish(msg_utils.transforms_to_tf(tf))


def main(args: list[str] | None = None) -> int:
    return run_node(SceneViz, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
