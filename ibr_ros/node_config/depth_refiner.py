# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The depth_refiner's parameter table and the configuration built from it (no rclpy)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, cast

from ibr_ros.core.depth.mvs import MvsOptions
from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.depth.schedule import ScheduleConfig, parse_depth_range
from ibr_ros.core.registration.sfm_session import ScaleHint, ScaleKind
from ibr_ros.core.registration.trigger import SFM_MODES, SfmConfig, SfmMode
from ibr_ros.errors import UserError
from ibr_ros.models import mono_spec, sky_spec
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Topic,
    Values,
)

__all__ = ['DEBUG_TOPICS', 'DEPTH_REFINER', 'SFM_MODES', 'SFM_SCALES', 'DepthRefinerConfig']

#: ``sfm_scale``: what ``sfm_scale_m`` measures (see :class:`ScaleHint`), or 'none'.
SFM_SCALES = ('none', 'baseline', 'altitude', 'depth')

#: Debug topics published with ``publish_debug``.
DEBUG_TOPICS = ('depth/mvs', 'depth/mono_remapped', 'depth/sky_mask', 'depth/preview', 'depth/mvs/preview')


@dataclass(frozen=True)
class DepthRefinerConfig:
    """What the depth_refiner node (and ``ibr process``'s refinement) run with.

    ``schedule`` holds the MVS options (``schedule.mvs``, the only copy); ``flush_after_s``: 0 =
    flush only when the camera stream ended; ``worker_lease_s``: a silent sharded worker is dead
    after this long (s); ``max_pending_bytes`` bounds keyframes waiting for their other messages;
    ``notes``: start-up remarks for the log (a parameter that acts differently than set).
    """

    schedule: ScheduleConfig
    refiner: RefinerConfig
    sfm: SfmConfig
    flush_after_s: float
    worker_lease_s: float
    mirror_model: bool
    publish_debug: bool
    max_pending: int
    max_pending_bytes: int
    warmup: bool
    notes: tuple[str, ...] = ()

    @property
    def mvs(self) -> MvsOptions:
        """The MVS options (``schedule.mvs``)."""
        return self.schedule.mvs


def _refiner(v: Values) -> RefinerConfig:
    """``mono*`` and ``sky*`` as a :class:`RefinerConfig` (models resolved, not loaded)."""
    mono, sky = v.text('mono'), v.text('sky')
    return RefinerConfig(
        mono=cast(Literal['plane', 'onnx'], mono),  # one of the parameter's choices
        mono_model=mono_spec(v.text('mono_model'), v.text('mono_preset')) if mono == 'onnx' else None,
        sky=cast(Literal['fallback', 'onnx', 'none'], sky),  # one of the parameter's choices
        sky_model=sky_spec(v.text('sky_model'), v.text('sky_preset')) if sky == 'onnx' else None,
    )


def _sfm(v: Values, num_workers: int) -> tuple[SfmConfig, tuple[str, ...]]:
    """The SfM settings and start-up notes; UserError for combinations the table cannot express."""
    mode, scale, scale_m = v.text('sfm_mode'), v.text('sfm_scale'), v.number('sfm_scale_m')
    hint = None
    if scale != 'none':
        if scale_m <= 0:
            raise UserError(f'parameter sfm_scale_m must be > 0 with sfm_scale {scale!r}, got {scale_m}')
        hint = ScaleHint(cast(ScaleKind, scale), scale_m)  # one of the parameter's choices
    notes: tuple[str, ...] = ()
    if num_workers > 1 and mode == 'always':
        raise UserError(
            f"parameter sfm_mode 'always' needs num_workers 1 (one SfM registration per graph), "
            f'got num_workers {num_workers}'
        )
    if num_workers > 1 and mode == 'auto':
        mode = 'off'
        notes = ('num_workers > 1: sfm_mode auto acts as off (one SfM registration per graph)',)
    config = SfmConfig(
        mode=cast(SfmMode, mode),  # one of the parameter's choices
        min_keyframes=v.integer('sfm_min_keyframes'),
        every=v.integer('sfm_every'),
        max_side=v.integer('sfm_max_side'),
        scale=hint,
    )
    return config, notes


