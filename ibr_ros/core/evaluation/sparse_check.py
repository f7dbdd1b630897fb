# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Refined depth of a real capture against SfM sparse points that did not seed it.

Without ground truth, the triangulated points a view observed are the reference: those held back
from the depth seeds (:func:`split_observed`) are projected into the view and compared with the
refined depth and its confidence (:func:`depth_vs_points`). They still count in the keyframe's
depth range (all sparse points do), which is not a depth value. Depth: float32 z-depth in metres, 0/NaN
unknown, +inf sky; poses 4x4 camera-to-world.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera

__all__ = ['depth_vs_points', 'split_observed']


def split_observed(
    observed: Mapping[int, NDArray[np.float64]], fraction: float, seed: int
) -> tuple[dict[int, NDArray[np.float64]], dict[int, NDArray[np.float64]]]:
    """Per view, a random ``fraction`` of its observed points held back (checks) and the rest
    (seeds), both by stamp; reproducible with ``seed``."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f'fraction must be in (0, 1), got {fraction}')
    rng = np.random.default_rng(seed)
    seeds, checks = {}, {}
    for stamp in sorted(observed):
        pts = np.asarray(observed[stamp], np.float64).reshape(-1, 3)
        held = rng.random(len(pts)) < fraction
        seeds[stamp], checks[stamp] = pts[~held], pts[held]
    return seeds, checks


def depth_vs_points(
    depth: NDArray[np.floating],
    confidence: NDArray[np.floating] | None,
    camera: PinholeCamera,
    t_wc: NDArray[np.float64],
    points_w: NDArray[np.float64],
    *,
    confident: float = 0.5,
    tolerance: float = 0.2,
) -> dict[str, float]:
    """How ``depth`` agrees with ``points_w`` (Kx3 world) projected into the view.

    Returns ``points`` (in the image, in front), ``confident_points`` (with confidence >=
    ``confident``; all known ones without a confidence), ``confident_off`` / ``filled_off``: the
    fraction of confident / other known pixels more than ``tolerance`` (relative) off the point's
    depth, ``max_rel`` among the confident ones, ``unknown_at_points``, ``sparse_depth_m`` (median
    point depth: the height above ground of a nadir view) and ``deeper_than_2x``: the fraction of
    the image with finite depth beyond twice that.
    """
    d = np.asarray(depth, np.float32)
    u, v, z = camera.pixels_of(points_w, t_wc)
    out: dict[str, float] = {'points': float(len(z))}
    if not len(z):
        return out
    dz = d[v, u]
    known = np.isfinite(dz) & (dz > 0)
    conf = np.ones(len(z), bool) if confidence is None else np.asarray(confidence)[v, u] >= confident
    rel = np.abs(dz - z) / z
    c, f = known & conf, known & ~conf
    h = float(np.median(z))
    finite = np.isfinite(d) & (d > 0)
    out.update(
        {
            'confident_points': float(c.sum()),
            'confident_off': float(np.mean(rel[c] > tolerance)) if c.any() else 0.0,
            'max_rel': float(rel[c].max()) if c.any() else 0.0,
            'filled_points': float(f.sum()),
            'filled_off': float(np.mean(rel[f] > tolerance)) if f.any() else 0.0,
            'unknown_at_points': float(np.mean(~known)),
            'sparse_depth_m': h,
            'deeper_than_2x': float(np.count_nonzero(finite & (d > 2 * h)) / d.size),
        }
    )
    return out
