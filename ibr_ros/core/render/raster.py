# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Rasterisation of warped superpixels into per-view superpixel-id images (numba kernels)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ibr_ros.core.render.projection import lands_near

__all__ = ['affine_maps', 'raster_views', 'row_spans']


@njit(cache=True)
def row_spans(labels, bbox, span_off, spans):
    """Column extent of every superpixel in every row of its box (empty rows: ``x_min > x_max``)."""
    spans[:, 0] = 32767
    spans[:, 1] = -1
    h, w = labels.shape
    for y in range(h):
        for x in range(w):
            k = labels[y, x]
            r = span_off[k] + y - bbox[k, 1]
            if x < spans[r, 0]:
                spans[r, 0] = x
            spans[r, 1] = x  # raster order: the last one is the largest


@njit(cache=True)
def affine_maps(src, dst, ok, bbox, max_area, w, h, inv, box):
    """Inverse affine maps (novel -> source) of the warped triangles and their destination boxes.

    Clears ``ok`` for flipped, degenerate, over-magnified or off-screen warps.
    """
    for k in range(src.shape[0]):
        if not ok[k]:
            continue
        s1x, s1y = src[k, 0, 0], src[k, 0, 1]
        s2x, s2y = src[k, 1, 0], src[k, 1, 1]
        s3x, s3y = src[k, 2, 0], src[k, 2, 1]
        d1x, d1y = dst[k, 0, 0], dst[k, 0, 1]
        d2x, d2y = dst[k, 1, 0], dst[k, 1, 1]
        d3x, d3y = dst[k, 2, 0], dst[k, 2, 1]
        ds = (s2x - s1x) * (s3y - s1y) - (s3x - s1x) * (s2y - s1y)
        dd = (d2x - d1x) * (d3y - d1y) - (d3x - d1x) * (d2y - d1y)
        ratio = dd / ds
        if not (ratio > 1e-6 and ratio < max_area):
            ok[k] = False
            continue
        # linear parts: source = B (d - d1) + s1, destination = A (s - s1) + d1
        ia = (d3y - d1y) / dd
        ib = -(d3x - d1x) / dd
        ic = -(d2y - d1y) / dd
        id_ = (d2x - d1x) / dd
        b00 = (s2x - s1x) * ia + (s3x - s1x) * ic
        b01 = (s2x - s1x) * ib + (s3x - s1x) * id_
        b10 = (s2y - s1y) * ia + (s3y - s1y) * ic
        b11 = (s2y - s1y) * ib + (s3y - s1y) * id_
        inv[k, 0, 0] = b00
        inv[k, 0, 1] = b01
        inv[k, 0, 2] = s1x - b00 * d1x - b01 * d1y
        inv[k, 1, 0] = b10
        inv[k, 1, 1] = b11
        inv[k, 1, 2] = s1y - b10 * d1x - b11 * d1y
        det = b00 * b11 - b01 * b10
        a00 = b11 / det
        a01 = -b01 / det
        a10 = -b10 / det
        a11 = b00 / det
        xmin = np.inf
        xmax = -np.inf
        ymin = np.inf
        ymax = -np.inf
        for cx in range(2):
            for cy in range(2):
                sx = (bbox[k, 0] - 0.5 if cx == 0 else bbox[k, 2] + 0.5) - s1x
                sy = (bbox[k, 1] - 0.5 if cy == 0 else bbox[k, 3] + 0.5) - s1y
                x = a00 * sx + a01 * sy + d1x
                y = a10 * sx + a11 * sy + d1y
                xmin = min(xmin, x)
                xmax = max(xmax, x)
                ymin = min(ymin, y)
                ymax = max(ymax, y)
        if not (xmax >= 0.0 and ymax >= 0.0 and xmin <= w - 1.0 and ymin <= h - 1.0):  # also NaN
            ok[k] = False
            continue
        x0 = math.ceil(max(xmin, 0.0))
        x1 = math.floor(min(xmax, w - 1.0))
        y0 = math.ceil(max(ymin, 0.0))
        y1 = math.floor(min(ymax, h - 1.0))
        if x0 > x1 or y0 > y1:
            ok[k] = False
            continue
        box[k, 0] = x0
        box[k, 1] = y0
        box[k, 2] = x1
        box[k, 3] = y1


@njit(cache=True)
def _span(ib, c, lo, hi, xs, xe):
    """Sub-interval of ``[xs, xe]`` where ``lo <= b * x + c <= hi``, ``ib = 1 / b`` (0: ``b == 0``).

    Empty when the result has ``xs > xe``.
    """
    if ib == 0.0:
        return (xs, xe) if lo <= c <= hi else (1.0, 0.0)
    a1 = (lo - c) * ib
    a2 = (hi - c) * ib
    if a1 > a2:
        a1, a2 = a2, a1
    return max(xs, a1), min(xe, a2)


