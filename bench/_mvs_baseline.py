# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The plane sweep of :mod:`ibr_ros.core.depth.mvs` before the issue-15 speed-up (main at 22d1ab2), kept
as the baseline of ``bench_mvs.py``: :func:`mvs_depth` is :func:`ibr_ros.core.depth.mvs.mvs_depth` with
this module's ``_sweep_and_refine`` (half-resolution sweep over all planes, 19 full-resolution
hypotheses per pixel, float64 warps) in place of the current one. Not used by the package.
"""

from __future__ import annotations

import math
from dataclasses import replace
from unittest import mock

import cv2
import numba
import numpy as np
from numba import njit, prange
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.depth import mvs
from ibr_ros.core.depth.mvs import REASON_NO_PARALLAX, MvsOptions, MvsResult, _relative
from ibr_ros.core.geometry.camera import PinholeCamera

_STRIP_ROWS = 32


#: The defaults of the options this sweep reads (the same as :class:`MvsOptions`' today).
OPTIONS = replace(MvsOptions(), refine_steps=3, surface_passes=1)


def mvs_depth(*args, **kwargs) -> MvsResult:
    """:func:`ibr_ros.core.depth.mvs.mvs_depth` with the baseline sweep (and, without ``options``,
    its defaults :data:`OPTIONS`)."""
    kwargs.setdefault('options', OPTIONS)
    with mock.patch.object(mvs, '_sweep_and_refine', _sweep_and_refine):
        return mvs.mvs_depth(*args, **kwargs)


@njit(cache=True, parallel=True)
def _box_stats(img, r):
    """Window mean and variance of ``img`` over (2r+1)^2 boxes truncated at the image border."""
    H, W = img.shape
    mean = np.empty((H, W), np.float64)
    var = np.empty((H, W), np.float64)
    for y in prange(H):
        ya, yb = max(0, y - r), min(H, y + r + 1)
        c1 = np.zeros(W)
        c2 = np.zeros(W)
        for yy in range(ya, yb):
            for x in range(W):
                v = np.float64(img[yy, x])
                c1[x] += v
                c2[x] += v * v
        s1 = 0.0
        s2 = 0.0
        for x in range(min(W, r)):
            s1 += c1[x]
            s2 += c2[x]
        for x in range(W):
            if x + r < W:
                s1 += c1[x + r]
                s2 += c2[x + r]
            if x - r - 1 >= 0:
                s1 -= c1[x - r - 1]
                s2 -= c2[x - r - 1]
            cnt = (yb - ya) * (min(W, x + r + 1) - max(0, x - r))
            m = s1 / cnt
            mean[y, x] = m
            var[y, x] = max(s2 / cnt - m * m, 0.0)
    return mean, var


@njit(cache=True, fastmath=True)
def _warp_rows(src, hs, ws, a, b, base, off, ya, yb, out, valid, y0, y1):
    """Rows ``ya:yb`` of one source warped into the reference at inverse depth ``base + off``.

    A reference pixel (u, v) maps to ``a @ (u, v, 1) + rho * b`` (homogeneous source pixel), with
    ``a = K_s R K_r^-1`` and ``b = K_s t``. Bilinear, border clamped; ``valid`` (rows ``y0:y1``) is
    False where the centre falls outside the source or behind it, or ``rho <= 0``.
    """
    W = out.shape[1]
    for y in range(ya, yb):
        for x in range(W):
            rho = base[y, x] + off
            h0 = a[0, 0] * x + a[0, 1] * y + a[0, 2] + rho * b[0]
            h1 = a[1, 0] * x + a[1, 1] * y + a[1, 2] + rho * b[1]
            h2 = a[2, 0] * x + a[2, 1] * y + a[2, 2] + rho * b[2]
            ok = h2 > 1e-9 and rho > 0.0
            sx = h0 / h2 if ok else 0.0
            sy = h1 / h2 if ok else 0.0
            ok = ok and -0.5 <= sx <= ws - 0.5 and -0.5 <= sy <= hs - 0.5
            sx = min(max(sx, 0.0), ws - 1.001)
            sy = min(max(sy, 0.0), hs - 1.001)
            x0 = int(sx)
            yi = int(sy)
            fx = sx - x0
            fy = sy - yi
            top = src[yi, x0] + fx * (src[yi, x0 + 1] - src[yi, x0])
            bot = src[yi + 1, x0] + fx * (src[yi + 1, x0 + 1] - src[yi + 1, x0])
            out[y - ya, x] = top + fy * (bot - top)
            if y0 <= y < y1:
                valid[y - y0, x] = ok


@njit(cache=True, fastmath=True)
def _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zn):
    """Windowed ZNCC of the warped rows ``s`` (from row ``ya``) against the reference, rows y0:y1.

    Running column and row sums (float64) over (2r+1)^2 boxes truncated at the image border, the
    same boxes as :func:`_box_stats`. Invalid centres score -1, flat source windows 0.
    """
    H, W = ref.shape
    c0 = np.zeros(W)
    c1 = np.zeros(W)
    c2 = np.zeros(W)
    for yy in range(max(0, y0 - r), min(H, y0 + r + 1)):
        for x in range(W):
            v = np.float64(s[yy - ya, x])
            c0[x] += v
            c1[x] += v * v
            c2[x] += v * ref[yy, x]
    for y in range(y0, y1):
        if y > y0:
            yy = y + r
            if yy < H:
                for x in range(W):
                    v = np.float64(s[yy - ya, x])
                    c0[x] += v
                    c1[x] += v * v
                    c2[x] += v * ref[yy, x]
            yy = y - r - 1
            if yy >= 0:
                for x in range(W):
                    v = np.float64(s[yy - ya, x])
                    c0[x] -= v
                    c1[x] -= v * v
                    c2[x] -= v * ref[yy, x]
        nrow = min(H, y + r + 1) - max(0, y - r)
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
            z = -1.0
            if valid[y - y0, x]:
                inv = 1.0 / (nrow * (min(W, x + r + 1) - max(0, x - r)))
                ms = s0 * inv
                den = vr[y, x] * (s1 * inv - ms * ms)
                z = (s2 * inv - mr[y, x] * ms) / math.sqrt(den) if den > 1e-6 else 0.0
            zn[y - y0, x] = z


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


class _Stack:
    """Grey reference and source images at one scale, with the maps of :func:`_warp_rows`."""

    def __init__(self, ref, ref_cam: PinholeCamera, t_wr, greys, cams, t_ws) -> None:
        self.ref = ref
        n = len(greys)
        self.srcs = np.zeros((n, max(g.shape[0] for g in greys), max(g.shape[1] for g in greys)), np.float32)
        self.sizes = np.zeros((n, 2), np.int64)
        self.a = np.empty((n, 3, 3))
        self.b = np.empty((n, 3))
        k_inv = np.linalg.inv(ref_cam.k)
        for i, (g, c, t) in enumerate(zip(greys, cams, t_ws)):
            self.srcs[i, : g.shape[0], : g.shape[1]] = g
            self.sizes[i] = g.shape
            r, tt = _relative(t_wr, t)
            self.a[i] = c.k @ r @ k_inv
            self.b[i] = c.k @ tt

    def disparity_span(self, rho: tuple[float, float]) -> float:
        """Largest distance (px) in any source between a pixel's matches at the two inverse depths."""
        H, W = self.ref.shape
        us, vs = np.meshgrid(np.linspace(0, W - 1, 7), np.linspace(0, H - 1, 7))
        p = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)])
        span = 0.0
        for a, b in zip(self.a, self.b):
            h = [a @ p + r * b[:, None] for r in rho]
            ok = (h[0][2] > 1e-9) & (h[1][2] > 1e-9)
            if ok.any():
                d = h[0][:2, ok] / h[0][2, ok] - h[1][:2, ok] / h[1][2, ok]
                span = max(span, float(np.linalg.norm(d, axis=0).max()))
        return span

    def sweep(self, stats, base: NDArray, offsets: ArrayLike, win: int, o: MvsOptions, fit: bool = True):
        """(position, best, second-best) of :func:`_sweep` for the hypotheses ``base + offsets[k]``.

        Strips are handed out one at a time (dynamic scheduling) so that a thread descheduled on a
        busy machine does not hold the others up.
        """
        base = np.ascontiguousarray(base, dtype=np.float32)
        offsets = np.asarray(offsets, dtype=np.float32).reshape(-1)
        with numba.parallel_chunksize(1):
            return _sweep(
                self.ref, stats[0], stats[1], self.srcs, self.sizes, self.a, self.b, base, offsets,
                win // 2, o.top_k, _STRIP_ROWS, fit, 2,
            )  # fmt: skip


