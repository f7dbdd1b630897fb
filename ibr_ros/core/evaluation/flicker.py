# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Temporal stability of rendered sequences: a smooth novel path through posed views and the excess
flicker of a render sequence over its ground truth (``ibr eval path``).

Metric (per frame ``t >= 1``, 8-bit RGB, colour units 0..255)::

    dR(p) = |R_t(p) - R_{t-1}(p)|,   dG(p) = |G_t(p) - G_{t-1}(p)|   (mean over the 3 channels)
    excess_t = mean over blocks B of max(0, mean_B dR - mean_B dG)

with ``R`` the renders and ``G`` the ground truth at the same poses, ``B`` the ``block`` x ``block``
px squares of the image (the remainder at the right and bottom edge left out) and ``mean_B`` the
mean over the pixels of ``B`` valid in both renders; blocks with fewer than half of their pixels
valid are left out (holes are reported as the valid fraction instead). ``block = 1`` is the per-pixel
form ``mean_p max(0, dR(p) - dG(p))``. Why blocks: per pixel, a render that is a fraction of a pixel
out of register with the truth on a textured surface has ``dR(p) != dG(p)`` at every textured pixel
(the same change, measured at a shifted place), a floor shared by every blend that hides the jumps of
view switching; a block compares the amount of change in a region, so register errors within it
cancel, while a region that changes when the truth does not (a view popping in, a best-view switch)
counts. Against the mean over the whole frame, a block does not let a blurrier render (less change
where the scene really moves) hide flicker elsewhere. Summary: the mean over frames and the worst
1 % (the mean of the worst ``ceil(1 %)`` of the frames, as the rephotography tail).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.transforms import (
    matrix_from_rt,
    quaternion_from_rotation,
    rotation_from_quaternion,
)

__all__ = [
    'FlickerSummary',
    'block_excess',
    'excess_flicker',
    'smooth_path',
    'summarise_flicker',
    'worst_mean',
]


def _check_rgb(name: str, img: NDArray) -> None:
    if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f'{name} must be an HxWx3 uint8 image, got {getattr(img, "shape", type(img))}')


