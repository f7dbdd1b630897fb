# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Camera frustums as line segments, for markers."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import validate_pose

__all__ = ['FRUSTUM_SEGMENTS', 'auto_frustum_depth', 'frustum_segments', 'known_median']

#: Segments of :func:`frustum_segments`: 4 edges from the centre to the image corners, the 4 sides
#: of the image rectangle, and a tick from the top side's middle upward (which way is up).
FRUSTUM_SEGMENTS = 9


def frustum_segments(camera: PinholeCamera, t_wc: ArrayLike, depth_m: float) -> NDArray[np.float64]:
    """``(9, 2, 3)`` world line segments of the camera's frustum cut at z-depth ``depth_m`` metres.

    Corners are the outer pixel edges ``(0, 0)``, ``(W, 0)``, ``(W, H)``, ``(0, H)`` (top-left,
    top-right, bottom-right, bottom-left in the image) back-projected with K along the REP-103
    optical axes, then moved by ``t_wc`` (4x4 camera-to-world). Order: centre-to-corner edges in
    corner order, the sides (top, right, bottom, left), the up tick (length 1/4 of the image height,
    towards -y of the optical frame).
    """
    if not (np.isfinite(depth_m) and depth_m > 0):
        raise ValueError(f'depth_m must be a positive number, got {depth_m!r}')
    pose = validate_pose(t_wc, field='t_wc')
    w, h = camera.width, camera.height
    uv = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    corners = camera.backproject(uv, np.full(4, depth_m))
    top_mid = 0.5 * (corners[0] + corners[1])
    tick = top_mid + np.array([0.0, -0.25 * (corners[3, 1] - corners[0, 1]), 0.0])
    centre = np.zeros(3)
    seg = [(centre, c) for c in corners]
    seg += [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    seg.append((top_mid, tick))
    pts = np.array(seg, dtype=np.float64)  # (9, 2, 3) optical frame
    return pts @ pose[:3, :3].T + pose[:3, 3]


def known_median(depth: ArrayLike) -> float | None:
    """Median of the known depths (finite, > 0; metres) of ``depth``, None when there is none."""
    a = np.asarray(depth, dtype=np.float32)
    with np.errstate(invalid='ignore'):
        known = a[np.isfinite(a) & (a > 0)]
    return float(np.median(known)) if known.size else None


def auto_frustum_depth(medians: Iterable[float], fraction: float = 0.15, default: float = 1.0) -> float:
    """A frustum depth that suits the scene: ``fraction`` of the median of the keyframes' median
    known depths (:func:`known_median`, metres); ``default`` when there is none."""
    meds = list(medians)
    return fraction * float(np.median(meds)) if meds else default
