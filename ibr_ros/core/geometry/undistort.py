# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Lens undistortion of images and pixel coordinates with OpenCV (plumb_bob, rational_polynomial).

Pixel conventions as in :mod:`ibr_ros.core.geometry.camera`. The rectification rotation ``R`` and the
projection ``P`` of a stereo pair are not applied: this removes lens distortion only.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from typing import cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import CameraError, PinholeCamera

__all__ = ['undistort_image', 'undistort_points']


@functools.lru_cache(maxsize=2)
def _maps(
    width: int, height: int, k: bytes, d: bytes, alpha: float
) -> tuple[NDArray[np.float64], NDArray[np.int16], NDArray[np.uint16]]:
    K = np.frombuffer(k).reshape(3, 3)
    D = np.frombuffer(d)
    new_k, _ = cv2.getOptimalNewCameraMatrix(K, D, (width, height), alpha, (width, height))
    map1, map2 = cv2.initUndistortRectifyMap(K, D, None, new_k, (width, height), cv2.CV_16SC2)
    # cv2's stubs give no dtypes: these are OpenCV's (CV_64F matrix, CV_16SC2 and CV_16UC1 maps).
    return cast('tuple[NDArray[np.float64], NDArray[np.int16], NDArray[np.uint16]]', (new_k, map1, map2))


def undistort_image(
    image: ArrayLike, cam: PinholeCamera, *, alpha: float = 0.0, interpolation: int = cv2.INTER_LINEAR
) -> tuple[NDArray[np.generic], PinholeCamera]:
    """Undistorted copy of ``image`` (HxW or HxWxC, size of ``cam``) and its distortion-free camera.

    ``alpha`` as in ``cv2.getOptimalNewCameraMatrix``: 0 keeps only valid pixels (zoomed in),
    1 keeps all source pixels (black borders). Pixels without a source are 0. Use
    ``interpolation=cv2.INTER_NEAREST`` for depth or label images. A camera without distortion
    returns ``image`` itself and ``cam`` unchanged. The new camera has zero distortion,
    ``R = I`` and ``P = [K' | 0]``; the output has the same size as the input.
    """
    img = np.asarray(image)
    if img.shape[:2] != (cam.height, cam.width):
        raise CameraError(f'image is {img.shape[1]}x{img.shape[0]}, camera is {cam.width}x{cam.height}')
    if not cam.is_distorted:
        return img, cam
    new_k, map1, map2 = _maps(cam.width, cam.height, cam.k.tobytes(), cam.d.tobytes(), float(alpha))
    out = cv2.remap(img, map1, map2, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if img.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    new_cam = replace(cam, k=new_k, d=np.zeros_like(cam.d), r=np.eye(3), p=None)
    return out, new_cam


def undistort_points(uv: ArrayLike, cam: PinholeCamera) -> NDArray[np.float64]:
    """Nx2 undistorted pixel coordinates of distorted pixels ``uv`` (Nx2), in the same ``K``.

    Solved iteratively (``cv2.undistortPoints``, to 1e-10 normalised units) with ``P = K``,
    so results are in the original camera's pixel grid, not that of :func:`undistort_image`.
    """
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if not cam.is_distorted or pts.size == 0:
        return pts.copy()
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    out = cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.k, cam.d, R=None, P=cam.k, criteria=criteria)
    return out.reshape(-1, 2).astype(np.float64)
