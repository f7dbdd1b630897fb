# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The sweep kernels of :mod:`ibr_ros.core.depth.mvs` before the first kernel speed-up (main at
606ef63): ``_warp_rows`` and ``_sweep`` verbatim, the round-1 baseline of ``bench_sweep_kernel.py
--round1`` (cumulative ratio); ``_zncc_rows`` had not changed since ``_mvs_baseline``'s (22d1ab2) and
is that one. :func:`_sweep` has the signature of ``mvs._sweep``. Not used by the package.
"""

from __future__ import annotations

import numpy as np
from _mvs_baseline import _zncc_rows  # unchanged from 22d1ab2 to 606ef63
from numba import njit, prange


@njit(cache=True, fastmath=True)
def _warp_rows(src, hs, ws, a, b, base, off, ya, yb, out, valid, y0, y1):
    """Rows ``ya:yb`` of one source warped into the reference at inverse depth ``base + off``.

    A reference pixel (u, v) maps to ``a @ (u, v, 1) + rho * b`` (homogeneous source pixel), with
    ``a = K_s R K_r^-1`` and ``b = K_s t``, in float32 (about 1e-4 px at 1000 px). Bilinear, border
    clamped; ``valid`` (rows ``y0:y1``) is False where the centre falls outside the source or behind
    it, or ``rho <= 0``. Per row, the positions come first (a loop that vectorises), then the taps.
    """
    W = out.shape[1]
    f32 = np.float32
    a00, a10, a20 = f32(a[0, 0]), f32(a[1, 0]), f32(a[2, 0])
    b0, b1, b2 = f32(b[0]), f32(b[1]), f32(b[2])
    lo, hx, hy = f32(-0.5), f32(ws - 0.5), f32(hs - 0.5)
    xmax, ymax = f32(ws - 1.001), f32(hs - 1.001)
    zero, tiny = f32(0.0), f32(1e-9)
    px = np.empty(W, np.float32)
    py = np.empty(W, np.float32)
    ok = np.empty(W, np.bool_)
    for y in range(ya, yb):
        c0 = f32(a[0, 1] * y + a[0, 2])
        c1 = f32(a[1, 1] * y + a[1, 2])
        c2 = f32(a[2, 1] * y + a[2, 2])
        for x in range(W):
            xf = f32(x)
            rho = base[y, x] + off
            h2 = a20 * xf + c2 + rho * b2
            inv = f32(1.0) / h2
            sx = (a00 * xf + c0 + rho * b0) * inv
            sy = (a10 * xf + c1 + rho * b1) * inv
            front = (h2 > tiny) & (rho > zero)
            ok[x] = front & (lo <= sx) & (sx <= hx) & (lo <= sy) & (sy <= hy)
            px[x] = min(max(sx, zero), xmax) if front else zero
            py[x] = min(max(sy, zero), ymax) if front else zero
        for x in range(W):
            x0 = int(px[x])
            yi = int(py[x])
            fx = px[x] - x0
            top = src[yi, x0] + fx * (src[yi, x0 + 1] - src[yi, x0])
            bot = src[yi + 1, x0] + fx * (src[yi + 1, x0 + 1] - src[yi + 1, x0])
            out[y - ya, x] = top + (py[x] - yi) * (bot - top)
        if y0 <= y < y1:
            valid[y - y0, :] = ok


@njit(cache=True, parallel=True)
def _sweep(ref, mr, vr, srcs, sizes, a, b, base, offsets, r, top_k, strip, fit, sep):
    """Score the inverse-depth hypotheses ``base + offsets[k]`` (per-pixel base) for every pixel.

    Per hypothesis and source: warp, windowed ZNCC; per hypothesis: mean of the ``top_k`` best
    sources. Per pixel returns the winning hypothesis index (with a parabola offset in [-0.5, 0.5]
    when ``fit``; -1 where nothing scored), its score, and the best score of hypotheses more than
    ``sep`` indices away (-1 if none). Rows are processed in strips of ``strip`` rows in parallel
    (one parallel region for the whole sweep).
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
        tops = np.empty(n, np.float32)
        for h in range(P):
            for i in range(n):
                hs, ws = sizes[i, 0], sizes[i, 1]
                _warp_rows(srcs[i], hs, ws, a[i], b[i], base, offsets[h], ya, yb, s, valid, y0, y1)
                _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zn[i])
            for y in range(rows):
                for x in range(W):
                    for i in range(n):  # insertion into descending order
                        z = zn[i, y, x]
                        j = i
                        while j > 0 and tops[j - 1] < z:
                            tops[j] = tops[j - 1]
                            j -= 1
                        tops[j] = z
                    acc = np.float32(0.0)
                    for i in range(k_top):
                        acc += tops[i]
                    vol[h, y, x] = acc / k_top
        for y in range(rows):
            for x in range(W):
                kb = 0
                cb = vol[0, y, x]
                for k in range(1, P):
                    if vol[k, y, x] > cb:
                        cb = vol[k, y, x]
                        kb = k
                c2 = np.float32(-1.0)
                for k in range(P):
                    if abs(k - kb) > sep and vol[k, y, x] > c2:
                        c2 = vol[k, y, x]
                off = 0.0
                if fit and 0 < kb < P - 1:
                    cm = vol[kb - 1, y, x]
                    cp = vol[kb + 1, y, x]
                    den = cm - 2.0 * cb + cp
                    if den < -1e-9:
                        off = min(max(0.5 * (cm - cp) / den, -0.5), 0.5)
                pos[y0 + y, x] = kb + off if cb > -1.0 else -1.0
                best[y0 + y, x] = cb
                second[y0 + y, x] = c2
    return pos, best, second
