# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The sweep kernels of :mod:`ibr_ros.core.depth.mvs` before the third kernel speed-up (main at
cf48d5e, after round 2 of issue 15 and its review fixes): ``_warp_rows``, ``_zncc_score``,
``_zncc_rows`` and ``_sweep`` verbatim, kept as the baseline of ``bench_sweep_kernel.py``.
:func:`_sweep` takes the arguments of ``mvs._sweep`` (``base`` of shape (1 or P, H, W) since
round 3), so patching ``mvs._sweep`` with it runs the whole pipeline on the previous kernels: one
base as before, one base per hypothesis (round 3's batched propagation) as mvs did before, one call
per base and the first best score wins. Not used by the package. ``_sweep_kernel_baseline_606ef63.py``:
the kernels before round 1 (``--round1``: the cumulative ratio).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit, prange

#: LLVM fast-math flags of the sweep kernels: IEEE division and square root (no 'arcp'/'afn'
#: approximations), reassociation and contraction allowed. With ``error_model='numpy'`` (no
#: ZeroDivisionError checks) the per-pixel loops vectorise.
_FASTMATH = {'nnan', 'ninf', 'nsz', 'contract', 'reassoc'}


@njit(cache=True, fastmath=_FASTMATH, error_model='numpy')
def _warp_rows(src, hs, ws, a, b, base, off, ya, yb, out, valid, y0, y1):
    """Rows ``ya:yb`` of one source warped into the reference at inverse depth ``base + off``.

    A reference pixel (u, v) maps to ``a @ (u, v, 1) + rho * b`` (homogeneous source pixel), with
    ``a = K_s R K_r^-1`` and ``b = K_s t``, in float32 (about 1e-4 px at 1000 px). Bilinear, border
    clamped; ``valid`` (rows ``y0:y1``) is False where the centre falls outside the source or behind
    it, or ``rho <= 0``. Per row, a loop that vectorises computes each pixel's top-left tap (flat
    index into ``src``, which must be C-contiguous) and bilinear weights, then a second one reads
    the 4 taps.
    """
    W = out.shape[1]
    f32 = np.float32
    a00, a10, a20 = f32(a[0, 0]), f32(a[1, 0]), f32(a[2, 0])
    b0, b1, b2 = f32(b[0]), f32(b[1]), f32(b[2])
    lo, hx, hy = f32(-0.5), f32(ws - 0.5), f32(hs - 0.5)
    xmax, ymax = f32(ws - 1.001), f32(hs - 1.001)
    zero, tiny = f32(0.0), f32(1e-9)
    stride = src.shape[1]
    flat = src.ravel()
    u1, us, us1 = np.uint32(1), np.uint32(stride), np.uint32(stride + 1)
    tap = np.empty(W, np.uint32)  # unsigned: no negative-index wraparound in the gather loop
    fxs = np.empty(W, np.float32)
    fys = np.empty(W, np.float32)
    ok = np.empty(W, np.bool_)
    for y in range(ya, yb):
        c0 = f32(a[0, 1] * y + a[0, 2])
        c1 = f32(a[1, 1] * y + a[1, 2])
        c2 = f32(a[2, 1] * y + a[2, 2])
        brow = base[y]
        for x in range(W):
            xf = f32(x)
            rho = brow[x] + off
            h2 = a20 * xf + c2 + rho * b2
            front = (h2 > tiny) & (rho > zero)
            inv = f32(1.0) / (h2 if front else f32(1.0))  # finite: no inf/NaN under fast-math
            sx = (a00 * xf + c0 + rho * b0) * inv
            sy = (a10 * xf + c1 + rho * b1) * inv
            ok[x] = front & (lo <= sx) & (sx <= hx) & (lo <= sy) & (sy <= hy)
            qx = min(max(sx, zero), xmax) if front else zero
            qy = min(max(sy, zero), ymax) if front else zero
            x0 = np.int32(qx)
            yi = np.int32(qy)
            tap[x] = np.uint32(yi * stride + x0)
            fxs[x] = qx - f32(x0)
            fys[x] = qy - f32(yi)
        orow = out[y - ya]
        for x in range(W):
            k = tap[x]
            fx = fxs[x]
            t0 = flat[k]
            top = t0 + fx * (flat[k + u1] - t0)
            u0 = flat[k + us]
            bot = u0 + fx * (flat[k + us1] - u0)
            orow[x] = top + fys[x] * (bot - top)
        if y0 <= y < y1:
            valid[y - y0, :] = ok


@njit(inline='always')
def _zncc_score(h0, h1, h2, inv, m, v, ok):
    """ZNCC of one window from its source sums ``h0``, ``h1``, ``h2`` (sum, sum of squares, sum of
    products with the reference), 1 / its area, the reference mean ``m`` and variance ``v``."""
    ms = h0 * inv
    den = v * (h1 * inv - ms * ms)
    z = (h2 * inv - m * ms) / math.sqrt(max(den, 1e-6))
    z = z if den > 1e-6 else 0.0
    return z if ok else -1.0


@njit(cache=True, fastmath=_FASTMATH, error_model='numpy')
def _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zrow, tops):
    """Windowed ZNCC of the warped rows ``s`` (from row ``ya``) against the reference, rows y0:y1,
    inserted into ``tops`` (k, y1 - y0, W: per pixel the k best scores so far, descending).

    Running column sums (float64; one pass per row adds the entering and subtracts the leaving row)
    over (2r+1)^2 boxes truncated at the image border, the same boxes as :func:`_box_stats`; invalid
    centres score -1, flat source windows 0. The column sums have r zero columns each side (the
    loops index the views ``d*`` by x: an offset index kept them from vectorising); for r = 3
    (7-pixel windows) the row sums are 7 direct taps in the loop that computes the scores
    (vectorised), otherwise serial running sums into row buffers. ``zrow``: float32, W scores.
    """
    H, W = ref.shape
    Wp = W + 2 * r
    c0 = np.zeros(Wp)  # column sums, column x at x + r
    c1 = np.zeros(Wp)
    c2 = np.zeros(Wp)
    d0, d1, d2 = c0[r : r + W], c1[r : r + W], c2[r : r + W]  # (indexed by x: loops that vectorise)
    h0 = np.empty(W)
    h1 = np.empty(W)
    h2 = np.empty(W)
    inv_w = np.empty(W)  # 1 / box width at each column
    for x in range(W):
        inv_w[x] = 1.0 / (min(W, x + r + 1) - max(0, x - r))
    for yy in range(max(0, y0 - r), min(H, y0 + r + 1)):
        srow = s[yy - ya]
        rrow = ref[yy]
        for x in range(W):
            v = np.float64(srow[x])
            d0[x] += v
            d1[x] += v * v
            d2[x] += v * rrow[x]
    for y in range(y0, y1):
        if y > y0:
            yi, yo = y + r, y - r - 1
            if yi < H and yo >= 0:  # one row enters, one leaves
                si, so = s[yi - ya], s[yo - ya]
                ri, ro = ref[yi], ref[yo]
                for x in range(W):
                    v = np.float64(si[x])
                    u = np.float64(so[x])
                    d0[x] += v - u
                    d1[x] += v * v - u * u
                    d2[x] += v * ri[x] - u * ro[x]
            elif yi < H:
                si, ri = s[yi - ya], ref[yi]
                for x in range(W):
                    v = np.float64(si[x])
                    d0[x] += v
                    d1[x] += v * v
                    d2[x] += v * ri[x]
            elif yo >= 0:
                so, ro = s[yo - ya], ref[yo]
                for x in range(W):
                    u = np.float64(so[x])
                    d0[x] -= u
                    d1[x] -= u * u
                    d2[x] -= u * ro[x]
        inv_rows = 1.0 / (min(H, y + r + 1) - max(0, y - r))
        mrow = mr[y]
        vrow = vr[y]
        vld = valid[y - y0]
        if r == 3:
            for x in range(W):
                a0 = c0[x] + c0[x + 1] + c0[x + 2] + c0[x + 3] + c0[x + 4] + c0[x + 5] + c0[x + 6]
                a1 = c1[x] + c1[x + 1] + c1[x + 2] + c1[x + 3] + c1[x + 4] + c1[x + 5] + c1[x + 6]
                a2 = c2[x] + c2[x + 1] + c2[x + 2] + c2[x + 3] + c2[x + 4] + c2[x + 5] + c2[x + 6]
                zrow[x] = _zncc_score(a0, a1, a2, inv_w[x] * inv_rows, mrow[x], vrow[x], vld[x])
        else:
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for x in range(2 * r):
                s0 += c0[x]
                s1 += c1[x]
                s2 += c2[x]
            for x in range(W):
                s0 += c0[x + 2 * r]
                s1 += c1[x + 2 * r]
                s2 += c2[x + 2 * r]
                h0[x] = s0
                h1[x] = s1
                h2[x] = s2
                s0 -= c0[x]
                s1 -= c1[x]
                s2 -= c2[x]
            for x in range(W):
                zrow[x] = _zncc_score(h0[x], h1[x], h2[x], inv_w[x] * inv_rows, mrow[x], vrow[x], vld[x])
        for j in range(tops.shape[0]):  # insert into each column's sorted list of the best scores
            tj = tops[j, y - y0]
            for x in range(W):
                hi = max(tj[x], zrow[x])
                zrow[x] = min(tj[x], zrow[x])
                tj[x] = hi


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model='numpy')
def _sweep_kernel(ref, mr, vr, srcs, sizes, a, b, base, offsets, r, top_k, strip, fit, sep):
    """Score the inverse-depth hypotheses ``base + offsets[k]`` (per-pixel base) for every pixel.

    Per hypothesis and source: warp, windowed ZNCC; per hypothesis: mean of the ``top_k`` best
    sources. Per pixel returns the winning hypothesis index (with a parabola offset in [-0.5, 0.5]
    when ``fit``; -1 where nothing scored), its score, and the best score of hypotheses more than
    ``sep`` indices away (-1 if none). Rows are processed in strips of ``strip`` rows in parallel
    (one parallel region for the whole sweep); the per-pixel steps run with columns innermost so
    that they vectorise.
    """
    H, W = ref.shape
    n = srcs.shape[0]
    P = offsets.shape[0]
    k_top = min(top_k, n)
    pos = np.empty((H, W), np.float32)
    best = np.empty((H, W), np.float32)
    second = np.empty((H, W), np.float32)
    n_strips = (H + strip - 1) // strip
    for si in prange(n_strips):
        y0 = si * strip
        y1 = min(H, y0 + strip)
        ya = max(0, y0 - r)
        yb = min(H, y1 + r)
        rows = y1 - y0
        s = np.empty((yb - ya, W), np.float32)
        valid = np.empty((rows, W), np.bool_)
        vol = np.empty((P, rows, W), np.float32)
        tops = np.empty((k_top, rows, W), np.float32)  # per pixel, the k_top best scores, descending
        zrow = np.empty(W, np.float32)
        kb = np.empty(W, np.int64)
        cb = np.empty(W, np.float32)
        c2 = np.empty(W, np.float32)
        for h in range(P):
            tops[:] = -2.0  # below any ZNCC; finite (fast-math ninf)
            for i in range(n):
                hs, ws = sizes[i, 0], sizes[i, 1]
                _warp_rows(srcs[i], hs, ws, a[i], b[i], base, offsets[h], ya, yb, s, valid, y0, y1)
                _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zrow, tops)
            for y in range(rows):
                vh = vol[h, y]
                vh[:] = 0.0
                for j in range(k_top):
                    tj = tops[j, y]
                    for x in range(W):
                        vh[x] += tj[x]
                for x in range(W):
                    vh[x] /= k_top
        for y in range(rows):
            # winner (first of equal scores), then the best more than sep planes away from it
            cb[:] = vol[0, y]
            kb[:] = 0
            for k in range(1, P):
                vk = vol[k, y]
                for x in range(W):
                    better = vk[x] > cb[x]
                    kb[x] = k if better else kb[x]
                    cb[x] = vk[x] if better else cb[x]
            c2[:] = -1.0
            for k in range(P):
                vk = vol[k, y]
                for x in range(W):
                    if abs(k - kb[x]) > sep and vk[x] > c2[x]:
                        c2[x] = vk[x]
            for x in range(W):
                k = kb[x]
                off = 0.0
                if fit and 0 < k < P - 1:
                    cm = vol[k - 1, y, x]
                    cp = vol[k + 1, y, x]
                    den = cm - 2.0 * cb[x] + cp
                    if den < -1e-9:
                        off = min(max(0.5 * (cm - cp) / den, -0.5), 0.5)
                pos[y0 + y, x] = k + off if cb[x] > -1.0 else -1.0
                best[y0 + y, x] = cb[x]
                second[y0 + y, x] = c2[x]
    return pos, best, second


