# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""ROS messages <-> numpy, for rclpy message classes and rosbags dataclasses alike.

Functions that build messages take ``flavor='rclpy' | 'rosbags'``; functions that read them
accept either. Conversions follow ibr_ros conventions (:mod:`ibr_ros.core.geometry.transforms`,
:mod:`ibr_ros.core.geometry.camera`): 4x4 float64 camera-to-world poses, REP-103 optical frames, ENU
``map``, float32 depth in metres with 0 = unknown. Bad messages raise :class:`MessageError`.
"""

from msg_utils.camera_info import camera_info_to_pinhole, pinhole_to_camera_info
from msg_utils.compressed import (
    camera_image_to_rgb,
    compressed_image_to_numpy,
    numpy_to_compressed_depth,
    numpy_to_compressed_image,
)
from msg_utils.errors import CONVERSION_ERRORS, MessageError
from msg_utils.flavor import (
    Flavor,
    coerce_header,
    is_rosbags_message,
    make_header,
    message_typename,
    new_message,
    ns_to_stamp,
    stamp_to_ns,
    typestore,
)
from msg_utils.image import (
    ENCODINGS,
    confidence_to_image,
    depth_image_to_m,
    depth_m_to_image,
    depth_m_to_mm,
    depth_mm_to_m,
    image_to_confidence,
    image_to_numpy,
    image_to_rgb,
    numpy_to_image,
)
from msg_utils.navsat import GeoFix, fix_to_navsatfix, navsatfix_to_fix
from msg_utils.pose import (
    matrix_to_odometry,
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_transform,
    matrix_to_transform_stamped,
    odometry_to_matrix,
    pose_stamped_to_matrix,
    pose_to_matrix,
    transform_stamped_to_matrix,
)
from msg_utils.status import (
    areas_to_diagnostics,
    diagnostics_to_areas,
    diagnostics_to_reply,
    pairs_to_status,
    reply_to_diagnostics,
    status_to_pairs,
)
from msg_utils.viz import (
    CLOUD_FIELDS,
    cloud_to_points,
    frustums_to_marker_array,
    markers_to_array,
    matrices_to_pose_array,
    points_to_cloud,
    segments_to_marker,
    tf_available,
    transforms_to_tf,
)

__all__ = [
    'CLOUD_FIELDS',
    'CONVERSION_ERRORS',
    'ENCODINGS',
    'Flavor',
    'GeoFix',
    'MessageError',
    'areas_to_diagnostics',
    'camera_image_to_rgb',
    'camera_info_to_pinhole',
    'cloud_to_points',
    'coerce_header',
    'compressed_image_to_numpy',
    'confidence_to_image',
    'depth_image_to_m',
    'depth_m_to_image',
    'depth_m_to_mm',
    'depth_mm_to_m',
    'diagnostics_to_areas',
    'diagnostics_to_reply',
    'fix_to_navsatfix',
    'frustums_to_marker_array',
    'image_to_confidence',
    'image_to_numpy',
    'image_to_rgb',
    'is_rosbags_message',
    'make_header',
    'markers_to_array',
    'matrices_to_pose_array',
    'matrix_to_odometry',
    'matrix_to_pose',
    'matrix_to_pose_stamped',
    'matrix_to_transform',
    'matrix_to_transform_stamped',
    'message_typename',
    'navsatfix_to_fix',
    'new_message',
    'ns_to_stamp',
    'numpy_to_compressed_depth',
    'numpy_to_compressed_image',
    'numpy_to_image',
    'odometry_to_matrix',
    'pairs_to_status',
    'pinhole_to_camera_info',
    'points_to_cloud',
    'pose_stamped_to_matrix',
    'pose_to_matrix',
    'reply_to_diagnostics',
    'segments_to_marker',
    'stamp_to_ns',
    'status_to_pairs',
    'tf_available',
    'transform_stamped_to_matrix',
    'transforms_to_tf',
    'typestore',
]
