# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Poses in geometry_msgs / nav_msgs messages <-> 4x4 float64 matrices.

A matrix ``T`` maps child-frame coordinates to parent-frame coordinates (``p_parent = T @ p_child``):
for ``PoseStamped``/``Odometry`` the parent is ``header.frame_id`` and the pose is that of the
child (Odometry's ``child_frame_id``); for ``TransformStamped`` the parent is ``header.frame_id``
and the child ``child_frame_id``. With parent ``map`` (ENU) and a REP-103 optical camera child,
``T`` is the camera-to-world ``T_wc`` of :mod:`ibr_ros.core.geometry.transforms`. Metres,
quaternions (x, y, z, w).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.transforms import (
    GeometryError,
    matrix_from_rt,
    quaternion_from_rotation,
    rotation_from_quaternion,
    validate_pose,
)
from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, make_header, new_message

__all__ = [
    'matrix_to_odometry',
    'matrix_to_pose',
    'matrix_to_pose_stamped',
    'matrix_to_transform',
    'matrix_to_transform_stamped',
    'odometry_to_matrix',
    'pose_stamped_to_matrix',
    'pose_to_matrix',
    'transform_stamped_to_matrix',
]


def _rt_to_matrix(t: Any, q: Any, t_field: str, q_field: str) -> NDArray[np.float64]:
    tv = np.array([t.x, t.y, t.z], dtype=np.float64)
    if not np.all(np.isfinite(tv)):
        raise MessageError(f'{t_field} must be finite, got (x, y, z) = {tuple(tv.tolist())}')
    try:
        r = rotation_from_quaternion([q.x, q.y, q.z, q.w], field=q_field)
    except GeometryError as e:
        raise MessageError(str(e)) from e
    return matrix_from_rt(r, tv)


def pose_to_matrix(pose: Any, *, field: str = 'Pose') -> NDArray[np.float64]:
    """4x4 matrix of a ``geometry_msgs/Pose`` (non-unit quaternions are normalised).

    Raises MessageError naming ``{field}.position`` / ``{field}.orientation`` for non-finite
    positions and zero or non-finite quaternions.
    """
    return _rt_to_matrix(pose.position, pose.orientation, f'{field}.position', f'{field}.orientation')


def pose_stamped_to_matrix(msg: Any) -> NDArray[np.float64]:
    """4x4 pose of a ``geometry_msgs/PoseStamped`` in ``msg.header.frame_id``."""
    return pose_to_matrix(msg.pose, field='PoseStamped.pose')


def transform_stamped_to_matrix(msg: Any) -> NDArray[np.float64]:
    """4x4 matrix of a ``geometry_msgs/TransformStamped``, mapping child to parent coordinates."""
    tf = msg.transform
    return _rt_to_matrix(
        tf.translation,
        tf.rotation,
        'TransformStamped.transform.translation',
        'TransformStamped.transform.rotation',
    )


def odometry_to_matrix(msg: Any) -> NDArray[np.float64]:
    """4x4 pose of ``child_frame_id`` in ``header.frame_id`` from a ``nav_msgs/Odometry``."""
    return pose_to_matrix(msg.pose.pose, field='Odometry.pose.pose')


def _rt(T: ArrayLike) -> tuple[list[float], list[float]]:
    m = validate_pose(T, field='T')
    return m[:3, 3].tolist(), quaternion_from_rotation(m[:3, :3]).tolist()


def _xyz(typename: str, values: list[float], flavor: Flavor) -> Any:
    return new_message(typename, flavor, x=values[0], y=values[1], z=values[2])


def _quaternion(q: list[float], flavor: Flavor) -> Any:
    return new_message('geometry_msgs/msg/Quaternion', flavor, x=q[0], y=q[1], z=q[2], w=q[3])


def matrix_to_pose(T: ArrayLike, *, flavor: Flavor = 'rclpy') -> Any:
    """``geometry_msgs/Pose`` of a rigid 4x4 matrix (quaternion with w >= 0).

    Raises GeometryError (a ValueError) if ``T`` is not a finite rigid transform.
    """
    t, q = _rt(T)
    return new_message(
        'geometry_msgs/msg/Pose',
        flavor,
        position=_xyz('geometry_msgs/msg/Point', t, flavor),
        orientation=_quaternion(q, flavor),
    )


def matrix_to_transform(T: ArrayLike, *, flavor: Flavor = 'rclpy') -> Any:
    """``geometry_msgs/Transform`` of a rigid 4x4 matrix (quaternion with w >= 0)."""
    t, q = _rt(T)
    return new_message(
        'geometry_msgs/msg/Transform',
        flavor,
        translation=_xyz('geometry_msgs/msg/Vector3', t, flavor),
        rotation=_quaternion(q, flavor),
    )


def matrix_to_pose_stamped(
    T: ArrayLike, *, stamp_ns: int = 0, frame_id: str = 'map', flavor: Flavor = 'rclpy'
) -> Any:
    """``geometry_msgs/PoseStamped`` of pose ``T`` in ``frame_id`` at ``stamp_ns`` nanoseconds."""
    return new_message(
        'geometry_msgs/msg/PoseStamped',
        flavor,
        header=make_header(stamp_ns, frame_id, flavor),
        pose=matrix_to_pose(T, flavor=flavor),
    )


def matrix_to_transform_stamped(
    T: ArrayLike,
    *,
    parent: str = 'map',
    child: str = 'camera_optical',
    stamp_ns: int = 0,
    flavor: Flavor = 'rclpy',
) -> Any:
    """``geometry_msgs/TransformStamped`` from ``parent`` (header.frame_id) to ``child``."""
    return new_message(
        'geometry_msgs/msg/TransformStamped',
        flavor,
        header=make_header(stamp_ns, parent, flavor),
        child_frame_id=child,
        transform=matrix_to_transform(T, flavor=flavor),
    )


def matrix_to_odometry(
    T: ArrayLike,
    *,
    stamp_ns: int = 0,
    frame_id: str = 'map',
    child_frame_id: str = 'camera_optical',
    flavor: Flavor = 'rclpy',
) -> Any:
    """``nav_msgs/Odometry`` with pose ``T`` of ``child_frame_id`` in ``frame_id``.

    Covariances and twist are left zero.
    """
    pose = new_message('geometry_msgs/msg/PoseWithCovariance', flavor, pose=matrix_to_pose(T, flavor=flavor))
    return new_message(
        'nav_msgs/msg/Odometry',
        flavor,
        header=make_header(stamp_ns, frame_id, flavor),
        child_frame_id=child_frame_id,
        pose=pose,
    )
