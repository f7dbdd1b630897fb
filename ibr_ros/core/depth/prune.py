# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pruning median filters for MVS depth maps (Liu et al. 2020, "MVS Depth Preprocessing").

A known MVS sample ``d`` is pruned (set to 0) when ``d / m`` is outside ``[0.9, 1.1]``, where ``m``
is a median of the known depths around it: first a 5x5 median, then, on the result, a 31x31 median
weighted by colour similarity to the centre pixel (Zhang, Xu and Jia 2014, "100+ times faster
weighted median filter", weight type ``exp``).

Definitions used throughout (depth float32 metres; *known* = finite and > 0):

* window of ``p``: the ``size x size`` square centred on ``p``, clipped to the image; only known
  pixels in it take part.
* colour weight: ``w(p, q) = exp(-||c_p - c_q||^2 / (2 sigma_c^2))``, ``c = rgb / 255`` in
  ``[0, 1]^3`` (Euclidean RGB distance).  It is evaluated in float32 by a polynomial (relative error
  below 2e-5) and taken as 0 where the exponent exceeds 32 (``w < 1.3e-14``).
* weighted median: the *lower* weighted median ``m = min{d_q : sum_{d_q' <= d_q} w_q' >= W / 2}``
  (``W`` the total weight); with unit weights it is the lower median, the ``ceil(n / 2)``-th
  smallest value.  A median is therefore always one of the window's samples, never an average.

:func:`prune_depth` does not materialise the filtered maps: with the lower median,
``lo <= d / m <= hi`` is equivalent to ``2 W(d_q < d / hi) < W`` and ``2 W(d_q > d / lo) <= W``,
which it evaluates exactly (up to float32 rounding of the thresholds and sums; the brute-force
tests agree wherever the weighted sums are not within 1e-5 of a tie).  The 5x5 pass counts, for
every pixel.  The 31x31 pass first settles, exactly, every pixel whose window has all its known
depths inside ``[d / hi, d / lo]`` (window min/max: the sums above are then 0); only the rest pay
for weights, O(size^2) each: rows holding an out-of-range depth first, then the other rows
nearest-first until "keep" is certain (they only add to ``W``).  No quantisation is involved.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

__all__ = ['median_filter_valid', 'prune_depth', 'weighted_median_filter_valid']

_VEC = 16  # float32 lanes the weighted kernel's rows are padded to
_FAR_COLOUR = 1e4  # colour of unknown pixels: weight exactly 0 to any real colour


# --------------------------------------------------------------------------------------------- kernels


@njit(cache=True, fastmath=True, error_model='numpy')
def _colour_weight(d2, k):
    """``exp(-k * d2)`` in float32 (0 beyond an exponent of 32); vectorisable, no libm call."""
    t = d2 * k
    s = t * np.float32(1.0 / 64.0)  # exp(-t) = exp(-s)^64, exp(-s) by Taylor to s^7 on [0, 0.5)
    e = np.float32(1.0 / 720.0) - s * np.float32(1.0 / 5040.0)
    e = np.float32(1.0 / 120.0) - s * e
    e = np.float32(1.0 / 24.0) - s * e
    e = np.float32(1.0 / 6.0) - s * e
    e = np.float32(1.0 / 2.0) - s * e
    e = np.float32(1.0) - s * e
    e = np.float32(1.0) - s * e
    for _ in range(6):
        e = e * e
    return e if t < np.float32(32.0) else np.float32(0.0)


@njit(cache=True)
def _median_values(v, r):
    """Lower median of the known (> 0) values of ``v`` in each clipped window; 0 where none."""
    H, W = v.shape
    out = np.zeros((H, W), np.float32)
    buf = np.empty((2 * r + 1) ** 2, np.float32)
    for y in range(H):
        for x in range(W):
            n = 0
            for yy in range(max(0, y - r), min(H, y + r + 1)):
                for xx in range(max(0, x - r), min(W, x + r + 1)):
                    q = v[yy, xx]
                    if q > 0:
                        buf[n] = q
                        n += 1
            if n > 0:
                out[y, x] = np.sort(buf[:n])[(n - 1) // 2]
    return out


@njit(cache=True)
def _weighted_median_values(v, col, r, k):
    """Lower colour-weighted median of the known values of ``v`` per clipped window; 0 where none."""
    H, W = v.shape
    out = np.zeros((H, W), np.float32)
    vals = np.empty((2 * r + 1) ** 2, np.float32)
    wts = np.empty((2 * r + 1) ** 2, np.float64)
    for y in range(H):
        for x in range(W):
            n = 0
            total = 0.0
            for yy in range(max(0, y - r), min(H, y + r + 1)):
                for xx in range(max(0, x - r), min(W, x + r + 1)):
                    q = v[yy, xx]
                    if q > 0:
                        d2 = np.float32(0.0)
                        for c in range(3):
                            dc = col[c, yy, xx] - col[c, y, x]
                            d2 += dc * dc
                        w = _colour_weight(d2, k)
                        vals[n] = q
                        wts[n] = w
                        total += w
                        n += 1
            if n == 0:
                continue
            idx = np.argsort(vals[:n])
            cum = 0.0
            out[y, x] = vals[idx[n - 1]]
            for i in range(n):
                cum += wts[idx[i]]
                if 2.0 * cum >= total:
                    out[y, x] = vals[idx[i]]
                    break
    return out


@njit(cache=True, fastmath=True, error_model='numpy')
def _count_keep(vp, lo_t, hi_t, r):
    """Unit-weight median test on a zero-padded ``vp``: ``2 n(q < lo_t) < n and 2 n(q > hi_t) <= n``."""
    H, W = lo_t.shape
    keep = np.zeros((H, W), np.bool_)
    n = np.empty(W, np.int32)
    nl = np.empty(W, np.int32)
    nh = np.empty(W, np.int32)
    for y in range(H):
        n[:] = 0
        nl[:] = 0
        nh[:] = 0
        lo_row = lo_t[y]
        hi_row = hi_t[y]
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                q = vp[y + dy, dx : dx + W]
                for x in range(W):
                    qq = q[x]
                    n[x] += qq > 0
                    nl[x] += (qq > 0) & (qq < lo_row[x])
                    nh[x] += qq > hi_row[x]
        for x in range(W):
            keep[y, x] = (2 * nl[x] < n[x]) & (2 * nh[x] <= n[x])
    return keep


@njit(cache=True)
def _row_min_max(v, r):
    """Min / max of the known (> 0) values of each row of ``v`` over ``[x - r, x + r]`` (clipped).

    ``inf`` / 0 where there is none.  The outputs have ``r`` extra rows (with none) above and
    below.  van Herk / Gil-Werman: O(1) per pixel for any ``r``.
    """
    H, W = v.shape
    n = 2 * r + 1
    L = W + 2 * r
    inf = np.float32(np.inf)
    g_min = np.empty(L, np.float32)
    g_max = np.empty(L, np.float32)
    h_min = np.empty(L, np.float32)
    h_max = np.empty(L, np.float32)
    out_min = np.full((H + 2 * r, W), inf, np.float32)
    out_max = np.zeros((H + 2 * r, W), np.float32)
    for y in range(H):
        row = v[y]
        k = 0
        for i in range(L):  # running min / max from the start of each block of n
            a = row[i - r] if r <= i < r + W else np.float32(0.0)
            a_min = a if a > 0 else inf
            if k == 0:
                g_min[i] = a_min
                g_max[i] = a
            else:
                g_min[i] = min(g_min[i - 1], a_min)
                g_max[i] = max(g_max[i - 1], a)
            k = k + 1 if k + 1 < n else 0
        for i in range(L - 1, -1, -1):  # ... and to the end of each block
            a = row[i - r] if r <= i < r + W else np.float32(0.0)
            a_min = a if a > 0 else inf
            if i == L - 1 or (i + 1) % n == 0:
                h_min[i] = a_min
                h_max[i] = a
            else:
                h_min[i] = min(h_min[i + 1], a_min)
                h_max[i] = max(h_max[i + 1], a)
        for x in range(W):
            out_min[y + r, x] = min(h_min[x], g_min[x + 2 * r])
            out_max[y + r, x] = max(h_max[x], g_max[x + 2 * r])
    return out_min, out_max


@njit(cache=True, fastmath=True, error_model='numpy')
def _column_min_max(row_min, row_max, r):
    """Window min / max from the padded row min / max of :func:`_row_min_max`, van Herk."""
    L, W = row_min.shape
    H = L - 2 * r
    n = 2 * r + 1
    g_min = np.empty((L, W), np.float32)
    g_max = np.empty((L, W), np.float32)
    h_min = np.empty((L, W), np.float32)
    h_max = np.empty((L, W), np.float32)
    for i in range(L):
        start = i % n == 0
        for x in range(W):
            g_min[i, x] = row_min[i, x] if start else min(g_min[i - 1, x], row_min[i, x])
            g_max[i, x] = row_max[i, x] if start else max(g_max[i - 1, x], row_max[i, x])
    for i in range(L - 1, -1, -1):
        end = i == L - 1 or (i + 1) % n == 0
        for x in range(W):
            h_min[i, x] = row_min[i, x] if end else min(h_min[i + 1, x], row_min[i, x])
            h_max[i, x] = row_max[i, x] if end else max(h_max[i + 1, x], row_max[i, x])
    out_min = np.empty((H, W), np.float32)
    out_max = np.empty((H, W), np.float32)
    for y in range(H):
        for x in range(W):
            out_min[y, x] = min(h_min[y, x], g_min[y + 2 * r, x])
            out_max[y, x] = max(h_max[y, x], g_max[y + 2 * r, x])
    return out_min, out_max


@njit(cache=True)
def _padded_inputs(v, rgb, r, sp):
    """Depth and float32 colour planes padded by ``r`` (``sp - r`` on the right) for the kernel below.

    Unknown and padding pixels get depth 0 and colour ``_FAR_COLOUR``.
    """
    H, W = v.shape
    far = np.float32(_FAR_COLOUR)
    vp = np.zeros((H + 2 * r, W + sp), np.float32)
    colp = np.full((3, H + 2 * r, W + sp), far, np.float32)
    for y in range(H):
        for x in range(W):
            if v[y, x] > 0:
                vp[y + r, x + r] = v[y, x]
                for c in range(3):
                    colp[c, y + r, x + r] = rgb[y, x, c]
    return vp, colp


@njit(cache=True, fastmath=True, error_model='numpy', parallel=True)
def _weighted_keep_at(vp, colp, row_min, row_max, ys, xs, lo_t, hi_t, r, colmask, k):
    """Colour-weighted median test for the listed centres: ``2 W(q < lo) < W and 2 W(q > hi) <= W``.

    ``vp`` and ``colp`` (3 planes) are padded by ``r`` on the left/top/bottom and by
    ``len(colmask) - r`` on the right; ``colmask`` zeroes the columns read past the window.  Unknown
    and padding pixels carry a colour far from any real one, so their weight is exactly 0.
    ``row_min`` / ``row_max`` (padded by ``r`` rows) are the known depths' min / max over each
    window row.  Rows holding a depth outside ``[lo, hi]`` are summed first; the others only add to
    ``W``, so they are summed nearest-first and only until the verdict is "keep" (which more weight
    cannot change).
    """
    sp = colmask.shape[0]
    n = 2 * r + 1
    keep = np.zeros(ys.shape[0], np.bool_)
    for i in prange(ys.shape[0]):  # centres are independent: spread over the cores
        outside = np.empty(n, np.bool_)
        y = ys[i]
        x = xs[i]
        cr = colp[0, y + r, x + r]
        cg = colp[1, y + r, x + r]
        cb = colp[2, y + r, x + r]
        lo = lo_t[i]
        hi = hi_t[i]
        a_sum = np.float32(0.0)
        b_sum = np.float32(0.0)
        t_sum = np.float32(0.0)
        ok = False
        for phase in range(2):
            for o in range(n):
                dy = r + (o + 1) // 2 if o % 2 else r - o // 2  # r, r + 1, r - 1, r + 2, ...
                if phase == 0:
                    outside[dy] = (row_min[y + dy, x] < lo) | (row_max[y + dy, x] > hi)
                    if not outside[dy]:
                        continue
                elif outside[dy]:
                    continue
                q = vp[y + dy, x : x + sp]
                rr = colp[0, y + dy, x : x + sp]
                gg = colp[1, y + dy, x : x + sp]
                bb = colp[2, y + dy, x : x + sp]
                for j in range(sp):
                    dr = rr[j] - cr
                    dg = gg[j] - cg
                    db = bb[j] - cb
                    w = _colour_weight(dr * dr + dg * dg + db * db, k) * colmask[j]
                    t_sum += w
                    a_sum += w if q[j] < lo else np.float32(0.0)
                    b_sum += w if q[j] > hi else np.float32(0.0)
                ok = (2 * a_sum < t_sum) & (2 * b_sum <= t_sum)
                if phase == 1 and ok:
                    break
            ok = (2 * a_sum < t_sum) & (2 * b_sum <= t_sum)
            if ok:
                break
        keep[i] = ok
    return keep


# --------------------------------------------------------------------------------------------- checks


def _check_depth(d: np.ndarray) -> None:
    if not isinstance(d, np.ndarray) or d.dtype != np.float32:
        raise ValueError(f'depth must be a float32 array, got {getattr(d, "dtype", type(d).__name__)}')
    if d.ndim != 2:
        raise ValueError(f'depth must be 2-D (H, W), got shape {d.shape}')


def _check_rgb(rgb: np.ndarray, shape: tuple[int, ...]) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8:
        raise ValueError(f'rgb must be a uint8 array, got {getattr(rgb, "dtype", type(rgb).__name__)}')
    if rgb.shape != (*shape, 3):
        raise ValueError(f'rgb has shape {rgb.shape}, expected {(*shape, 3)} (the depth size x 3)')


def _radius(name: str, size: int) -> int:
    if not isinstance(size, (int, np.integer)) or size < 1 or size % 2 == 0:
        raise ValueError(f'{name} must be an odd positive int, got {size!r}')
    return int(size) // 2


def _weight_k(sigma_c: float) -> np.float32:
    s = float(sigma_c)
    if not (s > 0 and math.isfinite(s)):
        raise ValueError(f'sigma_c must be positive and finite, got {sigma_c}')
    return np.float32(1.0 / (2.0 * (255.0 * s) ** 2))  # per squared 8-bit colour difference


def _known(d: np.ndarray) -> NDArray[np.float32]:
    """``d`` with every unknown (non-finite or <= 0) sample set to 0."""
    return np.where(np.isfinite(d) & (d > 0), d, np.float32(0)).astype(np.float32)


def _planes(rgb: np.ndarray) -> NDArray[np.float32]:
    return np.ascontiguousarray(np.moveaxis(rgb, 2, 0), dtype=np.float32)


# --------------------------------------------------------------------------------------------- public


def median_filter_valid(d: np.ndarray, size: int) -> NDArray[np.float32]:
    """Lower median of the known depths in each ``size x size`` window (clipped); 0 where none.

    ``d`` float32 H x W; unknown samples (non-finite or <= 0) are ignored.  O(size^2 log size)
    per pixel.
    """
    _check_depth(d)
    return _median_values(_known(d), _radius('size', size))


def weighted_median_filter_valid(
    d: np.ndarray, rgb: np.ndarray, size: int = 31, sigma_c: float = 0.033
) -> NDArray[np.float32]:
    """Lower colour-weighted median of the known depths in each window (module docstring); 0 where none.

    ``d`` float32 H x W; ``rgb`` uint8 H x W x 3 gives the weights (the centre's own colour is used
    also where its depth is unknown).  A direct O(size^2 log size) per pixel evaluation: a reference
    and inspection tool; :func:`prune_depth` uses the equivalent threshold test instead.
    """
    _check_depth(d)
    _check_rgb(rgb, d.shape)
    return _weighted_median_values(_known(d), _planes(rgb), _radius('size', size), _weight_k(sigma_c))


def prune_depth(
    d_mvs: np.ndarray,
    rgb: np.ndarray,
    *,
    small: int = 5,
    large: int = 31,
    sigma_c: float = 0.033,
    ratio: tuple[float, float] = (0.9, 1.1),
) -> NDArray[np.float32]:
    """Prune outliers from an MVS depth map: a float32 copy with pruned samples set to 0.

    A known sample ``d`` survives a pass when ``ratio[0] <= d / m <= ratio[1]`` for the median ``m``
    of that pass: first the unweighted ``small x small`` median of the known depths, then, on the
    result, the ``large x large`` colour-weighted median (``sigma_c`` on colours in [0, 1]).  Unknown
    samples (non-finite or <= 0) are ignored by both filters and returned unchanged.
    """
    _check_depth(d_mvs)
    _check_rgb(rgb, d_mvs.shape)
    r_small = _radius('small', small)
    r_large = _radius('large', large)
    k = _weight_k(sigma_c)
    lo, hi = (float(x) for x in ratio)
    if not (0 < lo <= hi and math.isfinite(hi)):
        raise ValueError(f'ratio must be (lo, hi) with 0 < lo <= hi < inf, got {ratio!r}')

    v = _known(d_mvs)
    known = v > 0
    lo_t = (v / hi).astype(np.float32)  # m >= d / hi  <=>  d / m <= hi
    hi_t = (v / lo).astype(np.float32)  # m <= d / lo  <=>  d / m >= lo
    keep = _count_keep(np.pad(v, r_small), lo_t, hi_t, r_small)
    v = np.where(keep, v, np.float32(0))

    row_min, row_max = _row_min_max(v, r_large)
    wmin, wmax = _column_min_max(row_min, row_max, r_large)
    unsure = (v > 0) & ((wmin < lo_t) | (wmax > hi_t))
    ys, xs = np.nonzero(unsure)
    if ys.size:
        sp = -(-(2 * r_large + 1) // _VEC) * _VEC
        vp, colp = _padded_inputs(v, np.ascontiguousarray(rgb), r_large, sp)
        colmask = (np.arange(sp) < 2 * r_large + 1).astype(np.float32)
        args = (ys, xs, lo_t[ys, xs], hi_t[ys, xs], r_large, colmask, k)
        ok = _weighted_keep_at(vp, colp, row_min, row_max, *args)
        v[ys[~ok], xs[~ok]] = 0

    out = d_mvs.copy()
    out[known & (v == 0)] = 0
    return out
