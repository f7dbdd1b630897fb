# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Full-reference image metrics of a render against a photo: PSNR and SSIM (8-bit RGB images)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ['psnr', 'ssim']

_SSIM_SIGMA = 1.5  # Wang et al. 2004: Gaussian window, sigma 1.5 px, 11 taps
_SSIM_RADIUS = 5
_C1 = (0.01 * 255.0) ** 2
_C2 = (0.03 * 255.0) ** 2


def _check(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> None:
    for name, img in (('reference', a), ('image', b)):
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f'{name} must be an HxWx3 uint8 image, got {getattr(img, "shape", type(img))}')
    if a.shape != b.shape:
        raise ValueError(f'images differ in size: {a.shape} and {b.shape}')


def psnr(reference: NDArray[np.uint8], image: NDArray[np.uint8]) -> float:
    """Peak signal-to-noise ratio (dB, peak 255) over all pixels and channels; +inf when identical."""
    _check(reference, image)
    mse = float(np.mean((reference.astype(np.float64) - image.astype(np.float64)) ** 2))
    return float('inf') if mse == 0.0 else float(10.0 * np.log10(255.0**2 / mse))


def ssim(reference: NDArray[np.uint8], image: NDArray[np.uint8]) -> float:
    """Mean structural similarity (Wang et al. 2004) in [-1, 1]: Gaussian window (sigma 1.5 px, 11x11),
    K1 0.01, K2 0.03, data range 255, per channel and averaged; the 5 px border (where the window
    leaves the image) is left out. Equals ``skimage.metrics.structural_similarity(..., channel_axis=2,
    gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255)``.
    """
    _check(reference, image)
    r = _SSIM_RADIUS
    if min(reference.shape[:2]) <= 2 * r:
        raise ValueError(f'images must be larger than {2 * r + 1} px, got {reference.shape[:2]}')
    x, y = reference.astype(np.float64), image.astype(np.float64)

    def blur(v: NDArray[np.float64]) -> NDArray[np.float64]:
        k = 2 * r + 1
        return np.asarray(cv2.GaussianBlur(v, (k, k), _SSIM_SIGMA, borderType=cv2.BORDER_REFLECT_101))

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    s = ((2 * mx * my + _C1) * (2 * cxy + _C2)) / ((mx * mx + my * my + _C1) * (vx + vy + _C2))
    return float(np.mean(s[r:-r, r:-r], dtype=np.float64))
