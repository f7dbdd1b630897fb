# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The view_renderer's parameter table and the configuration built from it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ibr_ros.core.render import RenderConfig, ReplyPolicy
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

__all__ = ['INTRINSICS', 'VIEW_RENDERER', 'ViewRendererConfig', 'render_config']

#: The output-intrinsics parameters, settable at run time.
INTRINSICS = ('width', 'height', 'hfov_deg')

#: Parameters that configure the renderer itself (:class:`RenderConfig` fields, same names).
_RENDER = (
    Param(
        'blend',
        'ulr',
        "'ulr' (weights 1 - p / p_max), 'paper' (smallest angle penalty wins), 'soft' or 'stable' "
        '(weights continuous in the pose: no flicker while navigating)',
        choices=('paper', 'soft', 'ulr', 'stable'),
    ),
    Param('stable_sigma_deg', 4.0, "blend 'stable': weights exp(-penalty / this) (deg)", (0.01, 1e3)),
    Param(
        'stable_fade',
        0.3,
        "blend 'stable': a view fades out over this fraction of the distance of the nearest view left out",
        (0.01, 1.0),
    ),
    Param('n_views', 4, 'source views per query', (1, 4)),
    Param('n_segments', 1500, 'SLIC superpixels per source view', (16, 100000)),
    Param(
        'depth_split',
        0.02,
        'split superpixels at depth steps above this (log depth, 0.02 = 2 %), 0 = off',
        (0.0, 10.0),
        comment='Additions to the paper renderer (0 = off). The paper exactly: blend paper, depth_split, '
        'coverage_px, depth_tolerance, resolution_weight_deg, confidence_weight_deg, fill_holes_px and '
        'depth_lookup_steps 0, min_depth_samples 10.',
    ),
    Param(
        'coverage_px',
        1.0,
        'a warped superpixel claims a pixel only if its source pixel reprojects this close (px), 0 = off',
        (0.0, 1e3),
    ),
    Param(
        'depth_tolerance',
        0.5,
        "views vote on each pixel's depth (agree = within a factor 1 + this); the majority blends; 0 = off",
        (0.0, 1e3),
    ),
    Param(
        'resolution_weight_deg',
        40.0,
        'angle penalty (deg) added per unit of the ULR resolution term',
        (0.0, 1e3),
    ),
    Param(
        'depth_lookup_steps',
        2,
        'Newton steps moving each colour lookup to where the source depth puts the pixel, 0 = off',
        (0, 10),
    ),
    Param('depth_lookup_max_px', 1.0, 'largest depth correction of the colour lookup (px)', (0.01, 1e3)),
    Param(
        'depth_lookup_min_fit_px',
        0.08,
        'correct only superpixels whose affine warp misses its samples by more (RMS px)',
        (0.0, 1e3),
    ),
    Param(
        'min_depth_samples',
        2,
        'known-depth pixels a superpixel needs to be warped (the paper: 10)',
        (1, 100000),
    ),
    Param(
        'confidence_weight_deg',
        10.0,
        'angle penalty (deg) per unit of missing depth confidence (keyframes/depth/confidence): low '
        'confidence loses the blend, 0 = off',
        (0.0, 1e3),
    ),
    Param(
        'fill_holes_px',
        256,
        'holes of a view up to this many pixels, not touching its border (cracks between superpixels), '
        'are filled from their surroundings; 0 = off',
        (0, 1000000),
    ),
    Param(
        'sky_depth_factor',
        2.0,
        "sky (+inf depth) is warped at this x the view's largest depth (the paper's Eq. 14: 2); 0 = as "
        'directions (rotation only)',
        (0.0, 1e3),
    ),
    Param(
        'max_axis_angle_deg',
        90.0,
        'source views facing farther away than this are ignored (deg)',
        (1.0, 180.0),
    ),
    Param(
        'far_factor',
        3.0,
        'queries farther than this x the median scene depth from every view are refused',
        (0.01, 1e6),
    ),
    Param('max_cached_views', 64, 'per-view superpixel/warp caches kept (LRU)', (1, 100000)),
)

