# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The frame_subsampler's parameter table and the configuration built from it."""

from __future__ import annotations

from dataclasses import dataclass

from ibr_ros.core.flight.keyframes import KeyframeConfig
from ibr_ros.core.flight.status import IMAGE_TRANSPORTS, POSE_MODES
from ibr_ros.errors import UserError
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Topic,
    Values,
)

__all__ = ['FRAME_SUBSAMPLER', 'POSE_TYPE_CHOICES', 'FrameSubsamplerConfig']

#: ``pose_type`` values: the message type of ``camera/pose``.
POSE_TYPE_CHOICES = ('pose', 'odometry')


@dataclass(frozen=True)
class FrameSubsamplerConfig:
    """What the frame_subsampler node (and ``ibr process``'s keyframe selection) run with.

    ``keyframes``: the selector's thresholds; ``scene_depth_m`` 0 = unknown (``min_baseline_m``
    applies); ``target_keyframes`` 0 = off; ``max_pending_bytes`` bounds frames waiting for their
    other messages (``max_pending`` of them at most).
    """

    keyframes: KeyframeConfig
    image_transport: str
    pose_type: str
    pose_source: str
    scene_depth_m: float
    poseless_interval_s: float
    target_keyframes: int
    expected_path_m: float
    max_pending: int
    max_pending_bytes: int


def _build(v: Values) -> FrameSubsamplerConfig:
    try:
        keyframes = KeyframeConfig(
            baseline_ratio=v.number('baseline_ratio'),
            min_baseline_m=v.number('min_baseline_m'),
            max_rotation_deg=v.number('max_rotation_deg'),
            max_interval_s=v.number('max_interval_s'),
            min_interval_s=v.number('min_interval_s'),
            max_blur_px=v.number('max_blur_px'),
            overlap_gap=v.number('overlap_gap'),
        )
    except ValueError as exc:
        raise UserError(f'bad frame_subsampler parameter: {exc}') from exc
    return FrameSubsamplerConfig(
        keyframes=keyframes,
        image_transport=v.text('image_transport'),
        pose_type=v.text('pose_type'),
        pose_source=v.text('pose_source'),
        scene_depth_m=v.number('scene_depth_m'),
        poseless_interval_s=v.number('poseless_interval_s'),
        target_keyframes=v.integer('target_keyframes'),
        expected_path_m=v.number('expected_path_m'),
        max_pending=v.integer('max_pending'),
        max_pending_bytes=round(v.number('max_pending_mb') * 2**20),
    )


_LIM = (0.0, 1e6)
_MODEL = 'reliable, transient local'
_INPUT = 'reliable keep-all if all its publishers offer reliable, else best effort'

