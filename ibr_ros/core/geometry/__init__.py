# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Cameras and geometry: pinhole cameras (REP-103 optical frame: z forward, x right, y down),
rigid transforms (4x4 camera-to-world matrices, metres), geodesy (WGS-84 -> local ENU), undistortion,
plane fitting and query paths between keyframes.
"""

from __future__ import annotations

from ibr_ros.core.geometry.camera import (
    DISTORTION_MODELS,
    CameraError,
    PinholeCamera,
    Roi,
)
from ibr_ros.core.geometry.geodesy import (
    WGS84_A,
    WGS84_F,
    ecef_to_enu,
    ecef_to_geodetic,
    enu_to_ecef,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)
from ibr_ros.core.geometry.path import (
    interpolate_path,
    path_pairs,
    path_stamps,
)
from ibr_ros.core.geometry.plane import (
    fit_ground_plane,
)
from ibr_ros.core.geometry.transforms import (
    GeometryError,
    look_at,
    matrix_from_rt,
    quaternion_from_rotation,
    rotation_angle_deg,
    rotation_from_quaternion,
    rotation_from_ypr,
    similarity_times_pose,
    validate_pose,
)
from ibr_ros.core.geometry.undistort import (
    undistort_image,
    undistort_points,
)

__all__ = [
    'DISTORTION_MODELS',
    'WGS84_A',
    'WGS84_F',
    'CameraError',
    'GeometryError',
    'PinholeCamera',
    'Roi',
    'ecef_to_enu',
    'ecef_to_geodetic',
    'enu_to_ecef',
    'enu_to_geodetic',
    'fit_ground_plane',
    'geodetic_to_ecef',
    'geodetic_to_enu',
    'interpolate_path',
    'look_at',
    'matrix_from_rt',
    'path_pairs',
    'path_stamps',
    'quaternion_from_rotation',
    'rotation_angle_deg',
    'rotation_from_quaternion',
    'rotation_from_ypr',
    'similarity_times_pose',
    'undistort_image',
    'undistort_points',
    'validate_pose',
]
