"""``frame_subsampler``: picks sharp, well-spaced keyframes from a camera stream.

Subscribes (sensor-data QoS unless noted): ``camera/image_raw`` (``sensor_msgs/Image``) or, with
``compressed:=true``, ``camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``);
``camera/camera_info`` (``sensor_msgs/CameraInfo``); ``camera/pose`` (``geometry_msgs/PoseStamped``
in ``map``, or ``nav_msgs/Odometry`` with ``pose_type:=odometry``). Messages of one frame are
matched by identical header stamps.

Publishes (reliable, transient local): ``keyframes/image`` (``sensor_msgs/Image`` rgb8),
``keyframes/camera_info`` and ``keyframes/pose`` (``geometry_msgs/PoseStamped``), all three with the
frame's header stamp. Decisions: :class:`ibr_ros.core.keyframes.KeyframeSelector`.
"""

from __future__ import annotations

import sys

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.keyframes import KeyframeConfig, KeyframeSelector, blur_score
from ibr_ros.nodes.common import (
    BadInput,
    StampAssembler,
    declare,
    model_qos,
    run_node,
    sensor_qos,
    size_mismatch,
    subscribe_field,
)


class FrameSubsampler(Node):
    """Keyframe selection node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('frame_subsampler')
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.compressed = bool(p('compressed', False, 'subscribe to camera/image_raw/compressed'))
        self.pose_type = str(p('pose_type', 'pose', "'pose' (PoseStamped) or 'odometry' (Odometry)"))
        self.scene_depth = float(
            p('scene_depth_m', 0.0, 'typical scene depth (m); 0 = unknown', limits=(0.0, 1e5))
        )
        self.max_pending = int(
            p('max_pending', 30, 'frames waiting for their other messages', limits=(1, 10000))
        )
        lim = {'limits': (0.0, 1e6)}
        self.config = KeyframeConfig(
            baseline_ratio=float(p('baseline_ratio', 0.08, 'keyframe baseline / scene depth', **lim)),
            min_baseline_m=float(p('min_baseline_m', 2.0, 'baseline when the depth is unknown (m)', **lim)),
            max_rotation_deg=float(p('max_rotation_deg', 15.0, 'rotation forcing a keyframe (deg)', **lim)),
            max_interval_s=float(p('max_interval_s', 0.0, 'time forcing a keyframe (s), 0 = off', **lim)),
            min_interval_s=float(p('min_interval_s', 0.0, 'minimum time between keyframes (s)', **lim)),
            blur_ratio=float(
                p('blur_ratio', 0.6, 'blurred below this x median sharpness', limits=(0.0, 1.0))
            ),
        )
        if self.pose_type not in ('pose', 'odometry'):
            raise ValueError(f"parameter pose_type must be 'pose' or 'odometry', got {self.pose_type!r}")
        self.selector = KeyframeSelector(self.config)
        self.bad = BadInput(self)
        self.frames = StampAssembler(
            ('image', 'camera_info', 'pose'),
            self.max_pending,
            lambda detail: self.bad('incomplete', detail),
            supersede=True,  # a sensor stream arrives in order: older frames can no longer complete
        )
        self.frames_seen = 0
        qos = sensor_qos()
        image_in = (
            (CompressedImage, 'camera/image_raw/compressed')
            if self.compressed
            else (Image, 'camera/image_raw')
        )
        info = lambda m: (m, msg_utils.camera_info_to_pinhole(m))  # noqa: E731
        pose_type = Odometry if self.pose_type == 'odometry' else PoseStamped
        for msg_type, topic, field, convert in (
            (*image_in, 'image', self._rgb),
            (CameraInfo, 'camera/camera_info', 'camera_info', info),
            (pose_type, 'camera/pose', 'pose', self._pose),
        ):
            subscribe_field(self, msg_type, topic, qos, field, convert, self._put, self.bad)
        out = model_qos()
        self.pub_image = self.create_publisher(Image, 'keyframes/image', out)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/camera_info', out)
        self.pub_pose = self.create_publisher(PoseStamped, 'keyframes/pose', out)

    def _rgb(self, msg: Image | CompressedImage) -> np.ndarray:
        rgb = msg_utils.compressed_image_to_numpy(msg) if self.compressed else msg_utils.image_to_rgb(msg)
        return np.ascontiguousarray(np.repeat(rgb[..., None], 3, axis=2) if rgb.ndim == 2 else rgb)

    def _pose(self, msg: PoseStamped | Odometry) -> tuple[np.ndarray, str]:
        convert = (
            msg_utils.odometry_to_matrix if self.pose_type == 'odometry' else msg_utils.pose_stamped_to_matrix
        )
        return convert(msg), msg.header.frame_id or 'map'

    def _put(self, stamp: int, field: str, value: object) -> None:
        if (f := self.frames.put(stamp, field, value)) is None:
            return
        image, (info, camera), (pose, pose_frame) = f['image'], f['camera_info'], f['pose']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        d = self.selector.decide(stamp, pose, blur_score(image), self.scene_depth or None)
        if not d.keep:
            self.get_logger().debug(f'frame {stamp}: skipped ({d.reason})')
            return
        header = msg_utils.make_header(stamp, info.header.frame_id or 'camera_optical')
        self.pub_image.publish(msg_utils.numpy_to_image(image, 'rgb8', header))
        info.header = header
        self.pub_info.publish(info)
        self.pub_pose.publish(msg_utils.matrix_to_pose_stamped(pose, stamp_ns=stamp, frame_id=pose_frame))
        self.get_logger().info(
            f'keyframe {self.selector.count} at {stamp} ns ({d.reason}: baseline {d.baseline_m:.1f} m, '
            f'rotation {d.rotation_deg:.1f} deg; {self.frames_seen} frames seen)'
        )


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSubsampler, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