@njit(cache=True)
def _raster_band(labels, bbox, span_off, spans, order, inv, box, ids, fb, r0, r1, depth, rel, thr2):
    """Rows ``r0..r1`` of :func:`raster_views` for one view."""
    for oi in range(order.size):
        k = order[oi]
        ya = max(box[k, 1], r0)
        yb = min(box[k, 3], r1)
        if ya > yb:
            continue
        b00, b01, b02 = inv[k, 0, 0], inv[k, 0, 1], inv[k, 0, 2]
        b10, b11, b12 = inv[k, 1, 0], inv[k, 1, 1], inv[k, 1, 2]
        bx0, by0, bx1, by1 = bbox[k, 0], bbox[k, 1], bbox[k, 2], bbox[k, 3]
        kk = labels.dtype.type(k)
        ib0 = 1.0 / b00 if abs(b00) > 1e-12 else 0.0
        ib1 = 1.0 / b10 if abs(b10) > 1e-12 else 0.0
        for y in range(ya, yb + 1):
            cu = b01 * y + b02
            cv = b11 * y + b12
            xs, xe = _span(ib0, cu, bx0 - 0.5, bx1 + 0.5, np.float64(box[k, 0]), np.float64(box[k, 2]))
            xs, xe = _span(ib1, cv, by0 - 0.5, by1 + 0.5, xs, xe)
            if xs > xe:
                continue
            # clip by the column extent of the superpixel in the source rows the segment crosses
            va = b10 * xs + cv
            vb = b10 * xe + cv
            ra = min(max(int(min(va, vb) + 0.5), by0), by1)
            rb = min(max(int(max(va, vb) + 0.5), by0), by1)
            sx0 = 32767
            sx1 = -1
            for sr in range(span_off[k] + ra - by0, span_off[k] + rb - by0 + 1):
                sx0 = min(sx0, spans[sr, 0])
                sx1 = max(sx1, spans[sr, 1])
            xs, xe = _span(ib0, cu, sx0 - 0.5, sx1 + 0.5, xs, xe)
            if xs > xe:
                continue
            x0 = int(xs)  # xs, xe >= 0 here: int() is floor
            x0 += x0 < xs
            x1 = int(xe)
            u = b00 * x0 + cu
            v = b10 * x0 + cv
            check = thr2 >= 0
            hx = hy = hz = sx = sy = sz = 0.0
            if check:  # H (u, v, 1) of the pre-image is affine in x along the row
                hx = rel[0] * u + rel[1] * v + rel[2]
                hy = rel[3] * u + rel[4] * v + rel[5]
                hz = rel[6] * u + rel[7] * v + rel[8]
                sx = rel[0] * b00 + rel[1] * b10
                sy = rel[3] * b00 + rel[4] * b10
                sz = rel[6] * b00 + rel[7] * b10
            for x in range(x0, x1 + 1):
                if ids[y, x] < 0:
                    ui = min(max(int(u + 0.5), bx0), bx1)  # u >= bx0 - 0.5 > -1: int() is floor
                    vi = min(max(int(v + 0.5), by0), by1)
                    if labels[vi, ui] == kk:
                        if not check or lands_near(depth[vi, ui], hx, hy, hz, rel, x, y, thr2):
                            ids[y, x] = k
                        elif fb[y, x] < 0:
                            fb[y, x] = k
                u += b00
                v += b10
                hx += sx
                hy += sy
                hz += sz


@njit(cache=True, parallel=True)
def raster_views(
    labels, depths, n, bbox, span_off, spans, order, order_off, inv, box, rel, thr2, ids, fb, n_bands
):
    """Draw the warped superpixels of ``n <= 4`` views front to back into their id buffers.

    ``labels`` / ``depths``: tuples of 4 same-typed arrays (views ``n..3`` repeat one of them), the
    superpixel labels and z-depths (m) of the source views; ``rel[j]``: view ``j``'s
    :func:`~ibr_ros.core.render.projection.reprojection_params`; ``thr2``: squared coverage
    threshold (px^2, < 0: off, see :func:`~ibr_ros.core.render.projection.lands_near`).
    View ``j`` (labels ``labels[j]``, boxes ``bbox[j]``, row extents ``spans[span_off[j, k] + y - y0]``,
    inverse affine maps ``inv[j]``, destination boxes ``box[j]``) draws superpixels
    ``order[order_off[j]:order_off[j + 1]]`` (nearest first). ``ids[j]`` (-1 = free) gets the
    superpixel of every pixel that maps back onto one of that superpixel's own source pixels
    (nearest pixel); the first (nearest) superpixel keeps a pixel. ``fb[j]`` (same shape) gets the
    first superpixel that failed only the coverage test there (the caller's fallback where ``ids[j]``
    stays free). Only the x-range of each row
    whose pre-image lies in the superpixel's box and in its column extent over the source rows
    crossed (both grown by half a pixel) is visited. Rows are split into ``n_bands`` bands
    processed in parallel.
    """
    h = ids.shape[1]
    for band in prange(n_bands):
        r0 = band * h // n_bands
        r1 = (band + 1) * h // n_bands - 1
        for j in range(n):
            _raster_band(
                labels[j],
                bbox[j],
                span_off[j],
                spans,
                order[order_off[j] : order_off[j + 1]],
                inv[j],
                box[j],
                ids[j],
                fb[j],
                r0,
                r1,
                depths[j],
                rel[j],
                thr2,
            )