def batched(kernel: Callable[..., Any]) -> Callable[..., Any]:
    """``kernel`` (a ``_sweep`` with one (H, W) base) taking ``mvs._sweep``'s ``base`` of shape
    (H, W), (1, H, W) or (P, H, W) (one base per hypothesis: one call each, as
    ``mvs._sweep_and_refine`` scored its propagation candidates before round 3; winner = first best,
    no parabola; second-best not computed: -1)."""

    def sweep(ref, mr, vr, srcs, sizes, a, b, base, offsets, r, top_k, strip, fit, sep):
        if base.ndim == 2 or base.shape[0] == 1:
            b2 = base if base.ndim == 2 else base[0]
            return kernel(ref, mr, vr, srcs, sizes, a, b, b2, offsets, r, top_k, strip, fit, sep)
        scores = [
            kernel(ref, mr, vr, srcs, sizes, a, b, base[h], offsets[h : h + 1], r, top_k, strip, False, sep)[
                1
            ]
            for h in range(offsets.shape[0])
        ]
        idx = np.zeros(ref.shape, np.float32)
        best = scores[0]
        for h in range(1, len(scores)):  # as mvs did: a where and a maximum per candidate
            idx = np.where(scores[h] > best, np.float32(h), idx)
            best = np.maximum(scores[h], best)
        pos = np.where(best > -1.0, idx, np.float32(-1.0))
        return pos, best, np.full_like(best, -1.0)  # second-best: unused by mvs for these calls

    return sweep


#: ``mvs._sweep`` on the kernels of cf48d5e.
_sweep = batched(_sweep_kernel)
