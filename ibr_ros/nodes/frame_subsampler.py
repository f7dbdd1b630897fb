"""``frame_subsampler``: picks sharp, well-spaced keyframes from a camera stream.

Subscribes (sensor-data QoS unless noted): ``camera/image_raw`` (``sensor_msgs/Image``) or, with
``compressed:=true``, ``camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``);
``camera/camera_info`` (``sensor_msgs/CameraInfo``); ``camera/pose`` (``geometry_msgs/PoseStamped``
in ``map``, or ``nav_msgs/Odometry`` with ``pose_type:=odometry``). Messages of one frame are
matched by identical header stamps.

Publishes (reliable, transient local): ``keyframes/image`` (``sensor_msgs/Image`` rgb8),
``keyframes/camera_info`` and ``keyframes/pose`` (``geometry_msgs/PoseStamped``), all three with the
frame's header stamp. Decisions: :class:`ibr_ros.core.keyframes.KeyframeSelector`: a sharp frame
becomes a keyframe when the camera moved ``baseline_ratio`` x ``scene_depth_m`` (``min_baseline_m``
when ``scene_depth_m`` is 0) from the last keyframe, turned ``max_rotation_deg`` or after
``max_interval_s``.

Target count (``target_keyframes`` > 0): live, the flight's length is unknown, so the node needs
``expected_path_m``, the planned flight path length in metres (it refuses to start without it), and
uses ONE baseline threshold of ``expected_path_m / target_keyframes`` metres (:func:`target_baseline`)
in place of ``baseline_ratio`` x ``scene_depth_m`` and ``min_baseline_m``; the rotation, interval and
blur rules are unchanged. On a flight of that path length the baseline rule then gives about
``target_keyframes`` keyframes (the first frame, then one per threshold of straight-line distance;
at most ``target_keyframes`` + 1): fewer on a shorter flight or a tightly curved path (the chord is
shorter than the path), more on a longer one or where ``max_rotation_deg`` or ``max_interval_s``
trigger. ``ibr process`` knows the whole flight and meets the target by bisection instead
(:func:`ibr_ros.core.keyframes.select_keyframes`; ``expected_path_m`` is not used there).

Without poses: when no pose has ever arrived and a frame's image and camera_info waited
``pose_timeout_s`` (wall clock) for its pose, the node selects keyframes without poses from then
on: the sharpest unblurred frame of every ``poseless_interval_s`` window of stamps
(:class:`ibr_ros.core.keyframes.IntervalSelector`; a window's keyframe is published when the
next window starts, or after ``poseless_interval_s`` without frames), published on
``keyframes/image`` and ``keyframes/camera_info`` only; the depth_refiner registers them (its SfM
mode). Choose the interval so that consecutive keyframes overlap well (SfM needs it). The first
pose that arrives switches back to pose-based selection for good. ``pose_timeout_s`` 0: always
wait for poses.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.keyframes import IntervalSelector, KeyframeConfig, KeyframeSelector, blur_score
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

#: ``pose_type`` -> the message type of ``camera/pose`` and its conversion to a 4x4 ``T_wc``.
POSE_TYPES = {
    'pose': (PoseStamped, msg_utils.pose_stamped_to_matrix),
    'odometry': (Odometry, msg_utils.odometry_to_matrix),
}


def target_baseline(target_keyframes: int, expected_path_m: float) -> float | None:
    """The live keyframe baseline (m) for about ``target_keyframes`` over ``expected_path_m`` metres of
    flight path: ``expected_path_m / target_keyframes``; None when ``target_keyframes`` is 0 (off).

    Raises:
        ValueError: ``target_keyframes`` < 0, or > 0 without ``expected_path_m`` > 0.

    """
    if target_keyframes < 0:
        raise ValueError(f'parameter target_keyframes must be >= 0 (0 = off), got {target_keyframes}')
    if not target_keyframes:
        return None
    if not expected_path_m > 0:
        raise ValueError(
            f'parameter target_keyframes {target_keyframes} needs expected_path_m > 0, the planned flight '
            f'path length in metres (the live node cannot know the flight length), got {expected_path_m}'
        )
    return float(expected_path_m) / target_keyframes


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
        self.pose_timeout = float(
            p('pose_timeout_s', 2.0, 'no pose in this time (s): keyframes without poses; 0 = never',
              limits=(0.0, 1e6))
        )  # fmt: skip
        self.poseless_interval = float(
            p(
                'poseless_interval_s',
                1.0,
                'without poses: one keyframe per this many seconds',
                limits=(1e-3, 1e6),
            )
        )
        self.target = int(
            p('target_keyframes', 0, 'about this many keyframes per flight (needs expected_path_m); 0 = off',
              limits=(0, 1_000_000))
        )  # fmt: skip
        self.expected_path = float(
            p('expected_path_m', 0.0, 'planned flight path length (m), for target_keyframes', **lim)
        )
        if self.pose_type not in POSE_TYPES:
            raise ValueError(f"parameter pose_type must be 'pose' or 'odometry', got {self.pose_type!r}")
        self.baseline = target_baseline(self.target, self.expected_path)
        # The scene depth the baseline rule uses (None: min_baseline_m).
        self.decide_depth = self.scene_depth or None
        if self.baseline is not None:
            self.config = replace(self.config, min_baseline_m=self.baseline)
            self.decide_depth = None
            self.get_logger().info(
                f'target_keyframes {self.target} over expected_path_m {self.expected_path:g} m: a keyframe '
                f'every {self.baseline:.3g} m (replaces baseline_ratio x scene_depth_m and min_baseline_m)'
            )
        self.selector = KeyframeSelector(self.config)
        self.bad = BadInput(self)
        self.frames = StampAssembler(
            ('image', 'camera_info', 'pose'),
            self.max_pending,
            lambda detail: self.bad('incomplete', detail),
            supersede=True,  # a sensor stream arrives in order: older frames can no longer complete
        )
        self.frames_seen = 0
        self.keyframes = 0
        self.poses_seen = 0
        self.poseless = False  # selecting keyframes without poses
        self.interval = IntervalSelector(self.poseless_interval, self.config)
        self._waiting: dict[int, float] = {}  # stamp -> when its image and camera_info were there
        self._last_poseless = time.monotonic()
        qos = sensor_qos()
        image_in = (
            (CompressedImage, 'camera/image_raw/compressed')
            if self.compressed
            else (Image, 'camera/image_raw')
        )
        info = lambda m: (m, msg_utils.camera_info_to_pinhole(m))  # noqa: E731
        pose_type, to_matrix = POSE_TYPES[self.pose_type]
        pose = lambda m: (to_matrix(m), m.header.frame_id or 'map')  # noqa: E731
        for msg_type, topic, field, convert in (
            (*image_in, 'image', msg_utils.camera_image_to_rgb),
            (CameraInfo, 'camera/camera_info', 'camera_info', info),
            (pose_type, 'camera/pose', 'pose', pose),
        ):
            subscribe_field(self, msg_type, topic, qos, field, convert, self._put, self.bad)
        out = model_qos()
        self.pub_image = self.create_publisher(Image, 'keyframes/image', out)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/camera_info', out)
        self.pub_pose = self.create_publisher(PoseStamped, 'keyframes/pose', out)
        if self.pose_timeout > 0:
            self.create_timer(min(0.1, self.pose_timeout / 2), self._on_timer)

    def _put(self, stamp: int, field: str, value: object) -> None:
        if field == 'pose':
            self.poses_seen += 1
            self._waiting.clear()
            if self.poseless:
                self.poseless = False
                self.get_logger().warning('camera/pose arrives: keyframes are selected by pose again')
        if (f := self.frames.put(stamp, field, value)) is None:
            if not self.poses_seen and self.pose_timeout > 0:
                partial = self.frames.partial(stamp)
                if 'image' in partial and 'camera_info' in partial:
                    if self.poseless:
                        self.frames.discard(stamp)
                        self._poseless_frame(stamp, partial)
                    else:
                        self._waiting.setdefault(stamp, time.monotonic())
            return
        image, (info, camera), (pose, pose_frame) = f['image'], f['camera_info'], f['pose']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        d = self.selector.decide(stamp, pose, blur_score(image), self.decide_depth)
        if not d.keep:
            self.get_logger().debug(f'frame {stamp}: skipped ({d.reason})')
            return
        self._publish(stamp, image, info, (pose, pose_frame))
        self.get_logger().info(
            f'keyframe {self.keyframes} at {stamp} ns ({d.reason}: baseline {d.baseline_m:.1f} m, '
            f'rotation {d.rotation_deg:.1f} deg; {self.frames_seen} frames seen)'
        )

    def _publish(
        self, stamp: int, image: np.ndarray, info: CameraInfo, pose: tuple[np.ndarray, str] | None
    ) -> None:
        """Publish one keyframe: image, camera_info and (when known) pose, all stamped ``stamp``."""
        header = msg_utils.make_header(stamp, info.header.frame_id or 'camera_optical')
        self.pub_image.publish(msg_utils.numpy_to_image(image, 'rgb8', header))
        info.header = header
        self.pub_info.publish(info)
        if pose is not None:
            self.pub_pose.publish(msg_utils.matrix_to_pose_stamped(pose[0], stamp_ns=stamp, frame_id=pose[1]))
        self.keyframes += 1

    # -- without poses ----------------------------------------------------------------------------
    def _poseless_frame(self, stamp: int, partial: dict) -> None:
        image, (info, camera) = partial['image'], partial['camera_info']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        self._last_poseless = time.monotonic()
        self._publish_poseless(self.interval.push(stamp, blur_score(image), (image, info)))

    def _publish_poseless(self, chosen: list[tuple[int, tuple[np.ndarray, CameraInfo]]]) -> None:
        for stamp, (image, info) in chosen:
            self._publish(stamp, image, info, None)
            self.get_logger().info(
                f'keyframe {self.keyframes} at {stamp} ns (no pose: the sharpest frame of its '
                f'{self.poseless_interval:g} s window; {self.frames_seen} frames seen)'
            )

    def _on_timer(self) -> None:
        now = time.monotonic()
        if not self.poses_seen and not self.poseless and self._waiting:
            if now - min(self._waiting.values()) < self.pose_timeout:
                return
            self.poseless = True
            self.get_logger().warning(
                f'no camera/pose within {self.pose_timeout:g} s: selecting keyframes without poses (the '
                f'sharpest frame every {self.poseless_interval:g} s), published without keyframes/pose'
            )
            for stamp in sorted(self._waiting):
                partial = self.frames.partial(stamp)
                if 'image' in partial and 'camera_info' in partial:
                    self.frames.discard(stamp)
                    self._poseless_frame(stamp, partial)
            self._waiting.clear()
        elif self.poseless and now - self._last_poseless >= self.poseless_interval:
            self._publish_poseless(self.interval.flush())  # the stream paused or ended


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSubsampler, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
