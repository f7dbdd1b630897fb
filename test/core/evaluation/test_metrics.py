# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""PSNR and SSIM of :mod:`ibr_ros.core.evaluation.metrics` against scikit-image (a test dependency only)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ibr_ros.core.evaluation import psnr, ssim


def test_psnr_and_ssim_agree_with_scikit_image():
    metrics = pytest.importorskip('skimage.metrics')
    rng = np.random.default_rng(1)
    a = cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (5, 5), 1.0)
    b = np.clip(a.astype(int) + rng.integers(-25, 26, a.shape), 0, 255).astype(np.uint8)
    assert psnr(a, b) == pytest.approx(metrics.peak_signal_noise_ratio(a, b, data_range=255))
    ref = metrics.structural_similarity(
        a, b, channel_axis=2, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255
    )
    assert ssim(a, b) == pytest.approx(ref, abs=1e-9)
    assert psnr(a, a) == math.inf
    assert ssim(a, a) == pytest.approx(1.0)
    with pytest.raises(ValueError, match='differ in size'):
        psnr(a, b[:-1])
