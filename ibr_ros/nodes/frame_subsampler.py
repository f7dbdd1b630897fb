# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``frame_subsampler``: picks sharp, well-spaced keyframes from a camera stream.

Topics, parameters and behaviour: ``doc/nodes.md`` (generated from
:data:`ibr_ros.node_config.FRAME_SUBSAMPLER`). Decisions are core policy:
:class:`~ibr_ros.core.flight.keyframes.KeyframeSelector` (with poses),
:class:`~ibr_ros.core.flight.keyframes.IntervalSelector` (without),
:func:`~ibr_ros.core.flight.keyframes.target_baseline` (``target_keyframes`` live),
:class:`~ibr_ros.core.flight.status.PoseSource` (whether the flight has poses) and
:class:`~ibr_ros.core.flight.status.FlightStatus` (``keyframes/status``). This node polls the ROS
graph for its inputs' publishers, converts messages and publishes.
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.diagnostics import Queue
from ibr_ros.core.flight.keyframes import (
    Decision,
    IntervalSelector,
    KeyframeSelector,
    Pick,
    blur_px,
    detail_score,
    target_baseline,
)
from ibr_ros.core.flight.status import IMAGE_TRANSPORTS, FlightStatus, PoseSource
from ibr_ros.node_config.frame_subsampler import FRAME_SUBSAMPLER
from ibr_ros.nodes.common import (
    POSE_MESSAGES,
    BadInput,
    StampAssembler,
    declare_table,
    input_qos,
    latched_qos,
    model_qos,
    run_node,
    size_mismatch,
    start_diagnostics,
    subscribe_field,
)

#: Image topic (:data:`~ibr_ros.core.flight.status.IMAGE_TRANSPORTS`) -> its message type.
IMAGE_TYPES = {'camera/image_raw': Image, 'camera/image_raw/compressed': CompressedImage}


