# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Registration of pose-less images: pycolmap structure from motion and the incremental session
that keeps one frame across updates, and the depth_refiner's SfM-mode trigger.
"""

from __future__ import annotations

from ibr_ros.core.registration.colmap import (
    pycolmap,
)
from ibr_ros.core.registration.sfm import (
    CameraModel,
    GpsAlignment,
    SfmError,
    SfmOptions,
    SfmResult,
    register_images,
    robust_similarity,
    similarity_from_orientations,
    umeyama,
)
from ibr_ros.core.registration.sfm_session import (
    Frame,
    ScaleHint,
    SfmSession,
    SfmUpdate,
)
from ibr_ros.core.registration.trigger import (
    SFM_MODES,
    SfmConfig,
    SfmMode,
    SfmTrigger,
    StatusDecision,
)

__all__ = [
    'SFM_MODES',
    'CameraModel',
    'Frame',
    'GpsAlignment',
    'ScaleHint',
    'SfmConfig',
    'SfmError',
    'SfmMode',
    'SfmOptions',
    'SfmResult',
    'SfmSession',
    'SfmTrigger',
    'SfmUpdate',
    'StatusDecision',
    'pycolmap',
    'register_images',
    'robust_similarity',
    'similarity_from_orientations',
    'umeyama',
]
