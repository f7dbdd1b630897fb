# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-pixel blending of the warped source views (numba kernels) and bilinear colour lookup."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ibr_ros.core.render.projection import refine_preimage

__all__ = ['BLEND_MODES', 'bilinear', 'blend_views', 'put_rgb']

_SOFT_CUTOFF = 3.0  # blend='soft' leaves out views whose weight exp(-d^2) is below exp(-9) = 1.2e-4
_STABLE_CUTOFF = 7.0  # blend='stable' leaves out views whose weight exp(-d) is below exp(-7) = 9e-4

#: ``mode`` of :func:`blend_views`'s ``weights`` per ``RenderConfig.blend``.
BLEND_MODES = {'paper': 0, 'soft': 1, 'ulr': 2, 'stable': 3}


@njit(cache=True)
def bilinear(img, u, v):
    """``img(u, v)`` (bilinear, clamped) as three float32."""
    h, w = img.shape[0], img.shape[1]
    uc = min(max(u, 0.0), w - 1.0)
    vc = min(max(v, 0.0), h - 1.0)
    u0 = int(uc)
    v0 = int(vc)
    u1 = min(u0 + 1, w - 1)
    v1 = min(v0 + 1, h - 1)
    fu = np.float32(uc - u0)
    fv = np.float32(vc - v0)
    w00 = (np.float32(1.0) - fu) * (np.float32(1.0) - fv)
    w01 = fu * (np.float32(1.0) - fv)
    w10 = (np.float32(1.0) - fu) * fv
    w11 = fu * fv
    r = w00 * img[v0, u0, 0] + w01 * img[v0, u1, 0] + w10 * img[v1, u0, 0] + w11 * img[v1, u1, 0]
    g = w00 * img[v0, u0, 1] + w01 * img[v0, u1, 1] + w10 * img[v1, u0, 1] + w11 * img[v1, u1, 1]
    b = w00 * img[v0, u0, 2] + w01 * img[v0, u1, 2] + w10 * img[v1, u0, 2] + w11 * img[v1, u1, 2]
    return np.float32(r), np.float32(g), np.float32(b)


@njit(cache=True)
def put_rgb(out, y, x, r, g, b):
    """Round three float32 colours in 0..255 into ``out[y, x]``."""
    out[y, x, 0] = np.uint8(min(r + np.float32(0.5), np.float32(255.0)))
    out[y, x, 1] = np.uint8(min(g + np.float32(0.5), np.float32(255.0)))
    out[y, x, 2] = np.uint8(min(b + np.float32(0.5), np.float32(255.0)))


@njit(cache=True)
def _same_surface(za, zb, tol):
    """1 when depths ``za`` and ``zb`` are within a factor ``1 + tol`` (both ``+inf``: sky), else 0."""
    lo = min(za, zb)
    hi = max(za, zb)
    return 1 if hi <= lo * (1.0 + tol) or lo == np.inf else 0


@njit(cache=True)
def _stable_factors(pen, sigma):
    """``exp(-(pen - min(pen)) / sigma)`` per view and superpixel (float64; ``+inf`` penalty: 0)."""
    p_min = np.inf
    for j in range(pen.shape[0]):
        for k in range(pen.shape[1]):
            p_min = min(p_min, pen[j, k])
    ew = np.zeros(pen.shape, np.float64)
    if p_min == np.inf:
        return ew
    for j in range(pen.shape[0]):
        for k in range(pen.shape[1]):
            ew[j, k] = math.exp(-(np.float64(pen[j, k]) - p_min) / sigma)
    return ew