class FrameSubsampler(Node):
    """Keyframe selection node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('frame_subsampler')
        cfg = FRAME_SUBSAMPLER.build(declare_table(self, FRAME_SUBSAMPLER))
        self.pose_source = PoseSource(cfg.pose_source)
        self.poseless_interval = cfg.poseless_interval_s
        self.config = cfg.keyframes
        self.scene_depth = cfg.scene_depth_m  # 0 = unknown
        self.decide_depth = self.scene_depth or None  # what the baseline rule uses (None: min_baseline_m)
        self.baseline = target_baseline(cfg.target_keyframes, cfg.expected_path_m)  # ValueError names them
        if self.baseline is not None:
            self.config = replace(self.config, min_baseline_m=self.baseline)
            self.decide_depth = None
            self.get_logger().info(
                f'target_keyframes {cfg.target_keyframes} over expected_path_m {cfg.expected_path_m:g} m: '
                f'a keyframe every {self.baseline:.3g} m (replaces baseline_ratio x scene_depth_m and '
                'min_baseline_m)'
            )
        self.selector = KeyframeSelector(self.config)
        self.interval: IntervalSelector[tuple[np.ndarray, CameraInfo]] = IntervalSelector(
            self.poseless_interval, self.config
        )
        self.bad = BadInput(self)
        self.frames = StampAssembler(
            ('image', 'camera_info', 'pose'),
            cfg.max_pending,
            lambda detail: self.bad('incomplete', detail),
            supersede=True,  # a sensor stream arrives in order: older frames can no longer complete
            max_bytes=cfg.max_pending_bytes,
        )
        self.frames_seen = 0
        self.keyframes = 0
        self.decisions: Counter[str] = Counter()  # with poses: frames per final Decision.reason
        self._held: tuple[int, np.ndarray, CameraInfo, tuple[np.ndarray, str]] | None = None  # 'held'
        self.camera = 'waiting'
        self._images = self._images_at_tick = 0  # image messages handled, at the last graph tick
        info = lambda m: (m, msg_utils.camera_info_to_pinhole(m))  # noqa: E731
        pose_type, to_matrix = POSE_MESSAGES[cfg.pose_type]
        pose = lambda m: (to_matrix(m), m.header.frame_id or 'map')  # noqa: E731
        # field -> candidate (message type, topic, conversion), in order of preference.
        self._inputs: dict[str, list[tuple[type, str, Callable[[Any], Any]]]] = {
            'image': [
                (IMAGE_TYPES[t], t, msg_utils.camera_image_to_rgb)
                for t in IMAGE_TRANSPORTS[cfg.image_transport]
            ],
            'camera_info': [(CameraInfo, 'camera/camera_info', info)],
        }
        if cfg.pose_source != 'none':
            self._inputs['pose'] = [(pose_type, 'camera/pose', pose)]
        self.subscribed: dict[str, str] = {}  # field -> resolved topic
        out = model_qos()
        self.pub_image = self.create_publisher(Image, 'keyframes/image', out)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/camera_info', out)
        self.pub_pose = self.create_publisher(PoseStamped, 'keyframes/pose', out)
        self.pub_status = self.create_publisher(DiagnosticStatus, 'keyframes/status', latched_qos())
        self._status: FlightStatus | None = None
        self.diag = start_diagnostics(self, FRAME_SUBSAMPLER.diagnostics, self._diagnostics)
        self._publish_status()
        images = ' or '.join(self.resolve_topic_name(t) for _, t, _ in self._inputs['image'])
        self.get_logger().info(
            f'waiting for a publisher of {images} (image_transport {cfg.image_transport}); '
            f'pose_source {cfg.pose_source}'
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
                subscribe_field(self, msg_type, topic, qos, field, convert, self._put, self.bad, self.diag)
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
            elif (last := self.selector.flush()) is not None:  # a blurred last frame bridges no gap
                self.decisions[last.reason] += 1
                self._held = None
                self.get_logger().info(
                    f'the last frame was blurred and bridges no gap: dropped ({last.reason})'
                )
            self._publish_status()

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        return {
            'rejected': self.bad.counts,
            'queues': {
                'pending_frames': Queue(len(self.frames), self.frames.max_pending),
                'pending_bytes': Queue(self.frames.pending_bytes, self.frames.max_bytes or 0),
            },
            'model': {
                'frames': self.frames_seen,
                'keyframes': self.keyframes,
                'pose_source': self.pose_source.state,
                'camera': self.camera,
            },
        }

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
        self.diag.started(stamp)
        d = self.selector.decide(stamp, pose, blur_px(image), self.decide_depth)
        if d.previous is not None and self._held is not None:  # the held frame before this one
            self._decided(*self._held, d.previous)
        self._held = None
        if d.reason == 'held':  # blurred, decided with the next frame
            self._held = (stamp, image, info, (pose, pose_frame))
            self.get_logger().debug(f'frame {stamp}: blurred ({d.blur:.1f} px), held for the next frame')
        else:
            self._decided(stamp, image, info, (pose, pose_frame), d)
        self._publish_status()

    def _decided(
        self, stamp: int, image: np.ndarray, info: CameraInfo, pose: tuple[np.ndarray, str], d: Decision
    ) -> None:
        """Count the final decision ``d`` of a frame with a pose; publish the frame if kept."""
        self.decisions[d.reason] += 1
        if not d.keep:
            self.diag.discard(stamp)
            self.get_logger().debug(f'frame {stamp}: skipped ({d.reason}, blur {d.blur:.1f} px)')
            return
        self._publish(stamp, image, info, pose)
        why = 'blurred, kept for overlap' if d.reason == 'overlap' else d.reason
        self.get_logger().info(
            f'keyframe {self.keyframes} at {stamp} ns ({why}: baseline {d.baseline_m:.1f} m, '
            f'rotation {d.rotation_deg:.1f} deg, blur {d.blur:.1f} px; {self.frames_seen} frames '
            f'seen, {self.decisions["blurred"]} dropped as blurred)'
        )

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
        self.diag.published('keyframes')
        self.diag.finished(stamp)

    # -- without poses ----------------------------------------------------------------------------
    def _poseless_frame(self, stamp: int, partial: dict) -> None:
        image, (info, camera) = partial['image'], partial['camera_info']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        self.frames_seen += 1
        self.diag.started(stamp)
        blur = blur_px(image)
        if blur > self.config.max_blur_px > 0:
            self.get_logger().debug(f'frame {stamp}: blurred ({blur:.1f} px)')
        self._publish_poseless(self.interval.push(stamp, blur, (image, info), detail=detail_score(image)))
        self._publish_status()

    def _publish_poseless(self, chosen: list[Pick[tuple[np.ndarray, CameraInfo]]]) -> None:
        for pick in chosen:
            image, info = pick.item
            self._publish(pick.stamp, image, info, None)
            why = (
                f'the sharpest frame of its {self.poseless_interval:g} s window'
                if pick.reason == 'sharpest'
                else 'blurred, kept for overlap: its window has no sharp frame'
            )
            self.get_logger().info(
                f'keyframe {self.keyframes} at {pick.stamp} ns (no pose: {why}; {self.frames_seen} frames '
                f'seen, {self.interval.rejected["blurred"]} dropped as blurred)'
            )


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSubsampler, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