FRAME_SUBSAMPLER: ParamTable[FrameSubsamplerConfig] = ParamTable(
    node='frame_subsampler',
    summary=(
        'Picks sharp, well-spaced keyframes from a camera stream (video or survey stills): a sharp frame '
        '(edges at most `max_blur_px` wide) becomes a keyframe when the camera moved `baseline_ratio` x '
        '`scene_depth_m` (else `min_baseline_m`) from the last one, turned `max_rotation_deg` or after '
        '`max_interval_s`. Without poses (`pose_source`) the sharpest frame of every `poseless_interval_s` '
        'window is one, published without `keyframes/pose`. A blurred frame is kept anyway when the gap '
        'between keyframes would exceed `overlap_gap` spacings without it (stills needed for overlap).'
    ),
    params=(
        Param(
            'image_transport',
            'auto',
            "camera image topic: 'auto' = camera/image_raw or camera/image_raw/compressed, whichever has "
            'a publisher (raw when both)',
            choices=tuple(IMAGE_TRANSPORTS),
        ),
        Param(
            'pose_type',
            'pose',
            "message type of camera/pose: 'pose' = geometry_msgs/PoseStamped, 'odometry' = nav_msgs/Odometry",
            choices=POSE_TYPE_CHOICES,
        ),
        Param(
            'scene_depth_m',
            0.0,
            'typical scene depth in metres; 0 = unknown (min_baseline_m applies)',
            (0.0, 1e5),
        ),
        Param(
            'baseline_ratio', 0.08, 'keyframe when the camera moved this fraction of the scene depth', _LIM
        ),
        Param('min_baseline_m', 2.0, '... or this many metres when the scene depth is unknown', _LIM),
        Param('max_rotation_deg', 15.0, '... or turned this much', _LIM),
        Param('max_interval_s', 0.0, '... or this much time passed (0 = off)', _LIM),
        Param(
            'target_keyframes',
            0,
            'about this many keyframes per flight (0 = off); live it needs expected_path_m',
            (0, 1_000_000),
            comment='Live it uses ONE baseline, expected_path_m / target_keyframes, in place of '
            'baseline_ratio x scene_depth_m and min_baseline_m; ibr process (with poses) bisects a common '
            'scale of those two over the whole flight instead (select_keyframes).',
        ),
        Param(
            'expected_path_m',
            0.0,
            'planned flight path length (m), needed live by target_keyframes (ibr process: unused)',
            _LIM,
        ),
        Param('min_interval_s', 0.0, 'never two keyframes closer in time than this', _LIM),
        Param(
            'max_blur_px',
            3.0,
            'a frame is blurred (dropped) when its edges are wider than this many pixels (the image '
            'shrunk to 1000 px on its long side); one absolute threshold for video and stills, 0 = off',
            (0.0, 1000.0),
            comment='Blur is measured as an edge width, independent of how much texture the scene has: '
            'sharp photos of the shipped bags measure 1.9-2.4 px, the same photos after a Gaussian blur '
            'of sigma 1 px 3.3-3.9 px. No frame is compared with its neighbours (survey stills seconds '
            'apart show different content). Raise it for a soft camera: keyframes are logged with their '
            'blur.',
        ),
        Param(
            'overlap_gap',
            2.0,
            'a blurred frame is kept anyway when the frame after it is more than this many keyframe '
            'spacings from the last keyframe (0 = off, else >= 1)',
            (0.0, 1000.0),
            comment='The spacing is the baseline, rotation or interval rule that makes a keyframe, or '
            'poseless_interval_s without poses. Without the blurred frame the gap between keyframes would '
            "exceed overlap_gap spacings (survey stills seconds apart: each is needed for its neighbours' "
            'overlap); video has a sharp frame within the gap. Counted and logged as kept for overlap; '
            'a blurred frame that would have been a keyframe is published one frame late, if kept.',
        ),
        Param(
            'max_pending', 30, 'frames kept while waiting for their image, camera_info and pose', (1, 10000)
        ),
        Param(
            'max_pending_mb',
            128.0,
            'pending frames (waiting for their other messages) hold at most this many MiB',
            (1.0, 1e6),
        ),
        Param(
            'pose_source',
            'auto',
            "whether the flight has poses: 'auto' = iff camera/pose has a publisher when the first frame is "
            "complete, 'topic' = always (wait for camera/pose), 'none' = never (keyframes without poses)",
            choices=POSE_MODES,
            comment='No timer decides: a live drone whose pose node may start after its camera should use '
            "'topic'. Poses arriving after a decision for 'none' are counted (pose_ignored) and dropped.",
        ),
        Param(
            'poseless_interval_s',
            1.0,
            'without poses: the sharpest frame of every this-many-seconds window is a keyframe',
            (1e-3, 1e6),
        ),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    subscribes=(
        Topic('camera/image_raw', 'sensor_msgs/Image', 'camera images (image_transport raw or auto)', _INPUT),
        Topic(
            'camera/image_raw/compressed',
            'sensor_msgs/CompressedImage',
            'camera images (image_transport compressed, or auto without a raw publisher)',
            _INPUT,
        ),
        Topic('camera/camera_info', 'sensor_msgs/CameraInfo', 'their intrinsics', _INPUT),
        Topic(
            'camera/pose',
            'geometry_msgs/PoseStamped',
            'camera-to-world pose of the optical frame in `map` (`nav_msgs/Odometry` with pose_type '
            'odometry)',
            _INPUT,
        ),
    ),
    publishes=(
        Topic('keyframes/image', 'sensor_msgs/Image', "rgb8 keyframes, the frame's header stamp", _MODEL),
        Topic('keyframes/camera_info', 'sensor_msgs/CameraInfo', 'their intrinsics, same stamp', _MODEL),
        Topic(
            'keyframes/pose',
            'geometry_msgs/PoseStamped',
            'their camera-to-world poses, same stamp (none without poses)',
            _MODEL,
        ),
        Topic(
            'keyframes/status',
            'diagnostic_msgs/DiagnosticStatus',
            'on every change: pose source (pose / none), camera stream (waiting / streaming / ended: '
            'every camera publisher gone), frames and keyframes so far',
            'reliable, transient local, depth 1',
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=('image', 'camera_info', 'pose'),
        outputs=('keyframes',),
        latency='from the frame complete (its image, camera_info and pose arrived) to its keyframe published '
        '(a blurred frame held for the next one, a pose-less frame until its window closes)',
        reasons=(
            ('image', 'malformed image'),
            ('camera_info', 'malformed camera_info or not the size of its image'),
            ('pose', 'malformed pose'),
            ('incomplete', 'a frame given up before all its messages arrived'),
            ('pose_ignored', 'a pose in a flight decided to be without poses'),
            ('lost', 'messages DDS reports lost (best effort)'),
            ('incompatible_qos', 'a publisher whose QoS cannot match'),
        ),
        queues=(
            ('pending_frames', 'frames waiting for their other messages (bound `max_pending`)'),
            ('pending_bytes', 'bytes they hold (bound `max_pending_mb`)'),
        ),
        model=(
            ('frames', 'complete frames received'),
            ('keyframes', 'keyframes published'),
            ('pose_source', '`pose`, `none` or `unknown`'),
            ('camera', '`waiting`, `streaming` or `ended`'),
        ),
    ),
)