@njit(cache=True, parallel=True)
def blend_views(rgbs, depths, n, ids, inv, pen, zk, fit, rel, view_ids, gain, tol, weights, lookup, out):
    """Blend the ``n <= 4`` warped views per pixel (see :mod:`ibr_ros.core.render.renderer`).

    ``rgbs`` / ``depths``: tuples of 4 same-typed arrays (views ``n..3`` repeat one of them), the
    source images (uint8 ``(H, W, 3)``) and z-depths (m); ``ids[j]``: superpixel of view ``j`` drawn
    at each pixel (-1 none); ``inv[j, k]``: its inverse affine map (novel -> source pixel);
    ``pen[j, k]`` / ``zk[j, k]``: its penalty (degrees) and novel-view depth (m); ``fit[j, k]``: its
    affine fit (RMS px); ``rel[j]``: view ``j``'s
    :func:`~ibr_ros.core.render.projection.reprojection_params`; ``view_ids[j]``: its index in the
    renderer; ``gain[j]``: view ``j``'s weight factor in (0, 1] (``stable`` mode only).
    ``out = (rgb, valid, source, depth)`` receives :class:`Rendered`'s arrays.

    The best view (smallest penalty) supplies ``source`` / ``depth``; the colour is the weighted
    mean of the views covering the pixel, ``weights = (mode, sigma, min_rel)`` with ``mode`` from
    :data:`BLEND_MODES`: 0 (paper) the best view alone; 1 (soft) weights
    ``exp(-((p - p_min) / sigma)^2)`` (views with ``(p - p_min) / sigma > _SOFT_CUTOFF`` left out);
    2 (ulr) ULR's ``1 - p / p_max`` (``p_max`` the largest penalty among them; the best view always
    takes part, views below ``min_rel`` times its weight are left out); 3 (stable)
    ``gain[j] * exp(-(p - p_min) / sigma)``: normalised, the same as ``gain[j] * exp(-p / sigma)``,
    so a view's share depends on its own penalty and gain alone and changes continuously with them
    (views below ``exp(-_STABLE_CUTOFF)`` left out). ``tol >= 0``: when a strict majority of the
    views agree on a depth (within a factor ``1 + tol``) only they take part.
    ``lookup = (iters, max_shift, min_fit)``: for ``iters > 0`` the colour lookups of superpixels
    with ``fit[j, k] > min_fit`` are corrected by
    :func:`~ibr_ros.core.render.projection.refine_preimage`.
    """
    mode, sigma, min_rel = weights
    n_blend = 1 if mode == 0 else 4
    iters, max_shift, min_fit = lookup
    out_rgb, out_valid, out_src, out_depth = out
    h, w = out_valid.shape
    ew = _stable_factors(pen, sigma) if mode == 3 else np.zeros((1, 1))
    stable_floor = math.exp(-_STABLE_CUTOFF)
    for y in prange(h):
        sel = np.empty(4, np.int64)
        sel_p = np.empty(4, np.float32)
        sel_z = np.empty(4, np.float32)
        for x in range(w):
            cnt = 0  # candidate views sorted by penalty (stable: ties keep the nearer view first)
            zlo = np.inf
            zhi = -np.inf
            for j in range(n):
                k = ids[j, y, x]
                if k >= 0:
                    p = pen[j, k]
                    z = zk[j, k]
                    zlo = min(zlo, z)
                    zhi = max(zhi, z)
                    q = cnt
                    while q > 0 and sel_p[q - 1] > p:
                        sel_p[q] = sel_p[q - 1]
                        sel_z[q] = sel_z[q - 1]
                        sel[q] = sel[q - 1]
                        q -= 1
                    sel_p[q] = p
                    sel_z[q] = z
                    sel[q] = j
                    cnt += 1
            if tol >= 0 and cnt > 2 and not _same_surface(zlo, zhi, tol):  # vote on the surface
                zref = np.inf
                best_votes = 0
                for a in range(cnt):
                    votes = 0
                    for c in range(cnt):
                        votes += _same_surface(sel_z[a], sel_z[c], tol)
                    if votes > best_votes or (votes == best_votes and sel_z[a] < zref):
                        best_votes = votes
                        zref = sel_z[a]
                if 2 * best_votes > cnt:  # a strict majority: keep its views, in penalty order
                    kept = 0
                    for q in range(cnt):
                        if _same_surface(sel_z[q], zref, tol):
                            sel_p[kept] = sel_p[q]
                            sel[kept] = sel[q]
                            kept += 1
                    cnt = kept
            if cnt == 0:
                out_valid[y, x] = False
                out_src[y, x] = -1
                out_depth[y, x] = 0.0
                out_rgb[y, x, 0] = 0
                out_rgb[y, x, 1] = 0
                out_rgb[y, x, 2] = 0
                continue
            b = sel[0]
            out_valid[y, x] = True
            out_src[y, x] = view_ids[b]
            out_depth[y, x] = zk[b, ids[b, y, x]]
            ar = ag = ab = sw = np.float32(0.0)
            m = min(cnt, n_blend)
            p_max = sel_p[m - 1]
            w_best = np.float32(1.0)  # set at q == 0 (ulr)
            e_best = 1.0  # set at q == 0 (stable)
            for q in range(m):
                if mode == 3:
                    e = ew[sel[q], ids[sel[q], y, x]]
                    if q == 0:
                        e_best = e
                    if e_best > 1e-250:  # exp(-(p - p_best) / sigma) as a ratio of the precomputed factors
                        if e < e_best * stable_floor:
                            break
                        wt = np.float32(gain[sel[q]] * (e / e_best))
                    else:  # factors (nearly) underflowed: penalties many sigmas apart
                        d = (sel_p[q] - sel_p[0]) / sigma
                        if d > _STABLE_CUTOFF:
                            break
                        wt = np.float32(gain[sel[q]] * math.exp(-d))
                elif mode == 1:
                    d = (sel_p[q] - sel_p[0]) / sigma
                    if d > _SOFT_CUTOFF:
                        break
                    wt = np.float32(math.exp(-d * d))
                elif q == 0:
                    wt = np.float32(1.0 - sel_p[0] / p_max) if m > 1 and p_max > 0 else np.float32(1.0)
                    wt = max(wt, np.float32(1e-6))  # the best view always takes part
                    w_best = wt
                else:
                    wt = np.float32(1.0 - sel_p[q] / p_max)
                    if not wt > min_rel * w_best:
                        break
                j = sel[q]
                k = ids[j, y, x]
                u = inv[j, k, 0, 0] * x + inv[j, k, 0, 1] * y + inv[j, k, 0, 2]
                v = inv[j, k, 1, 0] * x + inv[j, k, 1, 1] * y + inv[j, k, 1, 2]
                if iters > 0 and fit[j, k] > min_fit:
                    u, v = refine_preimage(
                        depths[j], rel[j], x, y, u, v,
                        inv[j, k, 0, 0], inv[j, k, 0, 1], inv[j, k, 1, 0], inv[j, k, 1, 1], iters, max_shift,
                    )  # fmt: skip
                cr, cg, cb = bilinear(rgbs[j], u, v)
                ar += wt * cr
                ag += wt * cg
                ab += wt * cb
                sw += wt
            put_rgb(out_rgb, y, x, ar / sw, ag / sw, ab / sw)