def _build(v: Values) -> DepthRefinerConfig:
    num_workers = v.integer('num_workers')
    sfm, notes = _sfm(v, num_workers)
    try:
        schedule = ScheduleConfig(
            num_workers=num_workers,
            worker_index=v.integer('worker_index'),
            min_neighbours=v.integer('min_neighbours'),
            refine_again=v.flag('refine_again'),
            reuse_neighbour_depth=v.flag('reuse_neighbour_depth'),
            depth_range=parse_depth_range(v.numbers('depth_range')),
            scene_depth_m=v.number('scene_depth_m'),
            near_ratio=v.number('near_ratio'),
            far_ratio=v.number('far_ratio'),
            mvs=MvsOptions(
                max_neighbours=v.integer('max_neighbours'),
                neighbour_sources=v.integer('neighbour_sources'),
                neighbour_roi=v.flag('neighbour_roi'),
            ),
        )
    except ValueError as exc:  # names the parameters (ScheduleConfig's fields have their names)
        raise UserError(f'parameter {exc}') from exc
    return DepthRefinerConfig(
        schedule=schedule,
        refiner=_refiner(v),
        sfm=sfm,
        flush_after_s=v.number('flush_after_s'),
        worker_lease_s=v.number('worker_lease_s'),
        mirror_model=v.flag('mirror_model'),
        publish_debug=v.flag('publish_debug'),
        max_pending=v.integer('max_pending'),
        max_pending_bytes=round(v.number('max_pending_mb') * 2**20),
        warmup=v.flag('warmup'),
        notes=notes,
    )


_MODEL = 'reliable, transient local'

