# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Evaluation only, not on the product path: rephotography error (shiftable L1, PSNR, SSIM), the renderer
baselines the product is measured against (point splat, ULR), real-capture depth against held-back
SfM points and the excess flicker of rendered sequences along a smooth path.
"""

from __future__ import annotations

from ibr_ros.core.evaluation.baselines import (
    SplatRenderer,
    UlrRenderer,
)
from ibr_ros.core.evaluation.flicker import (
    block_excess,
    excess_flicker,
    smooth_path,
    summarise_flicker,
    worst_mean,
)
from ibr_ros.core.evaluation.metrics import psnr, ssim
from ibr_ros.core.evaluation.rephoto import (
    RephotoScore,
    error_curve,
    score,
    shiftable_l1,
)
from ibr_ros.core.evaluation.sparse_check import depth_vs_points, split_observed

__all__ = [
    'RephotoScore',
    'SplatRenderer',
    'UlrRenderer',
    'block_excess',
    'depth_vs_points',
    'error_curve',
    'excess_flicker',
    'psnr',
    'score',
    'shiftable_l1',
    'smooth_path',
    'split_observed',
    'ssim',
    'summarise_flicker',
    'worst_mean',
]
