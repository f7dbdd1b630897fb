"""``frame_subsampler``: picks sharp, well-spaced keyframes from a camera stream.

Subscribes, once the topic has a publisher, with the reliability its publishers offer (reliable and
keep-all when all of them offer reliable, e.g. ``bag_player``, so a replay at any rate loses nothing;
else best effort, REP-2003 sensor data, each lost message counted): ``camera/image_raw``
(``sensor_msgs/Image``) or ``camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``),
``image_transport`` ``auto`` (default: whichever has a publisher, raw when both), ``raw`` or
``compressed``; ``camera/camera_info`` (``sensor_msgs/CameraInfo``); ``camera/pose``
(``geometry_msgs/PoseStamped`` in ``map``, or ``nav_msgs/Odometry`` with ``pose_type:=odometry``).
Messages of one frame are matched by identical header stamps.

Publishes (reliable, transient local): ``keyframes/image`` (``sensor_msgs/Image`` rgb8),
``keyframes/camera_info`` and ``keyframes/pose`` (``geometry_msgs/PoseStamped``), all three with the
frame's header stamp; ``keyframes/status`` (``diagnostic_msgs/DiagnosticStatus``, depth 1, on every
change; :class:`~ibr_ros.core.flight.status.FlightStatus`): the flight's pose source (``pose`` / ``none``),
the camera stream (``waiting`` / ``streaming`` / ``ended``: every camera publisher gone), frames
and keyframes so far. Decisions: :class:`ibr_ros.core.flight.keyframes.KeyframeSelector`: a sharp frame
becomes a keyframe when the camera moved ``baseline_ratio`` x ``scene_depth_m`` (``min_baseline_m``
when ``scene_depth_m`` is 0) from the last keyframe, turned ``max_rotation_deg`` or after
``max_interval_s``.

Target count (``target_keyframes`` > 0): live, the flight's length is unknown, so the node needs
``expected_path_m``, the planned flight path length in metres (it refuses to start without it), and
uses ONE baseline threshold of ``expected_path_m / target_keyframes`` metres (:func:`target_baseline`)
in place of ``baseline_ratio`` x ``scene_depth_m`` and ``min_baseline_m``; the rotation, interval and
blur rules are unchanged. ``ibr process`` knows the whole flight and meets the target by bisection
instead (:func:`ibr_ros.core.flight.keyframes.select_keyframes`; ``expected_path_m`` is not used there).

Pose source (:class:`~ibr_ros.core.flight.status.PoseSource`; ``pose_source``): ``auto`` decides when the
first frame's image and camera_info are there: the flight has poses when ``camera/pose`` has a
publisher then (every frame waits for its pose, however late), else none; ``topic`` always waits for
poses; ``none`` ignores them. Without poses the sharpest unblurred frame of every
``poseless_interval_s`` window of stamps is a keyframe (:class:`ibr_ros.core.flight.IntervalSelector`;
a window's keyframe is published when the next window starts or the camera stream ends), published
on ``keyframes/image`` and ``keyframes/camera_info`` only; the depth_refiner registers them (its SfM
mode). The decision holds for the flight: poses arriving later are counted (``pose_ignored``) and
dropped. No timer decides any of this: a live drone whose pose node may start after its camera
should use ``pose_source: topic``.
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.flight.keyframes import IntervalSelector, KeyframeConfig, KeyframeSelector, blur_score
from ibr_ros.core.flight.status import IMAGE_TRANSPORTS, FlightStatus, PoseSource
from ibr_ros.nodes.common import (
    BadInput,
    StampAssembler,
    declare,
    input_qos,
    latched_qos,
    model_qos,
    run_node,
    size_mismatch,
    subscribe_field,
)

#: Image topic (:data:`~ibr_ros.core.flight.status.IMAGE_TRANSPORTS`) -> its message type.
IMAGE_TYPES = {'camera/image_raw': Image, 'camera/image_raw/compressed': CompressedImage}

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
        transport = str(
            p('image_transport', 'auto', "camera images: 'auto' (raw or compressed), 'raw', 'compressed'")
        )
        self.pose_type = str(p('pose_type', 'pose', "'pose' (PoseStamped) or 'odometry' (Odometry)"))
        self.scene_depth = float(
            p('scene_depth_m', 0.0, 'typical scene depth (m); 0 = unknown', limits=(0.0, 1e5))
        )
        self.max_pending = int(
            p('max_pending', 30, 'frames waiting for their other messages', limits=(1, 10000))
        )
        max_mb = float(p('max_pending_mb', 128.0, 'MiB of pending frames at most', limits=(1.0, 1e6)))
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
        pose_mode = str(
            p('pose_source', 'auto', "'auto' (poses iff camera/pose has a publisher), 'topic' or 'none'")
        )
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
        if transport not in IMAGE_TRANSPORTS:
            raise ValueError(
                f"parameter image_transport must be 'auto', 'raw' or 'compressed', got {transport!r}"
            )
        self.pose_source = PoseSource(pose_mode)  # ValueError names the parameter
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
            max_bytes=round(max_mb * 2**20),
        )
        self.frames_seen = 0
        self.keyframes = 0
        self.interval = IntervalSelector(self.poseless_interval, self.config)
        self.camera = 'waiting'
        self._images = self._images_at_tick = 0  # image messages handled, at the last graph tick
        info = lambda m: (m, msg_utils.camera_info_to_pinhole(m))  # noqa: E731
        pose_type, to_matrix = POSE_TYPES[self.pose_type]
        pose = lambda m: (to_matrix(m), m.header.frame_id or 'map')  # noqa: E731
        # field -> candidate (message type, topic, conversion), in order of preference.
        self._inputs: dict[str, list[tuple[type, str, object]]] = {
            'image': [
                (IMAGE_TYPES[t], t, msg_utils.camera_image_to_rgb) for t in IMAGE_TRANSPORTS[transport]
            ],
            'camera_info': [(CameraInfo, 'camera/camera_info', info)],
        }
        if pose_mode != 'none':
            self._inputs['pose'] = [(pose_type, 'camera/pose', pose)]
        self.subscribed: dict[str, str] = {}  # field -> resolved topic
        out = model_qos()
        self.pub_image = self.create_publisher(Image, 'keyframes/image', out)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/camera_info', out)
        self.pub_pose = self.create_publisher(PoseStamped, 'keyframes/pose', out)
        self.pub_status = self.create_publisher(DiagnosticStatus, 'keyframes/status', latched_qos())
        self._status: FlightStatus | None = None
        self._publish_status()
        images = ' or '.join(self.resolve_topic_name(t) for _, t, _ in self._inputs['image'])
        self.get_logger().info(
            f'waiting for a publisher of {images} (image_transport {transport}); pose_source {pose_mode}'
        )
        self._on_graph()
        self.create_timer(0.1, self._on_graph)  # polls the ROS graph: publishers that came or went

    # -- inputs: subscribed as their publishers appear ----------------------------------------------
    def _on_graph(self) -> None:
        for field, candidates in self._inputs.items():
            if field in self.subscribed:
                continue
            for msg_type, topic, convert in candidates:
                name = self.resolve_topic_name(topic)
                infos = self.get_publishers_info_by_topic(name)
                if not infos:
                    continue
                qos, how = input_qos(infos)
                subscribe_field(self, msg_type, topic, qos, field, convert, self._put, self.bad)
                self.subscribed[field] = name
                self.get_logger().info(f'{field}: subscribed to {name} ({how})')
                break
        image = self.subscribed.get('image')
        if image is None:
            return
        n = self.count_publishers(image)
        # Messages still queued are handled between two ticks (one executor): none handled since the
        # last tick and no publisher left means the stream has ended, not merely its publisher.
        quiet = self._images == self._images_at_tick
        self._images_at_tick = self._images
        if n and self.camera != 'streaming':
            self.camera = 'streaming'
            self._publish_status()
        elif not n and self.camera == 'streaming' and quiet:
            self.camera = 'ended'
            self.get_logger().info(f'{image} has no publisher any more: the camera stream ended')
            if self.pose_source.state == 'none':
                self._publish_poseless(self.interval.flush())
            self._publish_status()

    def _publish_status(self) -> None:
        status = FlightStatus(
            pose_source=self.pose_source.state,
            camera=self.camera,
            frames=self.frames_seen,
            keyframes=self.keyframes,
            image_topic=self.subscribed.get('image', ''),
            pose_topic=self.subscribed.get('pose', ''),
        )
        if status == self._status:
            return
        self._status = status
        text = {'pose': 'keyframes with poses', 'none': 'keyframes without poses', 'unknown': 'no frame yet'}
        self.pub_status.publish(
            msg_utils.pairs_to_status(
                self.get_fully_qualified_name(),
                status.to_pairs(),
                message=f'{text[status.pose_source]}; camera {status.camera}',
            )
        )

    def _put(self, stamp: int, field: str, value: object) -> None:
        self._images += field == 'image'
        if field == 'pose':
            if self.pose_source.ignores_poses:
                self.bad('pose_ignored', f'camera/pose at {stamp} ns: this flight has no poses (decided at '
                         "its first frame; pose_source 'topic' waits for them)")  # fmt: skip
                return
            if self.pose_source.pose_arrived():
                self._publish_status()
        if (f := self.frames.put(stamp, field, value)) is None:
            partial = self.frames.partial(stamp)
            if field != 'pose' and 'image' in partial and 'camera_info' in partial:
                self._frame_without_pose(stamp, partial)
            return
        image, (info, camera), (pose, pose_frame) = f['image'], f['camera_info'], f['pose']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        d = self.selector.decide(stamp, pose, blur_score(image), self.decide_depth)
        if d.keep:
            self._publish(stamp, image, info, (pose, pose_frame))
            self.get_logger().info(
                f'keyframe {self.keyframes} at {stamp} ns ({d.reason}: baseline {d.baseline_m:.1f} m, '
                f'rotation {d.rotation_deg:.1f} deg; {self.frames_seen} frames seen)'
            )
        else:
            self.get_logger().debug(f'frame {stamp}: skipped ({d.reason})')
        self._publish_status()

    def _frame_without_pose(self, stamp: int, partial: dict) -> None:
        """Image and camera_info of ``stamp`` are there, its pose is not (yet)."""
        pose_topic = 'camera/pose' if 'pose' in self._inputs else None  # not just once subscribed
        publishers = self.count_publishers(self.resolve_topic_name(pose_topic)) if pose_topic else 0
        if self.pose_source.frame_ready(publishers):
            state = self.pose_source.state
            self.get_logger().info(
                'the flight has poses: every frame waits for its camera/pose'
                if state == 'pose'
                else 'camera/pose has no publisher: selecting keyframes without poses (the sharpest frame '
                f'every {self.poseless_interval:g} s), published without keyframes/pose'
            )
            self._publish_status()
        if self.pose_source.state == 'none':
            self.frames.discard(stamp)
            self._poseless_frame(stamp, partial)

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
        self._publish_poseless(self.interval.push(stamp, blur_score(image), (image, info)))
        self._publish_status()

    def _publish_poseless(self, chosen: list[tuple[int, tuple[np.ndarray, CameraInfo]]]) -> None:
        for stamp, (image, info) in chosen:
            self._publish(stamp, image, info, None)
            self.get_logger().info(
                f'keyframe {self.keyframes} at {stamp} ns (no pose: the sharpest frame of its '
                f'{self.poseless_interval:g} s window; {self.frames_seen} frames seen)'
            )


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSubsampler, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
