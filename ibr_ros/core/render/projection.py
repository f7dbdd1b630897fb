# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Reprojection of source-view pixels into the novel view, shared by the raster and blend kernels.

Cameras are undistorted pinholes (REP-103 optical frame: z forward, x right, y down; pixel centres
at integers); poses are 4x4 camera-to-world matrices in metres; depths are z-depths in metres
(REP-118: 0/NaN unknown, ``+inf`` sky). The source-to-novel transform of one view is packed into
the 12-vector ``rel`` of :func:`reprojection_params`: ``H = K_n R K_s^-1`` (9, row-major) and
``K_n t`` (3), so that source pixel ``(u, v)`` at depth ``d`` lands at the homogeneous novel-view
pixel ``H (u, v, 1) d + K_n t``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera

__all__ = ['intrinsics_vector', 'lands_near', 'refine_preimage', 'relative_pose', 'reprojection_params']


def intrinsics_vector(camera: PinholeCamera) -> NDArray[np.float64]:
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy])


def relative_pose(t_wn: NDArray[np.float64], t_ws: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Rotation and translation of ``T_ns = T_wn^-1 T_ws`` (source frame -> novel frame)."""
    r_wn = t_wn[:3, :3]
    r = r_wn.T @ t_ws[:3, :3]
    t = r_wn.T @ (t_ws[:3, 3] - t_wn[:3, 3])
    return np.ascontiguousarray(r), np.ascontiguousarray(t)


def reprojection_params(
    t_wn: NDArray[np.float64], novel: PinholeCamera, t_ws: NDArray[np.float64], source: PinholeCamera
) -> NDArray[np.float64]:
    """The ``rel`` row of :func:`refine_preimage` / :func:`lands_near` for one source view."""
    r, t = relative_pose(t_wn, t_ws)
    fx, fy, cx, cy = intrinsics_vector(novel)
    k_n = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    fx, fy, cx, cy = intrinsics_vector(source)
    k_s_inv = np.array([[1 / fx, 0.0, -cx / fx], [0.0, 1 / fy, -cy / fy], [0.0, 0.0, 1.0]])
    return np.concatenate([(k_n @ r @ k_s_inv).ravel(), k_n @ t])


@njit(cache=True)
def lands_near(d, hx, hy, hz, rel, x, y, thr2):
    """Whether a source pixel at depth ``d`` projects within ``sqrt(thr2)`` px of novel pixel
    ``(x, y)``; ``(hx, hy, hz) = H (u, v, 1)`` of the source pixel, ``rel`` as in
    :func:`refine_preimage`. True for unknown depth or sky (only the affine map is known there)."""
    d = np.float64(d)
    if not (d > 0 and d < np.inf):
        return True
    zc = hz * d + rel[11]
    ex = hx * d + rel[9] - x * zc
    ey = hy * d + rel[10] - y * zc
    return zc > 1e-6 and ex * ex + ey * ey <= thr2 * zc * zc


@njit(cache=True, inline='always')
def refine_preimage(depth, rel, x, y, u, v, a00, a01, a10, a11, iters, max_shift):
    """Pre-image ``(u, v)`` of novel pixel ``(x, y)`` corrected with the source depth (Newton steps).

    The superpixel's affine map gives ``(u, v)``; each step projects source pixel ``(u, v)`` at its
    own depth (nearest pixel) into the novel view and moves ``(u, v)`` by the affine map's linear part
    ``a`` applied to the residual, by at most ``max_shift`` px in total. ``rel``: ``H = K_n R K_s^-1``
    (9, row-major) and ``K_n t`` (3) of the source-to-novel transform ``(R, t)``, so that source
    pixel ``(u, v)`` at depth ``d`` lands at ``H (u, v, 1) d + K_n t`` (homogeneous novel-view
    pixel). Unknown or sky depth stops the steps.
    """
    h, w = depth.shape
    u0, v0 = u, v
    for _ in range(iters):
        ui = min(max(int(u + 0.5), 0), w - 1)
        vi = min(max(int(v + 0.5), 0), h - 1)
        d = np.float64(depth[vi, ui])
        if not (d > 0 and d < np.inf):
            break
        zc = (rel[6] * u + rel[7] * v + rel[8]) * d + rel[11]
        if not zc > 1e-6:
            break
        iz = 1.0 / zc
        rx = x - ((rel[0] * u + rel[1] * v + rel[2]) * d + rel[9]) * iz
        ry = y - ((rel[3] * u + rel[4] * v + rel[5]) * d + rel[10]) * iz
        u = min(max(u + a00 * rx + a01 * ry, u0 - max_shift), u0 + max_shift)
        v = min(max(v + a10 * rx + a11 * ry, v0 - max_shift), v0 + max_shift)
    return u, v
