# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The flight as it arrives: keyframe selection, the subsampler's latched flight status, shard
membership of sharded refiners, and assembly of messages matched by stamp.
"""

from __future__ import annotations

from ibr_ros.core.flight.keyframes import (
    Decision,
    IntervalSelector,
    KeyframeConfig,
    KeyframeSelector,
    Pick,
    TargetSelection,
    blur_px,
    detail_score,
    select_keyframes,
    select_keyframes_for_target,
    target_baseline,
)
from ibr_ros.core.flight.stamps import (
    StampAssembler,
)
from ibr_ros.core.flight.status import (
    CAMERA_STATES,
    IMAGE_TRANSPORTS,
    POSE_MODES,
    FlightStatus,
    PoseSource,
    ShardMembership,
    shard_of,
)

__all__ = [
    'CAMERA_STATES',
    'IMAGE_TRANSPORTS',
    'POSE_MODES',
    'Decision',
    'FlightStatus',
    'IntervalSelector',
    'KeyframeConfig',
    'KeyframeSelector',
    'Pick',
    'PoseSource',
    'ShardMembership',
    'StampAssembler',
    'TargetSelection',
    'blur_px',
    'detail_score',
    'select_keyframes',
    'select_keyframes_for_target',
    'shard_of',
    'target_baseline',
]
