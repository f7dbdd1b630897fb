# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Evaluation only, not on the product path: rephotography error (shiftable L1, PSNR, SSIM) and the renderer
baselines the product is measured against (point splat, ULR).
"""

from __future__ import annotations

from ibr_ros.core.evaluation.baselines import (
    SplatRenderer,
    UlrRenderer,
)
from ibr_ros.core.evaluation.metrics import psnr, ssim
from ibr_ros.core.evaluation.rephoto import (
    RephotoScore,
    error_curve,
    score,
    shiftable_l1,
)

__all__ = [
    'RephotoScore',
    'SplatRenderer',
    'UlrRenderer',
    'error_curve',
    'psnr',
    'score',
    'shiftable_l1',
    'ssim',
]