#: RenderConfig fields that are None (off) at 0.
_OFF_AT_ZERO = ('depth_split', 'coverage_px', 'depth_tolerance')


@dataclass(frozen=True)
class ViewRendererConfig:
    """What the view_renderer node (and ``ibr process``'s novel views) run with.

    ``width`` / ``height`` (px) / ``hfov_deg``: 0 takes the latest keyframe's. ``reply``: which renders
    answer a query (``min_valid_fraction``, ``publish_incomplete``). ``max_pending_bytes`` bounds
    keyframes waiting for their other messages.
    """

    render: RenderConfig
    width: int
    height: int
    hfov_deg: float
    reply: ReplyPolicy
    frame_id: str
    max_keyframes: int
    max_pending_bytes: int
    warmup: bool
    jpeg_quality: int = 90


def render_config(values: Mapping[str, object]) -> RenderConfig:
    """The renderer parameters among ``values`` (missing ones take their defaults) as a
    :class:`RenderConfig`; a bad value is a :class:`UserError` naming the parameter."""
    checked = VIEW_RENDERER.values({p.name: values[p.name] for p in _RENDER if p.name in values})
    fields: dict[str, object] = {p.name: checked[p.name] for p in _RENDER}
    for name in _OFF_AT_ZERO:
        fields[name] = fields[name] or None
    try:
        return RenderConfig(**fields)  # type: ignore[arg-type]  # names and types are RenderConfig's
    except ValueError as exc:
        raise UserError(f'bad view_renderer parameter: {exc}') from exc


def _build(v: Values) -> ViewRendererConfig:
    return ViewRendererConfig(
        render=render_config(v),
        width=v.integer('width'),
        height=v.integer('height'),
        hfov_deg=v.number('hfov_deg'),
        reply=ReplyPolicy(v.number('min_valid_fraction'), v.flag('publish_incomplete')),
        frame_id=v.text('frame_id'),
        max_keyframes=v.integer('max_keyframes'),
        max_pending_bytes=round(v.number('max_pending_mb') * 2**20),
        warmup=v.flag('warmup'),
        jpeg_quality=v.integer('jpeg_quality'),
    )


