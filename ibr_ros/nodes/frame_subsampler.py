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
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.camera import CameraError, PinholeCamera
from ibr_ros.core.geometry import GeometryError
from ibr_ros.core.keyframes import KeyframeConfig, KeyframeSelector, blur_score
from ibr_ros.nodes.common import BadInput, declare, model_qos, run_node, sensor_qos, size_mismatch

BAD_MESSAGE = (msg_utils.MessageError, CameraError, GeometryError, ValueError)


@dataclass
class _Frame:
    image: np.ndarray | None = None
    info: CameraInfo | None = None
    camera: PinholeCamera | None = None
    pose: np.ndarray | None = None
    pose_frame: str = 'map'


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
        self.pending: dict[int, _Frame] = {}
        self.frames_seen = 0
        qos = sensor_qos()
        if self.compressed:
            self.create_subscription(CompressedImage, 'camera/image_raw/compressed', self.on_image, qos)
        else:
            self.create_subscription(Image, 'camera/image_raw', self.on_image, qos)
        self.create_subscription(CameraInfo, 'camera/camera_info', self.on_info, qos)
        pose_cls = Odometry if self.pose_type == 'odometry' else PoseStamped
        self.create_subscription(pose_cls, 'camera/pose', self.on_pose, qos)
        out = model_qos()
        self.pub_image = self.create_publisher(Image, 'keyframes/image', out)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/camera_info', out)
        self.pub_pose = self.create_publisher(PoseStamped, 'keyframes/pose', out)

    def _slot(self, stamp: int) -> _Frame:
        if stamp not in self.pending and len(self.pending) >= self.max_pending:
            oldest = min(self.pending)
            del self.pending[oldest]
            self.bad('incomplete', f'frame at {oldest} ns never got all of image, camera_info and pose')
        return self.pending.setdefault(stamp, _Frame())

    def on_image(self, msg: Image | CompressedImage) -> None:
        try:
            rgb = msg_utils.compressed_image_to_numpy(msg) if self.compressed else msg_utils.image_to_rgb(msg)
            if rgb.ndim == 2:
                rgb = np.repeat(rgb[..., None], 3, axis=2)
        except BAD_MESSAGE as exc:
            self.bad('image', str(exc))
            return
        self._slot(msg_utils.stamp_to_ns(msg.header.stamp)).image = np.ascontiguousarray(rgb)
        self._try(msg_utils.stamp_to_ns(msg.header.stamp))

    def on_info(self, msg: CameraInfo) -> None:
        try:
            camera = msg_utils.camera_info_to_pinhole(msg)
        except BAD_MESSAGE as exc:
            self.bad('camera_info', str(exc))
            return
        slot = self._slot(msg_utils.stamp_to_ns(msg.header.stamp))
        slot.info, slot.camera = msg, camera
        self._try(msg_utils.stamp_to_ns(msg.header.stamp))

    def on_pose(self, msg: PoseStamped | Odometry) -> None:
        try:
            t_wc = (
                msg_utils.odometry_to_matrix(msg)
                if self.pose_type == 'odometry'
                else msg_utils.pose_stamped_to_matrix(msg)
            )
        except BAD_MESSAGE as exc:
            self.bad('pose', str(exc))
            return
        slot = self._slot(msg_utils.stamp_to_ns(msg.header.stamp))
        slot.pose, slot.pose_frame = t_wc, msg.header.frame_id or 'map'
        self._try(msg_utils.stamp_to_ns(msg.header.stamp))

    def _try(self, stamp: int) -> None:
        f = self.pending.get(stamp)
        if f is None or f.image is None or f.camera is None or f.pose is None:
            return
        del self.pending[stamp]
        for old in [s for s in self.pending if s < stamp]:  # older frames can no longer complete in order
            del self.pending[old]
            self.bad('incomplete', f'frame at {old} ns superseded before all its messages arrived')
        if mismatch := size_mismatch(f.camera.width, f.camera.height, f.image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        d = self.selector.decide(stamp, f.pose, blur_score(f.image), self.scene_depth or None)
        if not d.keep:
            self.get_logger().debug(f'frame {stamp}: skipped ({d.reason})')
            return
        header = msg_utils.make_header(stamp, f.info.header.frame_id or 'camera_optical')
        self.pub_image.publish(msg_utils.numpy_to_image(f.image, 'rgb8', header))
        f.info.header = header
        self.pub_info.publish(f.info)
        self.pub_pose.publish(msg_utils.matrix_to_pose_stamped(f.pose, stamp_ns=stamp, frame_id=f.pose_frame))
        self.get_logger().info(
            f'keyframe {self.selector.count} at {stamp} ns ({d.reason}: baseline {d.baseline_m:.1f} m, '
            f'rotation {d.rotation_deg:.1f} deg; {self.frames_seen} frames seen)'
        )


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSubsampler, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