DEPTH_REFINER: ParamTable[DepthRefinerConfig] = ParamTable(
    node='depth_refiner',
    summary=(
        'MVS and refined depth with a per-pixel confidence for every keyframe (plane-sweep MVS, '
        'monocular depth remapped to it, MST fusion, sky as +inf), shardable over several processes. A '
        'keyframe is refined once `min_neighbours` source views with enough overlap and parallax are '
        'there, or with one when the camera stream ended; keyframes without poses are registered with '
        "SfM (`sfm_mode`), whose sparse points then bound and seed each keyframe's depth."
    ),
    params=(
        Param(
            'num_workers',
            1,
            'refiner processes sharing the keyframes (each keyframe refined by exactly one)',
            (1, 1024),
            comment="Each worker receives all keyframes (they are everybody's neighbours) but refines "
            'those whose stamp hashes to its worker_index; a worker silent for worker_lease_s is dead '
            'and its unrefined keyframes go to the live ones. A keyframe whose depth is already '
            'published is never refined again, so a restarted worker picks up where it stopped.',
        ),
        Param(
            'worker_index',
            0,
            'this process: 0 .. num_workers - 1 (keyframe stamp hash % num_workers)',
            (0, 1023),
        ),
        Param(
            'min_neighbours',
            2,
            'refine a keyframe once MVS neighbour selection finds this many source views',
            (1, 16),
        ),
        Param(
            'max_neighbours',
            4,
            'MVS source views per keyframe (2: about a third of the MVS work of 4, less complete)',
            (1, 16),
        ),
        Param(
            'flush_after_s',
            0.0,
            'also refine with >= 1 neighbour after this long without keyframes (s); 0 = only when '
            'keyframes/status says the camera stream ended',
            (0.0, 1e6),
        ),
        Param(
            'worker_lease_s',
            3.0,
            'sharded: a worker whose heartbeat is silent this long is dead, its keyframes taken over',
            (0.1, 1e6),
        ),
        Param(
            'mirror_model',
            True,
            'republish each keyframe that has depth (image, camera_info, pose, depth): the model outlives '
            'the frame_subsampler and any one refiner',
        ),
        Param(
            'refine_again',
            False,
            'refine (and republish) a keyframe again when more neighbours become available',
        ),
        Param(
            'reuse_neighbour_depth',
            False,
            "reuse each keyframe's photometric MVS depth as a neighbour in later keyframes' geometric "
            'filter (about 1.6 sweeps per keyframe instead of 1 + max_neighbours, ~3x faster MVS; '
            'less accurate on real photos)',
            comment="Off: each keyframe's neighbours are swept again within its job, against the views of "
            'that job (with neighbour_roi only where they see the keyframe). On: their depth comes from '
            'a cache of the 48 most recent maps. Measured with '
            '`ibr eval rephoto bags/sheffield_cross`: mean error 5.86 -> 6.04, worst 1 % 26.3 -> 29.2 '
            '(synthetic accuracy unchanged); see bench/README.md.',
        ),
        Param(
            'neighbour_roi',
            True,
            "sweep each neighbour only over the pixels and depths where the keyframe's photometric depth "
            "projects (its depth only confirms the keyframe's; without reuse_neighbour_depth)",
            comment='The rest of a neighbour can confirm nothing; the depths swept end where enough of the '
            "keyframe's pixels project (the sweep's sparse outliers do not stretch them). Measured on 12 "
            'jobs of the 39-photo sheffield survey at 1000x750: 0.65x the MVS work and 0.72x the CPU of '
            'whole neighbour sweeps, completeness 0.7095 (whole: 0.7072); `ibr eval rephoto` of both real '
            'captures as good. See bench/README.md.',
        ),
        Param(
            'neighbour_sources',
            0,
            "source views of each neighbour's sweep: the keyframe and the best others; 0 = up to "
            'max_neighbours of the views of its job (2: about half the MVS work, less complete)',
            (0, 16),
            comment='Measured on bags/sheffield_cross jobs: 2 sources give 0.49x the work and keep 89 % '
            "of the default's MVS pixels (synthetic orbit: 0.70x, 85 %). See bench/README.md.",
        ),
        Param(
            'depth_range',
            [0.0, 0.0],
            'MVS sweep [near, far] in metres; [0, 0] = near_ratio/far_ratio x scene depth',
        ),
        Param(
            'scene_depth_m',
            0.0,
            "scene depth at the image centre (m); 0 = from the optical axes' convergence",
            (0.0, 1e6),
            comment='Estimated: the median distance along the optical axis to where it passes closest to '
            'the axes of the other keyframes (3-90 deg apart, in front of both; oblique and orbit '
            'flights), else (parallel axes, a nadir survey) 12.5 x the mean distance to the two nearest '
            'keyframes, with a warning to set it.',
        ),
        Param('near_ratio', 0.25, 'near = near_ratio x scene depth', (1e-3, 1.0)),
        Param(
            'far_ratio',
            1000.0,
            'far = far_ratio x scene depth',
            (1.0, 1e4),
            comment='The sweep is uniform in inverse depth: a far end beyond the horizon costs a few '
            'planes (1000 against 4: about 6 % more) and lets MVS measure distant ground on oblique '
            'flights.',
        ),
        Param(
            'mono',
            'plane',
            "monocular depth: 'plane' (geometric ground-plane prior) or 'onnx' (mono_model)",
            choices=('plane', 'onnx'),
        ),
        Param(
            'mono_model',
            'ibr_mono',
            "with mono 'onnx': 'ibr_mono' (shipped), a model fetched by `ibr models fetch`, or an .onnx path",
            comment='A bad model or preset (unknown name, missing or unloadable file) stops the node at '
            'start-up with one error line naming the parameter (exit status 2).',
        ),
        Param(
            'mono_preset',
            '',
            "I/O convention of mono_model (ibr_ros.core.depth.mono.PRESETS); '' = the named model's own",
        ),
        Param(
            'sky',
            'fallback',
            "sky mask: 'fallback' (horizon + colour cues), 'onnx' (sky_model) or 'none'",
            choices=('fallback', 'onnx', 'none'),
        ),
        Param(
            'sky_model',
            'ibr_mono',
            "with sky 'onnx': 'ibr_mono' (shipped, its sky head) or an .onnx path",
        ),
        Param(
            'sky_preset',
            '',
            "I/O convention of sky_model (ibr_ros.core.depth.sky.SKY_PRESETS); '' = the named model's own",
        ),
        Param('publish_debug', False, 'publish ' + ', '.join(DEBUG_TOPICS)),
        Param(
            'max_pending',
            30,
            'keyframes kept while waiting for their image, camera_info and pose',
            (1, 10000),
        ),
        Param(
            'max_pending_mb',
            128.0,
            'pending frames (waiting for their other messages) hold at most this many MiB',
            (1.0, 1e6),
        ),
        Param(
            'sfm_mode',
            'auto',
            "keyframes without poses: 'auto' (SfM when keyframes/status says the flight has no poses), "
            "'always' (ignore poses) or 'off'",
            choices=SFM_MODES,
            comment="'auto' never starts on a timer: until the status comes, keyframes wait for their "
            "poses, however late. With num_workers > 1 'always' is a start-up error and 'auto' acts as "
            "'off' (one registration per graph). With 'off' keyframes without a pose are not refined.",
        ),
        Param(
            'sfm_min_keyframes',
            4,
            'keyframes of the first SfM registration',
            (3, 10000),
        ),
        Param(
            'sfm_every',
            2,
            'register all keyframes again after this many new ones (and when flushing)',
            (1, 10000),
        ),
        Param(
            'sfm_max_side',
            640,
            'longest image side (px) SfM works at; 0 = as received',
            (0, 100000),
        ),
        Param(
            'sfm_scale',
            'none',
            "SfM frame unit: 'none' (first keyframe baseline = 1), or sfm_scale_m metres is the "
            "'baseline' (first two keyframes), 'altitude' (first keyframe above ground), 'depth' (median)",
            choices=SFM_SCALES,
            comment="'depth': the median depth of the sparse points. Depth maps are in the frame's unit; "
            'without a scale depth_range and scene_depth_m (metres) are ignored.',
        ),
        Param('sfm_scale_m', 0.0, 'metres of the sfm_scale length', (0.0, 1e7)),
        Param(
            'warmup',
            True,
            'run MVS + refinement on a tiny scene at start-up, so the first keyframe is not slow',
        ),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    subscribes=(
        Topic('keyframes/image', 'sensor_msgs/Image', 'keyframe images, matched by header stamp', _MODEL),
        Topic('keyframes/camera_info', 'sensor_msgs/CameraInfo', 'their intrinsics', _MODEL),
        Topic(
            'keyframes/pose',
            'geometry_msgs/PoseStamped',
            'camera-to-world pose of the optical frame (ignored in SfM mode: then it carries this '
            "node's own poses)",
            _MODEL,
        ),
        Topic(
            'keyframes/status',
            'diagnostic_msgs/DiagnosticStatus',
            "the frame_subsampler's flight status: whether the flight has poses (SfM mode) and whether the "
            'camera stream ended (refine what is left with one neighbour too)',
            'reliable, transient local, latest only',
        ),
        Topic(
            'keyframes/depth',
            'sensor_msgs/Image',
            "other workers' depth (and keyframes/depth/camera_info, keyframes/depth/confidence): a "
            'keyframe with published depth is not refined here, and is mirrored once (with `mirror_model`)',
            _MODEL,
        ),
        Topic(
            'refiners/heartbeat',
            'diagnostic_msgs/DiagnosticStatus',
            "with num_workers > 1: the other workers' heartbeats (index, published depth)",
            'reliable',
        ),
    ),
    publishes=(
        Topic(
            'keyframes/depth',
            'sensor_msgs/Image',
            "refined depth, 32FC1 metres (REP-118: NaN unknown, +inf sky); the keyframe's stamp",
            _MODEL,
        ),
        Topic(
            'keyframes/depth/confidence',
            'sensor_msgs/Image',
            'per-pixel confidence of the depth, 32FC1 in [0, 1] (>= 0.5: MVS depth, more the better its '
            'match and the more views confirm it, or an SfM point; below: filled along the image MST and '
            'from the monocular depth; 0: unknown); '
            "published just before the depth, the keyframe's stamp",
            _MODEL,
        ),
        Topic(
            'keyframes/depth/camera_info',
            'sensor_msgs/CameraInfo',
            "the depth's intrinsics (the keyframe's); the keyframe's stamp",
            _MODEL,
        ),
        Topic(
            'keyframes/image, keyframes/camera_info',
            'sensor_msgs/Image, sensor_msgs/CameraInfo',
            'with `mirror_model`: each keyframe that has depth (its own or mirrored), once, so that the '
            'model outlives the frame_subsampler',
            _MODEL,
        ),
        Topic(
            'keyframes/pose',
            'geometry_msgs/PoseStamped',
            'with `mirror_model`, the pose of each keyframe that has depth; in SfM mode each newly '
            "registered keyframe's pose, once (frame `sfm`: z up, origin on the ground below the first "
            'registered keyframe, x its viewing direction; unit: the first baseline or `sfm_scale`; '
            'later registrations are aligned to the earlier ones)',
            _MODEL,
        ),
        Topic(
            'refiners/heartbeat',
            'diagnostic_msgs/DiagnosticStatus',
            'with num_workers > 1: this worker, every worker_lease_s / 3 s',
            'reliable',
        ),
        Topic(
            'depth/mvs, depth/mono_remapped, depth/sky_mask',
            'sensor_msgs/Image',
            'with `publish_debug`: MVS and remapped monocular depth (32FC1), sky mask (mono8, 255 = sky)',
            'reliable',
        ),
        Topic(
            'depth/preview, depth/mvs/preview',
            'sensor_msgs/Image',
            'with `publish_debug`: rgb8 turbo-coloured inverse depth, black where unknown',
            'reliable',
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=('image', 'camera_info', 'pose'),
        outputs=('depth', 'mirrored', 'sfm_pose'),
        latency='from the keyframe complete (image, camera_info and pose; SfM: its pose registered) to '
        'its first depth published by this worker (waiting for neighbours included)',
        reasons=(
            ('image', 'malformed keyframes/image'),
            ('camera_info', 'malformed camera_info or not the size of its image'),
            ('pose', 'malformed keyframes/pose'),
            ('incomplete', 'a keyframe given up before all its messages arrived'),
            ('depth', "another worker's depth malformed or without a known value"),
            ('mirror', "another worker's depth whose keyframe never came"),
            ('status', 'malformed keyframes/status'),
            ('heartbeat', 'malformed refiners/heartbeat'),
            ('neighbours', 'a degenerate keyframe set (e.g. coincident cameras)'),
            ('refine', 'a failed refinement'),
            ('sfm', 'a keyframe SfM could not take'),
            ('lost', 'messages DDS reports lost'),
            ('incompatible_qos', 'a publisher whose QoS cannot match'),
        ),
        queues=(
            ('pending_keyframes', 'keyframes waiting for their other messages (bound `max_pending`)'),
            ('pending_bytes', 'bytes they hold (bound `max_pending_mb`)'),
            ('unrefined', "this worker's keyframes not refined yet"),
            ('sfm_queue', 'keyframes waiting for SfM registration'),
            ('mirror_pending', "other workers' depth waiting for its keyframe (bound `max_pending`)"),
        ),
        model=(
            ('keyframes', 'keyframes held'),
            ('refined', "this worker's keyframes refined"),
            ('published', 'keyframes whose depth this process published (own or mirrored)'),
            ('bytes', 'bytes of the keyframe images held'),
            ('sfm_mode', '`auto`, `always` or `off`'),
            ('sfm_active', 'whether keyframe poses are registered here (SfM mode)'),
        ),
    ),
)
