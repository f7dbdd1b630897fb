# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-keyframe depth: plane-sweep MVS, pruning, monocular depth and its per-view lookup table,
MST non-local fusion, sky masks, the refinement pipeline (one keyframe's step: ``refine_job``), the
refinement scheduler and depth colouring for previews.

Depth maps are float32 z-depth in metres (REP-118 in messages: NaN unknown, +inf sky).
"""

from __future__ import annotations

from ibr_ros.core.depth.colour import (
    colour_depth,
)
from ibr_ros.core.depth.fusion import (
    build_mst,
    fuse_depth,
    mvs_support,
    tree_filter,
)
from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth
from ibr_ros.core.depth.mono import (
    PRESETS,
    GroundPlanePrior,
    MonoModelSpec,
    OnnxMonoDepth,
    nearness_to_g,
)
from ibr_ros.core.depth.mvs import (
    REASON_NO_DEPTH_RANGE,
    REASON_NO_OVERLAP,
    REASON_NO_PARALLAX,
    REASON_NO_SOURCES,
    MvsBackendUnavailable,
    MvsOptions,
    MvsResult,
    MvsView,
    compute_depth_maps,
    depth_range_from_points,
    geometric_filter,
    mvs_depth,
    select_neighbours,
)
from ibr_ros.core.depth.onnx import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    MonoModelError,
    onnx_session,
    to_input_tensor,
)
from ibr_ros.core.depth.prune import (
    median_filter_valid,
    prune_depth,
    weighted_median_filter_valid,
)
from ibr_ros.core.depth.refine import (
    DepthRefiner,
    JobResult,
    RefinedDepth,
    RefineError,
    RefinerConfig,
    known_depth,
    refine_job,
)
from ibr_ros.core.depth.remap import (
    build_lut,
    level_medians,
    linear_remap,
    lut_remap,
    median_factor_remap,
)
from ibr_ros.core.depth.schedule import (
    RefineJob,
    RefineScheduler,
    ScheduleConfig,
    axis_scene_depth,
    parse_depth_range,
)
from ibr_ros.core.depth.sky import (
    SKY_PRESETS,
    OnnxSkySegmenter,
    SkySpec,
    apply_sky_depth,
    erode_sky,
    horizon_mask,
    sky_fallback,
)

__all__ = [
    'IMAGENET_MEAN',
    'IMAGENET_STD',
    'PRESETS',
    'REASON_NO_DEPTH_RANGE',
    'REASON_NO_OVERLAP',
    'REASON_NO_PARALLAX',
    'REASON_NO_SOURCES',
    'SKY_PRESETS',
    'DepthRefiner',
    'GroundPlanePrior',
    'JobResult',
    'MonoModelError',
    'MonoModelSpec',
    'MvsBackendUnavailable',
    'MvsOptions',
    'MvsResult',
    'MvsView',
    'OnnxMonoDepth',
    'OnnxSkySegmenter',
    'PhotometricCache',
    'RefineError',
    'RefineJob',
    'RefineScheduler',
    'RefinedDepth',
    'RefinerConfig',
    'ScheduleConfig',
    'SkySpec',
    'apply_sky_depth',
    'axis_scene_depth',
    'build_lut',
    'build_mst',
    'colour_depth',
    'compute_depth_maps',
    'depth_range_from_points',
    'erode_sky',
    'fuse_depth',
    'geometric_filter',
    'horizon_mask',
    'job_depth',
    'known_depth',
    'level_medians',
    'linear_remap',
    'lut_remap',
    'median_factor_remap',
    'median_filter_valid',
    'mvs_depth',
    'mvs_support',
    'nearness_to_g',
    'onnx_session',
    'parse_depth_range',
    'prune_depth',
    'refine_job',
    'select_neighbours',
    'sky_fallback',
    'to_input_tensor',
    'tree_filter',
    'weighted_median_filter_valid',
]