VIEW_RENDERER: ParamTable[ViewRendererConfig] = ParamTable(
    node='view_renderer',
    summary=(
        'Answers novel-view queries from the keyframe model: the superpixel shape-preserving warp of the '
        '4 nearest keyframes, a depth test and blending. A query is answered only when at least '
        '`min_valid_fraction` of the pixels was rendered; queries waiting while one renders are '
        'superseded by the newest (counted). Every query gets one `novel_view/status` with its '
        'stamp: answered, or refused and why, with the rendered fraction.'
    ),
    params=(
        Param('width', 0, "output width (px); 0 = the latest keyframe's", (0, 16384), dynamic=True),
        Param('height', 0, "output height (px); 0 = the latest keyframe's", (0, 16384), dynamic=True),
        Param(
            'hfov_deg',
            0.0,
            "output horizontal field of view (deg); 0 = the latest keyframe's",
            (0.0, 179.0),
            dynamic=True,
        ),
        Param(
            'min_valid_fraction',
            0.7,
            'reply only when at least this fraction of the pixels was rendered',
            (0.0, 1.0),
            comment='Measured (bench/README.md, Valid fraction): on the real and synthetic bags every view '
            'at least 70 % rendered beats showing the nearest keyframe photo; below 0.7 they start to lose.',
        ),
        Param(
            'publish_incomplete',
            False,
            'publish views below min_valid_fraction too (their status says incomplete, level WARN)',
        ),
        Param('frame_id', 'novel_view_optical', 'header.frame_id of the replies'),
        Param(
            'jpeg_quality',
            90,
            'JPEG quality of novel_view/image/compressed (for viewers over slow links; encoded only while '
            'it has a subscriber); 0 = not published',
            (0, 100),
        ),
        *_RENDER,
        Param('max_keyframes', 1000, 'keyframes kept in the model', (1, 100000)),
        Param(
            'max_pending_mb',
            128.0,
            'pending frames (waiting for their other messages) hold at most this many MiB',
            (1.0, 1e6),
        ),
        Param('warmup', True, 'render a tiny scene at start-up so that the first query is fast'),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    subscribes=(
        Topic('keyframes/image', 'sensor_msgs/Image', 'keyframe images', 'reliable, transient local'),
        Topic(
            'keyframes/camera_info', 'sensor_msgs/CameraInfo', 'their intrinsics', 'reliable, transient local'
        ),
        Topic(
            'keyframes/pose',
            'geometry_msgs/PoseStamped',
            'camera-to-world pose of the optical frame',
            'reliable, transient local',
        ),
        Topic(
            'keyframes/depth',
            'sensor_msgs/Image',
            'refined depth, 32FC1 metres (REP-118) or 16UC1 mm',
            'reliable, transient local',
        ),
        Topic(
            'keyframes/depth/confidence',
            'sensor_msgs/Image',
            'optional: depth confidence, 32FC1 in [0, 1] (low confidence loses the blend, '
            '`confidence_weight_deg`); without it the depth counts as sure',
            'reliable, transient local',
        ),
        Topic(
            'novel_view/query',
            'geometry_msgs/PoseStamped',
            'desired camera-to-world optical-frame pose (frame `map` or the model frame)',
            'reliable',
        ),
    ),
    publishes=(
        Topic(
            'novel_view/image',
            'sensor_msgs/Image',
            "rgb8 view, black where nothing was rendered; the query's stamp",
            'reliable',
        ),
        Topic(
            'novel_view/image/compressed',
            'sensor_msgs/CompressedImage',
            "the same view as JPEG (image_transport `compressed`, `jpeg_quality`); the query's stamp",
            'reliable',
        ),
        Topic(
            'novel_view/camera_info',
            'sensor_msgs/CameraInfo',
            "the view's intrinsics; the query's stamp",
            'reliable',
        ),
        Topic(
            'novel_view/status',
            'diagnostic_msgs/DiagnosticArray',
            "one per query, the query's stamp: one DiagnosticStatus, level OK (answered), WARN "
            '(incomplete, published) or ERROR (refused: no image); key-values result, reason, '
            'valid_fraction, min_valid_fraction, published, views, render_ms',
            'reliable',
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=('image', 'camera_info', 'pose', 'depth', 'confidence', 'query'),
        outputs=('image', 'status'),
        latency='from the query taken to its image published (rendering included)',
        reasons=(
            ('image', 'malformed keyframes/image'),
            ('camera_info', 'malformed keyframes/camera_info'),
            ('pose', 'malformed keyframes/pose'),
            ('depth', 'malformed keyframes/depth'),
            ('depth_unknown', 'a depth with no known value'),
            ('confidence', 'malformed confidence, or one whose keyframe never came'),
            ('size', 'image, depth, confidence and camera_info sizes differ'),
            ('frame', 'a keyframe in another frame than the model'),
            ('model_full', 'a keyframe beyond `max_keyframes`'),
            ('incomplete', 'a keyframe given up before all its messages arrived'),
            ('lost', 'messages DDS reports lost'),
            ('incompatible_qos', 'a publisher whose QoS cannot match'),
            (
                'query.<reason>',
                'refused queries by their novel_view/status reason (no_model, frame, '
                'invalid_query, unrenderable, superseded, render_error, incomplete)',
            ),
        ),
        queues=(
            ('pending_keyframes', 'keyframes waiting for their other messages (bound `max_keyframes`)'),
            ('pending_bytes', 'bytes they hold (bound `max_pending_mb`)'),
        ),
        model=(
            ('keyframes', 'keyframes in the model'),
            ('max_keyframes', 'its bound'),
            ('usable', 'keyframes the renderer can use'),
            ('bytes', 'bytes of their images, depth and confidence'),
        ),
    ),
)
