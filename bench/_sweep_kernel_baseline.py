# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The sweep kernels of :mod:`ibr_ros.core.depth.mvs` before the second kernel speed-up (main at
169fdec, after round 1 of issue 15): ``_warp_rows``, ``_zncc_rows`` and ``_sweep`` verbatim, kept as
the baseline of ``bench_sweep_kernel.py``. :func:`_sweep` has the signature of ``mvs._sweep``, so
patching ``mvs._sweep`` with it runs the whole pipeline on the previous kernels. Not used by the
package. ``_sweep_kernel_baseline_606ef63.py``: the kernels before round 1.
"""

from __future__ import annotations

import math

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
            inv = f32(1.0) / h2
            sx = (a00 * xf + c0 + rho * b0) * inv
            sy = (a10 * xf + c1 + rho * b1) * inv
            front = (h2 > tiny) & (rho > zero)
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


@njit(cache=True, fastmath=_FASTMATH, error_model='numpy')
def _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zn):
    """Windowed ZNCC of the warped rows ``s`` (from row ``ya``) against the reference, rows y0:y1.

    Running column and row sums (float64) over (2r+1)^2 boxes truncated at the image border, the
    same boxes as :func:`_box_stats`. Invalid centres score -1, flat source windows 0. Per row, the
    row sums (a serial loop) go to buffers and the scores come from a loop that vectorises.
    """
    H, W = ref.shape
    c0 = np.zeros(W)
    c1 = np.zeros(W)
    c2 = np.zeros(W)
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
            c0[x] += v
            c1[x] += v * v
            c2[x] += v * rrow[x]
    for y in range(y0, y1):
        if y > y0:
            yy = y + r
            if yy < H:
                srow = s[yy - ya]
                rrow = ref[yy]
                for x in range(W):
                    v = np.float64(srow[x])
                    c0[x] += v
                    c1[x] += v * v
                    c2[x] += v * rrow[x]
            yy = y - r - 1
            if yy >= 0:
                srow = s[yy - ya]
                rrow = ref[yy]
                for x in range(W):
                    v = np.float64(srow[x])
                    c0[x] -= v
                    c1[x] -= v * v
                    c2[x] -= v * rrow[x]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for x in range(min(W, r)):
            s0 += c0[x]
            s1 += c1[x]
            s2 += c2[x]
        for x in range(W):
            if x + r < W:
                s0 += c0[x + r]
                s1 += c1[x + r]
                s2 += c2[x + r]
            if x - r - 1 >= 0:
                s0 -= c0[x - r - 1]
                s1 -= c1[x - r - 1]
                s2 -= c2[x - r - 1]
            h0[x] = s0
            h1[x] = s1
            h2[x] = s2
        inv_rows = 1.0 / (min(H, y + r + 1) - max(0, y - r))
        mrow = mr[y]
        vrow = vr[y]
        vld = valid[y - y0]
        zrow = zn[y - y0]
        for x in range(W):
            inv = inv_w[x] * inv_rows
            ms = h0[x] * inv
            den = vrow[x] * (h1[x] * inv - ms * ms)
            z = (h2[x] * inv - mrow[x] * ms) / math.sqrt(max(den, 1e-6))
            z = z if den > 1e-6 else 0.0
            zrow[x] = z if vld[x] else -1.0


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model='numpy')
def _sweep(ref, mr, vr, srcs, sizes, a, b, base, offsets, r, top_k, strip, fit, sep):
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
        zn = np.empty((n, rows, W), np.float32)
        vol = np.empty((P, rows, W), np.float32)
        tops = np.empty((k_top, W), np.float32)  # per column, the k_top best scores, descending
        zc = np.empty(W, np.float32)
        kb = np.empty(W, np.int64)
        cb = np.empty(W, np.float32)
        c2 = np.empty(W, np.float32)
        for h in range(P):
            for i in range(n):
                hs, ws = sizes[i, 0], sizes[i, 1]
                _warp_rows(srcs[i], hs, ws, a[i], b[i], base, offsets[h], ya, yb, s, valid, y0, y1)
                _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zn[i])
            for y in range(rows):
                tops[:] = -2.0  # below any ZNCC; finite (fast-math ninf)
                for i in range(n):  # insert source i's score into each column's sorted list
                    zc[:] = zn[i, y]
                    for j in range(k_top):
                        tj = tops[j]
                        for x in range(W):
                            hi = max(tj[x], zc[x])
                            zc[x] = min(tj[x], zc[x])
                            tj[x] = hi
                vh = vol[h, y]
                vh[:] = 0.0
                for j in range(k_top):
                    tj = tops[j]
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
