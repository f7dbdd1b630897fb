# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Rigid-body geometry on numpy arrays.

Conventions used across ibr_ros:

* A pose is a 4x4 float64 matrix ``T_wc`` mapping camera coordinates to world
  coordinates (``p_w = T_wc @ p_c``), i.e. "camera-to-world".
* Camera frames are REP-103 *optical* frames: z forward, x right, y down.
* The world frame ``map`` is ENU (x east, y north, z up), metres.
* Quaternions are ``(x, y, z, w)`` like ``geometry_msgs/Quaternion``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    'GeometryError',
    'look_at',
    'matrix_from_rt',
    'quaternion_from_rotation',
    'rotation_angle_deg',
    'rotation_from_quaternion',
    'rotation_from_ypr',
    'similarity_times_pose',
    'validate_pose',
]

# Rotation taking optical-frame coordinates (z forward, x right, y down) to REP-103 body-frame
# coordinates (x forward, y left, z up): its columns are the optical axes seen in the body frame.
R_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class GeometryError(ValueError):
    """A pose, rotation or quaternion that is not usable (zero, non-finite, not rigid)."""


def _finite(name: str, value: NDArray[np.float64]) -> None:
    if not np.all(np.isfinite(value)):
        raise GeometryError(f'{name} must be finite, got {np.array2string(value, precision=4)}')


def rotation_from_quaternion(q: ArrayLike, *, field: str = 'orientation') -> NDArray[np.float64]:
    """Return the 3x3 rotation of quaternion ``q = (x, y, z, w)``; normalises non-unit input.

    Raises GeometryError naming ``field`` for zero-norm or non-finite quaternions.
    """
    qa = np.asarray(q, dtype=np.float64).reshape(4)
    _finite(field, qa)
    n = float(np.linalg.norm(qa))
    if n < 1e-9:
        raise GeometryError(f'{field} is a zero quaternion (x, y, z, w) = {tuple(qa.tolist())}')
    x, y, z, w = qa / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_rotation(r: ArrayLike) -> NDArray[np.float64]:
    """Return the unit quaternion ``(x, y, z, w)`` with ``w >= 0`` of a 3x3 rotation matrix."""
    m = np.asarray(r, dtype=np.float64).reshape(3, 3)
    _finite('rotation', m)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    qa = np.asarray(q)
    qa /= np.linalg.norm(qa)
    return -qa if qa[3] < 0 else qa


def matrix_from_rt(r: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """Assemble a 4x4 homogeneous matrix from a 3x3 rotation and a translation (metres)."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(r, dtype=np.float64).reshape(3, 3)
    m[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return m


def rotation_angle_deg(r_a: ArrayLike, r_b: ArrayLike) -> float:
    """Angle (degrees) of the relative rotation ``r_a^T r_b`` of two 3x3 rotations."""
    c = (np.trace(np.asarray(r_a).T @ np.asarray(r_b)) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def similarity_times_pose(m: ArrayLike, t_wc: ArrayLike) -> NDArray[np.float64]:
    """The rigid pose ``t_wc`` moved by the similarity ``m`` (4x4 ``[[s R, t], [0, 1]]``): the
    camera centre goes to ``s R c + t`` and the orientation to ``R R_wc`` (still rigid)."""
    m, t_wc = np.asarray(m, dtype=np.float64), np.asarray(t_wc, dtype=np.float64)
    s = float(np.cbrt(np.linalg.det(m[:3, :3])))
    return matrix_from_rt((m[:3, :3] / s) @ t_wc[:3, :3], m[:3, :3] @ t_wc[:3, 3] + m[:3, 3])


def validate_pose(t_wc: ArrayLike, *, field: str = 'pose', tol: float = 1e-4) -> NDArray[np.float64]:
    """Check that ``t_wc`` is a finite rigid 4x4 transform; return it as float64.

    Raises GeometryError naming ``field`` otherwise.
    """
    m = np.asarray(t_wc, dtype=np.float64)
    if m.shape != (4, 4):
        raise GeometryError(f'{field} must be a 4x4 matrix, got shape {m.shape}')
    _finite(field, m)
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > tol or abs(float(np.linalg.det(r)) - 1.0) > tol:
        raise GeometryError(f'{field} rotation is not orthonormal (max |RtR - I| = {err:.3g})')
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise GeometryError(f'{field} last row must be [0, 0, 0, 1], got {m[3].tolist()}')
    return m


def rotation_from_ypr(yaw: float, pitch: float, roll: float) -> NDArray[np.float64]:
    """Camera-to-world rotation of an optical camera from ENU yaw/pitch/roll in radians.

    ``yaw`` is the heading of the optical axis, counter-clockwise from east (ENU, REP-103);
    ``pitch`` tilts the optical axis up (positive) or down (negative, e.g. -0.5 looks down);
    ``roll`` rotates about the optical axis (right-handed about forward). With all zero the
    camera looks east with image x pointing south and image y pointing down.
    """
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    # Body frame x forward, y left, z up: positive pitch about -y raises the nose.
    ry = np.array([[cp, 0, -sp], [0, 1.0, 0], [sp, 0, cp]])
    rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    r_wb = rz @ ry @ rx
    return r_wb @ R_BODY_FROM_OPTICAL


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> NDArray[np.float64]:
    """Camera-to-world pose of an optical camera at ``eye`` looking at ``target`` (ENU metres).

    Image y (down) is aligned with ``-up`` projected on the image plane.
    """
    e = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - e
    nz = np.linalg.norm(z)
    if nz < 1e-12:
        raise GeometryError('look_at: eye and target coincide')
    z /= nz
    u = np.asarray(up, dtype=np.float64)
    x = np.cross(z, u)
    if np.linalg.norm(x) < 1e-9:
        raise GeometryError('look_at: viewing direction is parallel to up')
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return matrix_from_rt(np.stack([x, y, z], axis=1), e)
