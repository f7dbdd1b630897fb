# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Filling the small inner holes of a render: cracks between warped superpixels (numba kernel)."""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ['fill_small_holes']

#: 8-neighbourhood, the 4 edge neighbours first: ``(dy, dx, weight)``.
_DY = np.array([0, 0, -1, 1, -1, -1, 1, 1], np.int64)
_DX = np.array([-1, 1, 0, 0, -1, 1, -1, 1], np.int64)
_WT = np.array([1.0, 1.0, 1.0, 1.0, 0.7071, 0.7071, 0.7071, 0.7071], np.float32)


def fill_small_holes(
    rgb: NDArray[np.uint8],
    valid: NDArray[np.bool_],
    source: NDArray[np.int16],
    depth: NDArray[np.float32],
    *,
    max_px: int,
) -> int:
    """Fill, in place, the holes of a render (8-connected components of ``~valid``) of at most
    ``max_px`` pixels that do not touch the image border: cracks between warped superpixels, not
    missing scene. Returns the number of pixels filled; they become valid.

    The holes are filled from their rims inwards, one ring of pixels at a time: a pixel's colour is
    the weighted mean of its 8 neighbours already known (rendered or filled by an earlier ring;
    diagonal ones weigh 1/sqrt(2)), its ``source`` and ``depth`` are those of its first known
    neighbour (edge neighbours before diagonal ones).
    """
    if max_px < 0:
        raise ValueError(f'fill_small_holes: max_px must be >= 0, got {max_px}')
    h, w = valid.shape
    if rgb.shape != (h, w, 3) or source.shape != (h, w) or depth.shape != (h, w):
        raise ValueError(
            f'fill_small_holes: rgb {rgb.shape}, source {source.shape} and depth {depth.shape} '
            f'must match valid {valid.shape} (rgb with 3 channels)'
        )
    n, labels, stats, _ = cv2.connectedComponentsWithStats(
        np.logical_not(valid).view(np.uint8), connectivity=8, ltype=cv2.CV_32S
    )
    if n <= 1:
        return 0
    x, y, bw, bh, area = stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3], stats[:, 4]
    inner = (area <= max_px) & (x > 0) & (y > 0) & (x + bw < w) & (y + bh < h)
    inner[0] = False  # the background label (rendered pixels)
    total = int(area[inner].sum())
    if not total:
        return 0
    return int(_peel(rgb, valid, source, depth, labels, inner, total, _DY, _DX, _WT))


@njit(cache=True)
def _peel(rgb, valid, source, depth, labels, inner, total, dys, dxs, wts):
    """Fill the pixels of the ``inner`` components of ``labels`` ring by ring (see the wrapper).

    ``labels`` is scratch: a pixel queued for filling gets label -1.
    """
    h, w = valid.shape
    ring_y = np.empty(total, np.int64)
    ring_x = np.empty(total, np.int64)
    nxt_y = np.empty(total, np.int64)
    nxt_x = np.empty(total, np.int64)
    cnt = 0
    for yy in range(1, h - 1):  # the first ring: hole pixels with a rendered neighbour
        for xx in range(1, w - 1):
            lab = labels[yy, xx]
            if lab > 0 and inner[lab]:
                for q in range(8):
                    if valid[yy + dys[q], xx + dxs[q]]:
                        ring_y[cnt] = yy
                        ring_x[cnt] = xx
                        labels[yy, xx] = -1
                        cnt += 1
                        break
    filled = 0
    while cnt > 0:
        for i in range(cnt):
            yy, xx = ring_y[i], ring_x[i]
            ar = ag = ab = sw = np.float32(0.0)
            first = -1
            for q in range(8):
                ny, nx = yy + dys[q], xx + dxs[q]
                if valid[ny, nx]:
                    wt = wts[q]
                    ar += wt * np.float32(rgb[ny, nx, 0])
                    ag += wt * np.float32(rgb[ny, nx, 1])
                    ab += wt * np.float32(rgb[ny, nx, 2])
                    sw += wt
                    if first < 0:
                        first = q
            rgb[yy, xx, 0] = np.uint8(min(ar / sw + np.float32(0.5), np.float32(255.0)))
            rgb[yy, xx, 1] = np.uint8(min(ag / sw + np.float32(0.5), np.float32(255.0)))
            rgb[yy, xx, 2] = np.uint8(min(ab / sw + np.float32(0.5), np.float32(255.0)))
            source[yy, xx] = source[yy + dys[first], xx + dxs[first]]
            depth[yy, xx] = depth[yy + dys[first], xx + dxs[first]]
        for i in range(cnt):  # the ring is known only now: its pixels do not feed each other
            valid[ring_y[i], ring_x[i]] = True
        filled += cnt
        m = 0
        for i in range(cnt):  # the next ring: unqueued hole pixels next to this one
            for q in range(8):
                ny, nx = ring_y[i] + dys[q], ring_x[i] + dxs[q]
                lab = labels[ny, nx]
                if lab > 0 and inner[lab]:
                    labels[ny, nx] = -1
                    nxt_y[m] = ny
                    nxt_x[m] = nx
                    m += 1
        ring_y, nxt_y = nxt_y, ring_y
        ring_x, nxt_x = nxt_x, ring_x
        cnt = m
    return filled
