# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Shape-preserving superpixel warp (Liu et al. 2020, Sec. III-B, Eq. 15-18) in numba.

Every superpixel ``S_k`` of a source view gets one *circumscribed triangle* ``T = (v1, v2, v3)``
(pixels, OpenCV convention: x right, y down, pixel centres at integers). The triangle is the
smallest equilateral triangle with a horizontal base that encloses the superpixel's bounding box
grown by half a pixel plus ``margin`` pixels on every side: base (``v1`` left, ``v2`` right) on the
box's bottom edge, apex ``v3`` above, its two slanted sides through the box's top corners. All
pixels of ``S_k`` therefore have barycentric coordinates ``(alpha, beta, gamma) > 0`` (Eq. 15).

Warping to a novel camera ``N`` solves for the new vertices ``V = (v1~x, v1~y, v2~x, v2~y, v3~x, v3~y)``:

* Reprojection energy (Eq. 16): ``|alpha v1~ + beta v2~ + gamma v3~ - C_N(C_I^-1(x, D(x)))|^2`` for the
  pixels ``x`` of ``S_k`` with known depth. For speed a fixed subset of at most ``max_samples``
  pixels (evenly spaced in the superpixel's raster-ordered pixel list among those with depth) is
  used, each weighted ``n_eligible / n_used`` so the term still sums over all pixels with depth
  and keeps the paper's balance against the shape term.
* Shape energy (Eq. 17) in its self-consistent form: with ``e = v2 - v1``,
  ``a = (v3 - v1) . e / |e|^2`` and ``b = (v3 - v1) . R90 e / |e|^2`` the source triangle satisfies
  ``v3 = v1 + a e + b R90 e`` exactly, and ``E_s = |v3~ - v1~ - a (v2~ - v1~) - b R90 (v2~ - v1~)|^2``
  is zero exactly for similarity transforms of ``T``. ``R90 = [[0, -1], [1, 0]]`` (counter-clockwise
  in a y-up frame; the same matrix in ``a``, ``b`` and ``E_s``, so the handedness cancels). The
  printed Eq. 17 divides by ``|e|`` instead of ``|e|^2`` and mixes up the vertex roles, which is
  not invariant to scale; this is the form of Liu et al. 2009 (content-preserving warps) it cites.
* ``E(S_k) = shape_weight * E_s + sum_x E_p(x)`` (Eq. 18, the paper's ``shape_weight`` is 1) is a
  linear least-squares problem in 6 unknowns. Its 6x6 normal matrix depends only on the source
  view (barycentrics, sample weights, ``a``, ``b``), so :func:`prepare_warp` accumulates and
  inverts it once per view (Cholesky, numba); a query only projects the samples into the novel
  camera, accumulates the 6-vector right-hand side and multiplies (:func:`warp_superpixels`).
  :func:`solve_warp` is the same closed form for arbitrary targets, in one pass.

Sky superpixels (median depth ``+inf``) are warped by rotation only: their pixels are directions
(points at infinity), reprojected with the infinite homography ``K_N R K_I^-1``, whatever depth
the individual pixels have. In finite superpixels only pixels with finite depth are samples.
Superpixels without depth (``has_depth`` False), with fewer than 3 samples or a singular system
are not warpable (``WarpModel.usable`` False). A query drops a superpixel whose anchor (its
centroid at the median depth) or any sample lands at ``z <= near`` in the novel camera (for sky:
a direction not in front of the camera).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render.superpixels import SuperpixelStats

__all__ = [
    'WarpModel',
    'WarpResult',
    'barycentric',
    'circumscribed_triangles',
    'prepare_warp',
    'shape_coefficients',
    'shape_energy',
    'solve_warp',
    'warp_superpixels',
]

_SQRT3 = math.sqrt(3.0)


# ------------------------------------------------------------------------------------ triangles


def circumscribed_triangles(bbox: ArrayLike, margin: float = 1.0) -> NDArray[np.float64]:
    """Equilateral triangles ``(K, 3, 2)`` enclosing inclusive pixel boxes ``(K, 4)`` = (x0, y0, x1, y1).

    The box is grown by ``0.5 + margin`` px (pixel extent plus margin); ``v1``/``v2`` are the left/right
    base corners on its bottom edge (image y down), ``v3`` the apex above (see module docstring).
    """
    b = np.asarray(bbox, dtype=np.float64).reshape(-1, 4)
    g = 0.5 + float(margin)
    x0, y0, x1, y1 = b[:, 0] - g, b[:, 1] - g, b[:, 2] + g, b[:, 3] + g
    half = 0.5 * (x1 - x0) + (y1 - y0) / _SQRT3
    xc = 0.5 * (x0 + x1)
    tri = np.empty((b.shape[0], 3, 2))
    tri[:, 0, 0], tri[:, 0, 1] = xc - half, y1
    tri[:, 1, 0], tri[:, 1, 1] = xc + half, y1
    tri[:, 2, 0], tri[:, 2, 1] = xc, y1 - _SQRT3 * half
    return tri


def shape_coefficients(tri: ArrayLike) -> NDArray[np.float64]:
    """``(K, 2)`` coefficients ``(a, b)`` with ``v3 = v1 + a e + b R90 e``, ``e = v2 - v1`` (Eq. 17)."""
    t = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 2)
    e = t[:, 1] - t[:, 0]
    d = t[:, 2] - t[:, 0]
    n2 = np.einsum('ij,ij->i', e, e)
    r90e = np.stack([-e[:, 1], e[:, 0]], axis=1)
    return np.stack([np.einsum('ij,ij->i', d, e) / n2, np.einsum('ij,ij->i', d, r90e) / n2], axis=1)


def shape_energy(tri: ArrayLike, warped: ArrayLike) -> NDArray[np.float64]:
    """``E_s`` (px^2, Eq. 17) of warped triangles ``(K, 3, 2)`` against source triangles ``(K, 3, 2)``."""
    ab = shape_coefficients(tri)
    w = np.asarray(warped, dtype=np.float64).reshape(-1, 3, 2)
    e = w[:, 1] - w[:, 0]
    r90e = np.stack([-e[:, 1], e[:, 0]], axis=1)
    r = w[:, 2] - w[:, 0] - ab[:, :1] * e - ab[:, 1:] * r90e
    return np.einsum('ij,ij->i', r, r)


def barycentric(tri: ArrayLike, xy: ArrayLike) -> NDArray[np.float64]:
    """``(N, 3)`` barycentrics ``(alpha, beta, gamma)`` of points ``(N, 2)`` in one triangle ``(3, 2)``."""
    t = np.asarray(tri, dtype=np.float64).reshape(3, 2)
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    m = np.stack([t[1] - t[0], t[2] - t[0]], axis=1)
    bg = np.linalg.solve(m, (p - t[0]).T).T
    return np.column_stack([1.0 - bg.sum(axis=1), bg])


# ------------------------------------------------------------------------------- numba kernels


@njit(cache=True)
def _bary(tri, k, x, y):
    """Barycentric ``(alpha, beta, gamma)`` of ``(x, y)`` in triangle ``tri[k]``."""
    e1x = tri[k, 1, 0] - tri[k, 0, 0]
    e1y = tri[k, 1, 1] - tri[k, 0, 1]
    e2x = tri[k, 2, 0] - tri[k, 0, 0]
    e2y = tri[k, 2, 1] - tri[k, 0, 1]
    px = x - tri[k, 0, 0]
    py = y - tri[k, 0, 1]
    det = e1x * e2y - e1y * e2x
    b = (px * e2y - py * e2x) / det
    g = (e1x * py - e1y * px) / det
    return 1.0 - b - g, b, g


@njit(cache=True)
def _shape_rows(a, b, sx, sy):
    """Rows of the shape residual ``r = S V`` (Eq. 17), unknowns ``(v1x, v1y, v2x, v2y, v3x, v3y)``."""
    sx[0], sx[1], sx[2], sx[3], sx[4], sx[5] = a - 1.0, -b, -a, b, 1.0, 0.0
    sy[0], sy[1], sy[2], sy[3], sy[4], sy[5] = b, a - 1.0, -b, -a, 0.0, 1.0


@njit(cache=True)
def _shape_normal(a, b, w, n):
    """``n = w * S^T S`` for one triangle (6x6)."""
    sx = np.empty(6)
    sy = np.empty(6)
    _shape_rows(a, b, sx, sy)
    for i in range(6):
        for j in range(6):
            n[i, j] = w * (sx[i] * sx[j] + sy[i] * sy[j])


@njit(cache=True)
def _add_bary(n, w, al, be, ga):
    """Add ``w * rows^T rows`` of the reprojection residual at barycentrics ``(al, be, ga)``."""
    c0 = (al, be, ga)
    for i in range(3):
        for j in range(3):
            v = w * c0[i] * c0[j]
            n[2 * i, 2 * j] += v
            n[2 * i + 1, 2 * j + 1] += v


@njit(cache=True)
def _cholesky(n, lo):
    """Cholesky factor ``lo`` (lower) of the 6x6 SPD matrix ``n``; False when not positive definite."""
    scale = 0.0
    for i in range(6):
        scale = max(scale, n[i, i])
    for j in range(6):
        s = n[j, j]
        for p in range(j):
            s -= lo[j, p] * lo[j, p]
        if not s > 1e-12 * scale:
            return False
        lo[j, j] = math.sqrt(s)
        for i in range(j + 1, 6):
            s = n[i, j]
            for p in range(j):
                s -= lo[i, p] * lo[j, p]
            lo[i, j] = s / lo[j, j]
        for i in range(j):
            lo[i, j] = 0.0
    return True


@njit(cache=True)
def _chol_solve(lo, rhs, out):
    """Solve ``lo lo^T out = rhs``."""
    y = np.empty(6)
    for i in range(6):
        s = rhs[i]
        for p in range(i):
            s -= lo[i, p] * y[p]
        y[i] = s / lo[i, i]
    for i in range(5, -1, -1):
        s = y[i]
        for p in range(i + 1, 6):
            s -= lo[p, i] * out[p]
        out[i] = s / lo[i, i]


@njit(cache=True)
def _solve_kernel(tri, ab, offsets, bary, targets, weights, shape_weight, out, ok):
    """Accumulate the normal equations of every triangle and solve them (see :func:`solve_warp`)."""
    n = np.empty((6, 6))
    lo = np.empty((6, 6))
    rhs = np.empty(6)
    v = np.empty(6)
    for k in range(offsets.size - 1):
        _shape_normal(ab[k, 0], ab[k, 1], shape_weight, n)
        rhs[:] = 0.0
        for i in range(offsets[k], offsets[k + 1]):
            w = weights[i]
            _add_bary(n, w, bary[i, 0], bary[i, 1], bary[i, 2])
            for c in range(3):
                rhs[2 * c] += w * bary[i, c] * targets[i, 0]
                rhs[2 * c + 1] += w * bary[i, c] * targets[i, 1]
        ok[k] = _cholesky(n, lo)
        if not ok[k]:
            out[k, :, :] = np.nan
            continue
        _chol_solve(lo, rhs, v)
        for c in range(3):
            out[k, c, 0] = v[2 * c]
            out[k, c, 1] = v[2 * c + 1]


@njit(cache=True)
def _count_samples(offsets, indices, depth_flat, sky, usable, max_samples, n_take, n_elig):
    for k in range(offsets.size - 1):
        m = 0
        if usable[k]:
            if sky[k]:
                m = offsets[k + 1] - offsets[k]
            else:
                for t in range(offsets[k], offsets[k + 1]):
                    d = depth_flat[indices[t]]
                    if d > 0 and d < np.inf:
                        m += 1
        n_elig[k] = m
        n_take[k] = min(m, max_samples)


@njit(cache=True)
def _fill_samples(offsets, indices, depth_flat, width, sky, n_elig, s_off, s_xy, s_depth):
    """Take ``s_off[k + 1] - s_off[k]`` evenly spaced eligible pixels of every superpixel."""
    for k in range(offsets.size - 1):
        m = s_off[k + 1] - s_off[k]
        if m == 0:
            continue
        ne = n_elig[k]
        j = 0  # eligible pixels seen
        i = 0  # samples taken
        nxt = (2 * i + 1) * ne // (2 * m)
        for t in range(offsets[k], offsets[k + 1]):
            p = indices[t]
            d = depth_flat[p]
            if not sky[k] and not (d > 0 and d < np.inf):
                continue
            if j == nxt:
                s_xy[s_off[k] + i, 0] = p % width
                s_xy[s_off[k] + i, 1] = p // width
                s_depth[s_off[k] + i] = d if not sky[k] else np.inf
                i += 1
                if i == m:
                    break
                nxt = (2 * i + 1) * ne // (2 * m)
            j += 1


@njit(cache=True)
def _normal_inverses(tri, ab, s_off, s_xy, s_weight, shape_weight, usable, ninv, gram):
    """Invert every superpixel's 6x6 normal matrix (Cholesky); clears ``usable`` when singular.

    ``gram[k]``: the weighted sums of the samples' barycentric products ``(aa, ab, ag, bb, bg, gg)``.
    """
    n = np.empty((6, 6))
    lo = np.empty((6, 6))
    e = np.zeros(6)
    col = np.empty(6)
    for k in range(tri.shape[0]):
        gram[k, :] = 0.0
        if not usable[k] or s_off[k + 1] - s_off[k] < 3:
            usable[k] = False
            ninv[k, :, :] = 0.0
            continue
        _shape_normal(ab[k, 0], ab[k, 1], shape_weight, n)
        wk = s_weight[k]
        for i in range(s_off[k], s_off[k + 1]):
            al, be, ga = _bary(tri, k, np.float64(s_xy[i, 0]), np.float64(s_xy[i, 1]))
            _add_bary(n, wk, al, be, ga)
            gram[k, 0] += wk * al * al
            gram[k, 1] += wk * al * be
            gram[k, 2] += wk * al * ga
            gram[k, 3] += wk * be * be
            gram[k, 4] += wk * be * ga
            gram[k, 5] += wk * ga * ga
        if not _cholesky(n, lo):
            usable[k] = False
            ninv[k, :, :] = 0.0
            continue
        for c in range(6):
            e[:] = 0.0
            e[c] = 1.0
            _chol_solve(lo, e, col)
            ninv[k, :, c] = col


@njit(cache=True)
def _bary_matrices(tri, out):
    """``out[k]`` (2x3) maps ``(x, y, 1)`` to the barycentrics ``(beta, gamma)`` in triangle ``k``."""
    for k in range(tri.shape[0]):
        e1x = tri[k, 1, 0] - tri[k, 0, 0]
        e1y = tri[k, 1, 1] - tri[k, 0, 1]
        e2x = tri[k, 2, 0] - tri[k, 0, 0]
        e2y = tri[k, 2, 1] - tri[k, 0, 1]
        det = e1x * e2y - e1y * e2x
        out[k, 0, 0] = e2y / det
        out[k, 0, 1] = -e2x / det
        out[k, 0, 2] = -(e2y * tri[k, 0, 0] - e2x * tri[k, 0, 1]) / det
        out[k, 1, 0] = -e1y / det
        out[k, 1, 1] = e1x / det
        out[k, 1, 2] = -(e1x * tri[k, 0, 1] - e1y * tri[k, 0, 0]) / det


@njit(cache=True)
def _anchor_depth(r, t, a, sky, near):
    """Novel z, angle (degrees) between the source and novel rays at the anchor and the resolution term
    ``max(0, (|a - C_s| - |a - C_n|) / |a - C_s|)``; z NaN if not in front, angle and term 0 for sky."""
    px = r[0, 0] * a[0] + r[0, 1] * a[1] + r[0, 2] * a[2]
    py = r[1, 0] * a[0] + r[1, 1] * a[1] + r[1, 2] * a[2]
    pz = r[2, 0] * a[0] + r[2, 1] * a[1] + r[2, 2] * a[2]
    if sky:
        if not pz > 1e-6 * math.sqrt(px * px + py * py + pz * pz):
            return np.nan, 0.0, 0.0
        return np.inf, 0.0, 0.0
    px += t[0]
    py += t[1]
    pz += t[2]
    if not pz > near:
        return np.nan, 0.0, 0.0
    # rays to the point from the source centre (t in the novel frame) and from the novel centre (0)
    qx, qy, qz = px - t[0], py - t[1], pz - t[2]
    nq = math.sqrt(qx * qx + qy * qy + qz * qz)
    npn = math.sqrt(px * px + py * py + pz * pz)
    c = (qx * px + qy * py + qz * pz) / max(nq * npn, 1e-300)
    res = max(0.0, (nq - npn) / max(nq, 1e-300))
    return pz, math.degrees(math.acos(min(1.0, max(-1.0, c)))), res


@njit(cache=True, inline='always')
def project_pixel(r, t, ki, kn, u, v, d, near):
    """Novel-view ``(x, y, z)`` of source pixel ``(u, v)`` at depth ``d`` (``+inf``: direction, z = inf).

    ``(r, t)``: source-to-novel rotation and translation; ``ki`` / ``kn``: ``fx, fy, cx, cy`` of the
    source / novel camera. ``z`` is NaN when the point is not in front of the novel camera (at
    ``z <= near``; for a direction, not ahead of it).
    """
    dx = (u - ki[2]) * (1.0 / ki[0])  # reciprocals: hoisted out of the callers' loops once inlined
    dy = (v - ki[3]) * (1.0 / ki[1])
    xc = r[0, 0] * dx + r[0, 1] * dy + r[0, 2]
    yc = r[1, 0] * dx + r[1, 1] * dy + r[1, 2]
    zc = r[2, 0] * dx + r[2, 1] * dy + r[2, 2]
    if d == np.inf:
        if not zc > 1e-6 * math.sqrt(xc * xc + yc * yc + zc * zc):
            return 0.0, 0.0, np.nan
        zz = np.inf
    else:
        xc = xc * d + t[0]
        yc = yc * d + t[1]
        zc = zc * d + t[2]
        if not zc > near:
            return 0.0, 0.0, np.nan
        zz = zc
    return kn[0] * xc / zc + kn[2], kn[1] * yc / zc + kn[3], zz


@njit(cache=True, parallel=True)
def _warp_kernel(
    bm, ninv, gram, usable, sky, anchor, s_off, s_xy, s_depth, s_weight, ki, kn, r, t, near, verts, z, pen,
    res, fit, ok,
):  # fmt: skip
    """Per-query warp of all superpixels: reproject samples, accumulate the rhs, ``V = N^-1 rhs``;
    ``fit[k]``: the RMS distance (px) between the samples' reprojections and their warped positions,
    from the sums (``sum w |t|^2 - 2 V.rhs + V^T G V``, ``G`` the samples' Gram matrix)."""
    for k in prange(bm.shape[0]):
        ok[k] = False
        verts[k, :, :] = np.nan
        z[k] = np.nan
        pen[k] = np.inf
        res[k] = np.inf
        fit[k] = np.inf
        if not usable[k]:
            continue
        inf = sky[k]
        zk, ang, rk = _anchor_depth(r, t, anchor[k], inf, near)
        if zk != zk:
            continue
        r0 = r1 = r2 = r3 = r4 = r5 = tt = 0.0
        w = s_weight[k]
        good = True
        for i in range(s_off[k], s_off[k + 1]):
            u = np.float64(s_xy[i, 0])
            v = np.float64(s_xy[i, 1])
            tu, tv, zz = project_pixel(r, t, ki, kn, u, v, np.float64(s_depth[i]), near)  # sky: +inf
            if zz != zz:
                good = False
                break
            tt += tu * tu + tv * tv
            tu *= w
            tv *= w
            be = bm[k, 0, 0] * u + bm[k, 0, 1] * v + bm[k, 0, 2]
            ga = bm[k, 1, 0] * u + bm[k, 1, 1] * v + bm[k, 1, 2]
            al = 1.0 - be - ga
            r0 += al * tu
            r1 += al * tv
            r2 += be * tu
            r3 += be * tv
            r4 += ga * tu
            r5 += ga * tv
        if not good:
            continue
        for c in range(3):
            for e in range(2):
                q = 2 * c + e
                verts[k, c, e] = (
                    ninv[k, q, 0] * r0
                    + ninv[k, q, 1] * r1
                    + ninv[k, q, 2] * r2
                    + ninv[k, q, 3] * r3
                    + ninv[k, q, 4] * r4
                    + ninv[k, q, 5] * r5
                )
        sse = w * tt
        g = gram[k]
        for e in range(2):
            va, vb, vc = verts[k, 0, e], verts[k, 1, e], verts[k, 2, e]
            sse += g[0] * va * va + g[3] * vb * vb + g[5] * vc * vc
            sse += 2.0 * (g[1] * va * vb + g[2] * va * vc + g[4] * vb * vc)
        sse -= 2.0 * (
            verts[k, 0, 0] * r0 + verts[k, 0, 1] * r1 + verts[k, 1, 0] * r2
            + verts[k, 1, 1] * r3 + verts[k, 2, 0] * r4 + verts[k, 2, 1] * r5
        )  # fmt: skip
        fit[k] = math.sqrt(max(sse, 0.0) / (w * (s_off[k + 1] - s_off[k])))
        z[k] = zk
        pen[k] = ang
        res[k] = rk
        ok[k] = True


# ----------------------------------------------------------------------------------------- API


def solve_warp(
    tri: ArrayLike,
    offsets: ArrayLike,
    bary: ArrayLike,
    targets: ArrayLike,
    weights: ArrayLike | None = None,
    shape_weight: float = 1.0,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Closed-form minimiser of Eq. 18 for ``K`` triangles with arbitrary reprojection targets.

    Args:
        tri: ``(K, 3, 2)`` source triangles (pixels).
        offsets: ``(K + 1,)`` CSR offsets: samples ``offsets[k]:offsets[k + 1]`` belong to triangle ``k``.
        bary: ``(S, 3)`` barycentric coordinates of the samples in their source triangle.
        targets: ``(S, 2)`` reprojected sample positions in the novel view (pixels).
        weights: ``(S,)`` sample weights (default 1).
        shape_weight: weight of the shape term ``E_s``.

    Returns:
        ``(K, 3, 2)`` warped vertices (NaN where singular) and ``(K,)`` bool solved.
    """
    t = np.ascontiguousarray(tri, dtype=np.float64).reshape(-1, 3, 2)
    off = np.ascontiguousarray(offsets, dtype=np.int64)
    b = np.ascontiguousarray(bary, dtype=np.float64).reshape(-1, 3)
    x = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
    w = np.ones(b.shape[0]) if weights is None else np.ascontiguousarray(weights, dtype=np.float64)
    if (
        off.size != t.shape[0] + 1
        or off[-1] != b.shape[0]
        or x.shape[0] != b.shape[0]
        or w.size != b.shape[0]
    ):
        raise ValueError('inconsistent sizes of tri, offsets, bary, targets, weights')
    out = np.empty_like(t)
    ok = np.empty(t.shape[0], np.bool_)
    _solve_kernel(t, shape_coefficients(t), off, b, x, w, float(shape_weight), out, ok)
    return out, ok


@dataclass(frozen=True, eq=False)
class WarpModel:
    """Query-independent warp data of one source view (``K`` superpixels, ``S`` samples).

    Attributes:
        tri: ``(K, 3, 2)`` circumscribed source triangles.
        bary: ``(K, 2, 3)`` maps ``(x, y, 1)`` to the barycentrics ``(beta, gamma)`` in ``tri[k]``.
        usable: ``(K,)`` warpable (depth, >= 3 samples, non-singular system).
        sky: ``(K,)`` median depth ``+inf`` (rotation-only warp).
        anchor: ``(K, 3)`` source optical-frame point of the centroid at the median depth (z-depth,
            metres); for sky superpixels the centroid's direction with ``z = 1``.
        ninv: ``(K, 6, 6)`` inverse normal matrices of Eq. 18.
        gram: ``(K, 6)`` weighted sums of the samples' barycentric products (for ``fit_px``).
        sample_offsets: ``(K + 1,)`` CSR offsets into ``sample_xy`` / ``sample_depth``.
        sample_xy: ``(S, 2)`` uint16 pixel ``(x, y)`` of the reprojection samples.
        sample_depth: ``(S,)`` float32 their depth (``+inf`` for sky superpixels).
        sample_weight: ``(K,)`` weight of each sample of superpixel ``k``.
        shape_weight: the shape-term weight the inverses were built with.
    """

    tri: NDArray[np.float64]
    bary: NDArray[np.float64]
    usable: NDArray[np.bool_]
    sky: NDArray[np.bool_]
    anchor: NDArray[np.float64]
    ninv: NDArray[np.float64]
    gram: NDArray[np.float64]
    sample_offsets: NDArray[np.int64]
    sample_xy: NDArray[np.uint16]
    sample_depth: NDArray[np.float32]
    sample_weight: NDArray[np.float64]
    shape_weight: float

    @property
    def n_labels(self) -> int:
        return int(self.tri.shape[0])

    @property
    def nbytes(self) -> int:
        return sum(
            a.nbytes
            for a in (
                self.tri,
                self.bary,
                self.usable,
                self.sky,
                self.anchor,
                self.ninv,
                self.gram,
                self.sample_offsets,
                self.sample_xy,
                self.sample_depth,
                self.sample_weight,
            )
        )


def prepare_warp(
    stats: SuperpixelStats,
    depth: NDArray[np.floating],
    camera: PinholeCamera,
    *,
    max_samples: int = 64,
    shape_weight: float = 1.0,
    margin: float = 1.0,
) -> WarpModel:
    """Triangles, reprojection samples and inverted normal matrices of one source view.

    ``stats`` from :func:`~ibr_ros.core.render.superpixels.superpixel_stats` on ``depth`` (float z-depth,
    metres, ``+inf`` sky, ``<= 0``/NaN unknown); ``camera`` is the (undistorted) source camera.
    """
    h, w = stats.shape
    dep = np.ascontiguousarray(depth, dtype=np.float32)
    if dep.shape != (h, w) or (camera.height, camera.width) != (h, w):
        raise ValueError(
            f'depth {dep.shape} / camera {camera.width}x{camera.height} do not match labels {h}x{w}'
        )
    if int(max_samples) < 3 or not shape_weight >= 0:
        raise ValueError(f'need max_samples >= 3 and shape_weight >= 0, got {max_samples}, {shape_weight}')
    k = stats.n_labels
    med = stats.median_depth.astype(np.float64)
    sky = np.isinf(med)
    usable = stats.has_depth & (stats.count > 0) & ~np.isnan(med)
    tri = circumscribed_triangles(np.maximum(stats.bbox, 0), margin)
    flat = dep.ravel()
    n_take = np.empty(k, np.int64)
    n_elig = np.empty(k, np.int64)
    _count_samples(stats.offsets, stats.indices, flat, sky, usable, int(max_samples), n_take, n_elig)
    s_off = np.zeros(k + 1, np.int64)
    np.cumsum(n_take, out=s_off[1:])
    s_xy = np.empty((s_off[-1], 2), np.uint16)
    s_depth = np.empty(s_off[-1], np.float32)
    _fill_samples(stats.offsets, stats.indices, flat, w, sky, n_elig, s_off, s_xy, s_depth)
    s_weight = n_elig / np.maximum(n_take, 1)
    ninv = np.empty((k, 6, 6))
    gram = np.empty((k, 6))
    _normal_inverses(
        tri, shape_coefficients(tri), s_off, s_xy, s_weight, float(shape_weight), usable, ninv, gram
    )
    bm = np.empty((k, 2, 3))
    _bary_matrices(tri, bm)
    cen = np.nan_to_num(stats.centroid)
    rays = np.column_stack(
        [(cen[:, 0] - camera.cx) / camera.fx, (cen[:, 1] - camera.cy) / camera.fy, np.ones(k)]
    )
    anchor = rays * np.where(sky | ~usable, 1.0, np.nan_to_num(med))[:, None]
    return WarpModel(
        tri=tri,
        bary=bm,
        usable=usable,
        sky=sky,
        anchor=anchor,
        ninv=ninv,
        gram=gram,
        sample_offsets=s_off,
        sample_xy=s_xy,
        sample_depth=s_depth,
        sample_weight=s_weight,
        shape_weight=float(shape_weight),
    )


@dataclass(frozen=True, eq=False)
class WarpResult:
    """Per-superpixel warp into one novel camera.

    Attributes:
        vertices: ``(K, 3, 2)`` warped triangle vertices in novel-view pixels (NaN where not ok).
        depth: ``(K,)`` novel-view z of the superpixel's anchor (metres; ``+inf`` sky; NaN not ok).
        angle_deg: ``(K,)`` angle at the anchor between the source and novel rays (degrees; 0 sky).
        resolution: ``(K,)`` how much farther the source camera is from the anchor than the novel
            one, ``max(0, (|a - C_s| - |a - C_n|) / |a - C_s|)`` (ULR's resolution term; 0 sky).
        fit_px: ``(K,)`` how well the affine warp fits: the RMS distance (novel-view pixels) between
            the reprojection samples' exact reprojections and where the warp puts them (``inf``
            where not ok).
        ok: ``(K,)`` warped and in front of the camera.
    """

    vertices: NDArray[np.float64]
    depth: NDArray[np.float64]
    angle_deg: NDArray[np.float64]
    resolution: NDArray[np.float64]
    fit_px: NDArray[np.float64]
    ok: NDArray[np.bool_]


def _intrinsics(camera: PinholeCamera) -> NDArray[np.float64]:
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy])


def warp_superpixels(
    model: WarpModel,
    source_camera: PinholeCamera,
    t_ws: ArrayLike,
    novel_camera: PinholeCamera,
    t_wn: ArrayLike,
    near: float = 0.05,
) -> WarpResult:
    """Warp every superpixel of a source view (pose ``t_ws``) into a novel view (pose ``t_wn``).

    Poses are 4x4 camera-to-world; ``near`` (metres) is the depth-test plane of the novel camera;
    """
    t_ns = np.linalg.inv(np.asarray(t_wn, dtype=np.float64)) @ np.asarray(t_ws, dtype=np.float64)
    k = model.n_labels
    verts = np.empty((k, 3, 2))
    z = np.empty(k)
    pen = np.empty(k)
    res = np.empty(k)
    fit = np.empty(k)
    ok = np.empty(k, np.bool_)
    _warp_kernel(
        model.bary,
        model.ninv,
        model.gram,
        model.usable,
        model.sky,
        model.anchor,
        model.sample_offsets,
        model.sample_xy,
        model.sample_depth,
        model.sample_weight,
        _intrinsics(source_camera),
        _intrinsics(novel_camera),
        np.ascontiguousarray(t_ns[:3, :3]),
        np.ascontiguousarray(t_ns[:3, 3]),
        float(near),
        verts,
        z,
        pen,
        res,
        fit,
        ok,
    )
    return WarpResult(vertices=verts, depth=z, angle_deg=pen, resolution=res, fit_px=fit, ok=ok)