def _scaled(cam: PinholeCamera, s: float) -> PinholeCamera:
    """The camera of the image resized to ``round(s * size)`` pixels (exact per-axis factors)."""
    w, h = max(2, round(cam.width * s)), max(2, round(cam.height * s))
    return cam.scaled(w / cam.width, h / cam.height)


def _sweep_and_refine(
    ref, ref_cam, t_wr, greys, cams, t_ws, near: float, far: float, o: MvsOptions, window=None
):
    """Steps 1-3 of the module docstring on checked grey images: (depth, score, n_planes) or a reason.

    ``window`` (the current sweep's depth window, added after this baseline): whole views only.
    """
    if window is not None:
        raise ValueError('the baseline sweep has no depth window (sweep_window): whole views only')
    H, W = ref.shape
    rho_near, rho_far = 1.0 / near, 1.0 / far
    s = o.sweep_scale
    if s < 1:
        cam_s = _scaled(ref_cam, s)
        cams_s = [_scaled(c, s) for c in cams]
        ref_s = cv2.resize(ref, (cam_s.width, cam_s.height), interpolation=cv2.INTER_AREA)
        greys_s = [
            cv2.resize(g, (c.width, c.height), interpolation=cv2.INTER_AREA) for g, c in zip(greys, cams_s)
        ]
        coarse = _Stack(ref_s, cam_s, t_wr, greys_s, cams_s, t_ws)
        fine = _Stack(ref, ref_cam, t_wr, greys, cams, t_ws)
    else:
        coarse = fine = _Stack(ref, ref_cam, t_wr, greys, cams, t_ws)
    span = coarse.disparity_span((rho_near, rho_far))
    if span < 1.0:
        return REASON_NO_PARALLAX
    n_planes = o.n_planes or int(min(max(math.ceil(span / o.plane_step_px) + 1, o.min_planes), o.max_planes))
    step = (rho_far - rho_near) / (n_planes - 1)

    # 1. sweep
    planes = rho_near + step * np.arange(n_planes)
    stats_s = _box_stats(coarse.ref, o.window // 2)
    pos, best, second = coarse.sweep(stats_s, np.zeros(coarse.ref.shape), planes, o.window, o)
    rho_s = np.where(pos >= 0, rho_near + pos * step, 0.0).astype(np.float32)
    bad_s = (pos < 0.5) | (pos > n_planes - 1.5) | (best - second < o.min_margin)

    # 2. refine at full resolution
    stats = _box_stats(ref, o.refine_window // 2)

    def up(a: NDArray) -> NDArray:
        return cv2.resize(a, (W, H), interpolation=cv2.INTER_NEAREST) if s < 1 else a

    base = up(rho_s)
    _, score, _ = fine.sweep(stats, base, [0.0], o.refine_window, o, False)
    cands = (
        [np.roll(rho_s, (dy, dx), axis=(0, 1)) for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0))]
        if s < 1
        else []
    )
    if o.propagation_radius > 0:
        ker = np.ones((2 * o.propagation_radius + 1,) * 2, np.uint8)
        cands += [
            np.asarray(cv2.dilate(rho_s, ker), np.float32),
            np.asarray(cv2.erode(np.where(rho_s > 0, rho_s, np.float32(1e9)), ker), np.float32),
        ]
    for c in cands:
        c = up(c)
        _, sc, _ = fine.sweep(stats, c, [0.0], o.refine_window, o, False)
        better = sc > score
        base = np.where(better, c, base)
        score = np.where(better, sc, score)
    half = 0.5 * step
    pos, score, _ = fine.sweep(
        stats, base, np.arange(-o.refine_steps, o.refine_steps + 1) * half, o.refine_window, o
    )
    valid = pos >= 0
    rho = base + (pos - o.refine_steps) * np.float32(half)
    for _ in range(o.surface_passes):
        base = cv2.medianBlur(np.where(valid, rho, 0).astype(np.float32), 5)
        pos, score, _ = fine.sweep(stats, base, np.arange(-2, 3) * 0.25 * half, o.refine_window, o)
        valid &= pos >= 0
        rho = base + (pos - 2) * np.float32(0.25 * half)

    # 3. reject
    bad = up(bad_s.astype(np.uint8)).astype(bool) | ~valid | ~(rho > rho_far * 0.999)
    bad |= (score < o.min_zncc) | (stats[1] < o.min_std**2)
    if o.edge_trim_px > 0:
        ker = np.ones((2 * o.edge_trim_px + 1,) * 2, np.uint8)
        bad |= cv2.erode(np.where(bad, 1e9, rho).astype(np.float32), ker) * o.edge_trim_ratio < rho
    depth = np.where(bad, 0.0, 1.0 / np.where(bad, 1.0, rho)).astype(np.float32)
    return depth, np.where(bad, 0.0, score).astype(np.float32), n_planes
