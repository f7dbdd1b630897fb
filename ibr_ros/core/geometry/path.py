# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Query paths along a flight: poses between consecutive keyframes (4x4 camera-to-world, metres)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.transforms import (
    matrix_from_rt,
    quaternion_from_rotation,
    rotation_from_quaternion,
)

__all__ = ['interpolate_path', 'path_pairs', 'path_stamps']


def path_pairs(n_keyframes: int, n: int) -> list[int]:
    """Indices ``i`` of up to ``n`` keyframe pairs ``(i, i + 1)``, spread evenly along the flight."""
    if n_keyframes < 2:
        return []
    return np.unique(np.linspace(0, n_keyframes - 2, min(n, n_keyframes - 1)).round().astype(int)).tolist()


def interpolate_path(poses: Sequence[NDArray[np.float64]], n: int) -> list[NDArray[np.float64]]:
    """Up to ``n`` poses at the midpoints of the keyframe pairs :func:`path_pairs` picks.

    ``poses``: 4x4 camera-to-world keyframe poses in flight order. Each midpoint has the mean
    position and the normalised mean (lerp) of the two rotations' quaternions.
    """
    mids = []
    for i in path_pairs(len(poses), n):
        a, b = poses[i], poses[i + 1]
        qa, qb = quaternion_from_rotation(a[:3, :3]), quaternion_from_rotation(b[:3, :3])
        qb = qb if qa @ qb >= 0 else -qb
        mids.append(matrix_from_rt(rotation_from_quaternion(qa + qb), (a[:3, 3] + b[:3, 3]) / 2))
    return mids


def path_stamps(stamps: Sequence[int], n: int) -> list[int]:
    """Stamps (ns) of :func:`interpolate_path`'s poses: the midpoints of the same keyframe pairs."""
    return [(stamps[i] + stamps[i + 1]) // 2 for i in path_pairs(len(stamps), n)]
