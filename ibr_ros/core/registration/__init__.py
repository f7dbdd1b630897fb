"""Registration of pose-less images: pycolmap structure from motion and the incremental session
that keeps one frame across updates.
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

__all__ = [
    'CameraModel',
    'Frame',
    'GpsAlignment',
    'ScaleHint',
    'SfmError',
    'SfmOptions',
    'SfmResult',
    'SfmSession',
    'SfmUpdate',
    'pycolmap',
    'register_images',
    'robust_similarity',
    'similarity_from_orientations',
    'umeyama',
]
