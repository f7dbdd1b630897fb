# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Depth maps as colour images for people: turbo-coloured inverse depth, black where unknown."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ['colour_depth']


def colour_depth(
    depth: NDArray[np.floating], limits: tuple[float, float] | None = None, *, bgr: bool = False
) -> NDArray[np.uint8]:
    """HxWx3 uint8 turbo colouring of inverse depth (near = red, far = blue), black where unknown.

    ``depth``: HxW metres; 0, NaN, negative and +inf (sky) are unknown. ``limits``: ``(near, far)``
    (m, 0 < near <= far) mapped to the ends of the colour map, nearer and farther values clipped;
    None: the 2nd and 98th percentiles of the known inverse depths. RGB, or BGR with ``bgr``
    (OpenCV's order, for ``cv2.imwrite``).
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f'depth must be HxW, got shape {d.shape}')
    ok = np.isfinite(d) & (d > 0)
    if not ok.any():
        return np.zeros((*d.shape, 3), np.uint8)
    inv = 1.0 / d[ok]  # in the depth's precision (the previews stay what they were)
    if limits is None:
        lo, hi = np.percentile(inv, (2, 98))
    else:
        near, far = limits
        if not 0 < near <= far:
            raise ValueError(f'limits must be (near, far) with 0 < near <= far, got {limits}')
        lo, hi = 1.0 / far, 1.0 / near
    grey = np.zeros(d.shape, np.uint8)
    t = ((inv - lo) / max(hi - lo, 1e-12)).astype(np.float64)
    grey[ok] = np.clip(t * 255, 0, 255).astype(np.uint8)
    out = np.asarray(cv2.applyColorMap(grey, cv2.COLORMAP_TURBO), np.uint8)
    if not bgr:
        out = np.asarray(cv2.cvtColor(out, cv2.COLOR_BGR2RGB), np.uint8)
    out[~ok] = 0
    return out
