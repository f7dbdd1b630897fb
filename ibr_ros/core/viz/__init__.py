# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The model for standard ROS viewers (RViz, Foxglove): coloured point clouds of the refined
keyframes, camera frustums and the TF frames of the cameras (REP-103 / REP-105 names), computed
the same way live (the ``scene_viz`` node) and offline (``ibr process``'s output bag).
"""

from __future__ import annotations

from ibr_ros.core.viz.cloud import CloudConfig, grid, keyframe_points
from ibr_ros.core.viz.frames import (
    T_BODY_FROM_OPTICAL,
    FrameNames,
    camera_transforms,
    keyframe_frame,
)
from ibr_ros.core.viz.frustum import FRUSTUM_SEGMENTS, auto_frustum_depth, frustum_segments, known_median
from ibr_ros.core.viz.model import KEYFRAME_RGBA, NOVEL_VIEW_RGBA, VizConfig, VizKeyframe, VizModel

__all__ = [
    'FRUSTUM_SEGMENTS',
    'KEYFRAME_RGBA',
    'NOVEL_VIEW_RGBA',
    'T_BODY_FROM_OPTICAL',
    'CloudConfig',
    'FrameNames',
    'VizConfig',
    'VizKeyframe',
    'VizModel',
    'auto_frustum_depth',
    'camera_transforms',
    'frustum_segments',
    'grid',
    'keyframe_frame',
    'keyframe_points',
    'known_median',
]