def block_excess(
    r_prev: NDArray[np.uint8],
    r_cur: NDArray[np.uint8],
    g_prev: NDArray[np.uint8],
    g_cur: NDArray[np.uint8],
    valid: NDArray[np.bool_] | None = None,
    block: int = 16,
) -> float:
    """Excess temporal change of one frame pair in ``block`` px blocks (module docstring), colour
    units; NaN when no block counts. ``valid``: pixels valid in both renders (None: all)."""
    for name, img in (('r_prev', r_prev), ('r_cur', r_cur), ('g_prev', g_prev), ('g_cur', g_cur)):
        _check_rgb(name, img)
        if img.shape != r_prev.shape:
            raise ValueError(f'{name} is {img.shape}, r_prev is {r_prev.shape}: all four must match')
    if block < 1:
        raise ValueError(f'block must be >= 1 px, got {block}')
    h, w = r_prev.shape[:2]
    if valid is None:
        valid = np.ones((h, w), np.bool_)
    elif valid.shape != (h, w):
        raise ValueError(f'valid is {valid.shape}, the images are {(h, w)}')
    hb, wb = h // block * block, w // block * block
    if hb == 0 or wb == 0:
        return math.nan

    def change(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.float32]:
        d = np.abs(b[:hb, :wb].astype(np.int16) - a[:hb, :wb].astype(np.int16))
        return np.asarray(d.mean(axis=2, dtype=np.float32))

    def sums(x: NDArray) -> NDArray[np.float64]:
        return np.asarray(
            x.reshape(hb // block, block, wb // block, block).sum(axis=(1, 3), dtype=np.float64)
        )

    v = valid[:hb, :wb]
    n = sums(v)
    ok = n >= 0.5 * block * block
    if not ok.any():
        return math.nan
    dr = sums(np.where(v, change(r_prev, r_cur), 0.0))
    dg = sums(np.where(v, change(g_prev, g_cur), 0.0))
    ex = np.maximum(dr[ok] - dg[ok], 0.0) / n[ok]
    return float(ex.mean())


def excess_flicker(
    renders: Sequence[NDArray[np.uint8]],
    truths: Sequence[NDArray[np.uint8]],
    valids: Sequence[NDArray[np.bool_]] | None = None,
    block: int = 16,
) -> NDArray[np.float64]:
    """Per-frame excess flicker ``excess_1 .. excess_{n-1}`` of a render sequence over its ground truth
    in ``block`` px blocks (module docstring); ``valids[t]``: the pixels render ``t`` covers (None: all)."""
    if len(renders) != len(truths) or (valids is not None and len(valids) != len(renders)):
        raise ValueError(f'{len(renders)} renders, {len(truths)} truths: one of each per frame')
    out = np.empty(max(len(renders) - 1, 0))
    for t in range(1, len(renders)):
        both = None if valids is None else valids[t] & valids[t - 1]
        out[t - 1] = block_excess(renders[t - 1], renders[t], truths[t - 1], truths[t], both, block)
    return out


def worst_mean(values: ArrayLike, fraction: float = 0.01) -> float:
    """Mean of the largest ``ceil(fraction * n)`` finite values (NaN when there are none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    k = max(1, math.ceil(fraction * v.size))
    return float(np.sort(v)[-k:].mean())


FlickerSummary = dict[str, float]


def summarise_flicker(excess: ArrayLike) -> FlickerSummary:
    """``mean``, ``worst_1pct`` (:func:`worst_mean`), ``median`` and ``max`` of per-frame excess."""
    v = np.asarray(excess, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {'mean': math.nan, 'worst_1pct': math.nan, 'median': math.nan, 'max': math.nan, 'frames': 0}
    return {
        'mean': float(v.mean()),
        'worst_1pct': worst_mean(v),
        'median': float(np.median(v)),
        'max': float(v.max()),
        'frames': int(v.size),
    }


def _slerp(qa: NDArray[np.float64], qb: NDArray[np.float64], s: float) -> NDArray[np.float64]:
    """Unit quaternion ``s`` of the way from ``qa`` to ``qb`` (shortest arc)."""
    if float(qa @ qb) < 0:
        qb = -qb
    c = min(1.0, float(qa @ qb))
    if c > 0.9995:
        q = qa + s * (qb - qa)
        return np.asarray(q / np.linalg.norm(q), np.float64)
    th = math.acos(c)
    q = (math.sin((1 - s) * th) * qa + math.sin(s * th) * qb) / math.sin(th)
    return np.asarray(q, np.float64)


def smooth_path(
    poses: Sequence[ArrayLike], per_segment: int, offset_m: ArrayLike = (0.0, 0.0, 0.0)
) -> list[NDArray[np.float64]]:
    """A smooth camera path through ``poses`` (4x4 camera-to-world, at least 2): ``per_segment`` poses
    from each pose to the next (the last pose ends the path), positions on the uniform Catmull-Rom
    spline through the pose centres each moved by ``offset_m`` (metres, in that pose's optical frame:
    x right, y down, z forward; nonzero keeps the path off the captured poses), orientations by slerp.
    Positions are C1, orientations continuous."""
    if len(poses) < 2 or per_segment < 1:
        raise ValueError(f'need >= 2 poses and per_segment >= 1, got {len(poses)}, {per_segment}')
    mats = [np.asarray(p, np.float64).reshape(4, 4) for p in poses]
    off = np.asarray(offset_m, np.float64).reshape(3)
    pts = [m[:3, 3] + m[:3, :3] @ off for m in mats]
    quats = [quaternion_from_rotation(m[:3, :3]) for m in mats]
    ext = [2 * pts[0] - pts[1], *pts, 2 * pts[-1] - pts[-2]]
    out: list[NDArray[np.float64]] = []
    for i in range(len(mats) - 1):
        p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
        last = i == len(mats) - 2
        for k in range(per_segment + (1 if last else 0)):
            s = k / per_segment
            pos = 0.5 * (
                2 * p1
                + (p2 - p0) * s
                + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s * s
                + (3 * p1 - p0 - 3 * p2 + p3) * s * s * s
            )
            rot = rotation_from_quaternion(_slerp(quats[i], quats[i + 1], s))
            out.append(matrix_from_rt(rot, pos))
    return out
