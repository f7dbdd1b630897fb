# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Non-local MVS/monocular depth fusion on a minimum spanning tree (Liu et al. 2020, Eq. 5-13).

The colour image is a 4-connected graph whose edge weight is the largest absolute channel difference
of the two pixels, colours scaled to [0, 1] (so weights are multiples of 1/255).  On its minimum
spanning tree, ``Dis(p, q)`` is the sum of the edge weights on the tree path and the similarity is
``S(p, q) = exp(-Dis(p, q) / sigma)`` (Yang 2012, "A non-local cost aggregation method for stereo
matching").  With ``C(q) = 1`` on known MVS pixels and 0 elsewhere, the aggregated sums

    J^A(p) = sum_q S(p, q) C(q)                  (Eq. 11)
    D^A(p) = sum_q S(p, q) C(q) D_mvs(q)         (Eq. 12)

are computed for all pixels at once by Yang's two-pass tree filter (leaf-to-root, then
root-to-leaf), both channels in the same pass.  The fused depth (Eq. 5, 13) is ``D_mvs`` where it
is known and ``(alpha * D_mono + D^A) / (J^A + alpha)`` elsewhere.

Pixels are indexed row-major, ``p = y * W + x``.  Depth: float32 metres, 0 (or NaN) = unknown,
+inf = infinitely far.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ['build_mst', 'fuse_depth', 'fuse_with_support', 'mvs_support', 'tree_filter']

# Neighbour bits of a pixel in the tree: right, down, left, up.
_RIGHT, _DOWN, _LEFT, _UP = 1, 2, 4, 8


# --------------------------------------------------------------------------------------------- kernels


@njit(cache=True)
def _edge_weights(rgb):
    """Grid edge weights in 1/255 units: ``we[2p]`` to the right neighbour, ``we[2p+1]`` below.

    Also returns the histogram ``cnt[k + 1]`` of the weights of the existing edges (for the sort).
    """
    H, W = rgb.shape[0], rgb.shape[1]
    we = np.zeros(2 * H * W, np.uint8)
    cnt = np.zeros(257, np.int64)
    for y in range(H):
        for x in range(W):
            p = y * W + x
            if x + 1 < W:
                m = 0
                for c in range(3):
                    m = max(m, abs(np.int32(rgb[y, x, c]) - np.int32(rgb[y, x + 1, c])))
                we[2 * p] = m
                cnt[m + 1] += 1
            if y + 1 < H:
                m = 0
                for c in range(3):
                    m = max(m, abs(np.int32(rgb[y, x, c]) - np.int32(rgb[y + 1, x, c])))
                we[2 * p + 1] = m
                cnt[m + 1] += 1
    return we, cnt


@njit(cache=True)
def _kruskal(we, cnt, H, W):
    """Kruskal's MST of the grid: returns the tree's neighbour bits per pixel (uint8[N]).

    Edges are ordered by an exact 256-bucket counting sort of their integer weights; ties keep edge
    id order (``2p`` right, ``2p+1`` down, row-major).  Union-find: union by size, path halving.
    """
    N = H * W
    start = np.empty(257, np.int64)
    start[0] = 0
    for k in range(256):
        start[k + 1] = start[k] + cnt[k + 1]
    edges = np.empty(start[256], np.int32)
    for y in range(H):
        for x in range(W):
            p = y * W + x
            if x + 1 < W:
                k = we[2 * p]
                edges[start[k]] = 2 * p
                start[k] += 1
            if y + 1 < H:
                k = we[2 * p + 1]
                edges[start[k]] = 2 * p + 1
                start[k] += 1
    par = np.arange(N).astype(np.int32)
    size = np.ones(N, np.int32)
    nbr = np.zeros(N, np.uint8)
    n = 0
    for i in range(edges.shape[0]):
        if n == N - 1:
            break
        e = edges[i]
        p = e >> 1
        q = p + W if e & 1 else p + 1
        a = p
        while par[a] != a:
            par[a] = par[par[a]]
            a = par[a]
        b = q
        while par[b] != b:
            par[b] = par[par[b]]
            b = par[b]
        if a == b:
            continue
        if size[a] < size[b]:
            a, b = b, a
        par[b] = a
        size[a] += size[b]
        if e & 1:
            nbr[p] |= _DOWN
            nbr[q] |= _UP
        else:
            nbr[p] |= _RIGHT
            nbr[q] |= _LEFT
        n += 1
    return nbr


@njit(cache=True)
def _bfs(nbr, we, W):
    """Breadth-first order of the tree from pixel 0.

    Returns ``order`` (pixel at each position), ``ppos`` (position of the parent; 0 for the root)
    and ``wpar`` (weight of the edge to the parent in 1/255 units; 0 for the root).
    """
    N = nbr.shape[0]
    order = np.empty(N, np.int32)
    ppos = np.empty(N, np.int32)
    wpar = np.empty(N, np.uint8)
    back = np.empty(N, np.uint8)  # bit of the edge leading back to the parent, per position
    order[0] = 0
    ppos[0] = 0
    wpar[0] = 0
    back[0] = 0
    tail = 1
    for head in range(N):
        p = order[head]
        m = nbr[p] & ~back[head]
        if m & _RIGHT:
            order[tail] = p + 1
            ppos[tail] = head
            wpar[tail] = we[2 * p]
            back[tail] = _LEFT
            tail += 1
        if m & _DOWN:
            order[tail] = p + W
            ppos[tail] = head
            wpar[tail] = we[2 * p + 1]
            back[tail] = _UP
            tail += 1
        if m & _LEFT:
            order[tail] = p - 1
            ppos[tail] = head
            wpar[tail] = we[2 * (p - 1)]
            back[tail] = _RIGHT
            tail += 1
        if m & _UP:
            order[tail] = p - W
            ppos[tail] = head
            wpar[tail] = we[2 * (p - W) + 1]
            back[tail] = _DOWN
            tail += 1
    return order, ppos, wpar


@njit(cache=True)
def _aggregate(order, ppos, wpar, d_mvs, sim):
    """Two-pass tree filter of ``[C, C * D_mvs]`` in BFS position order: returns float64 (N, 2).

    ``sim[k] = exp(-(k / 255) / sigma)`` is the similarity across one edge of weight ``k``.
    """
    N = order.shape[0]
    agg = np.empty((N, 2), np.float64)
    for i in range(N):
        v = d_mvs[order[i]]
        known = v > 0 and v < np.inf
        agg[i, 0] = 1.0 if known else 0.0
        agg[i, 1] = v if known else 0.0
    for i in range(N - 1, 0, -1):  # leaf to root: up(parent) += S * up(child)
        j = ppos[i]
        s = sim[wpar[i]]
        agg[j, 0] += s * agg[i, 0]
        agg[j, 1] += s * agg[i, 1]
    for i in range(1, N):  # root to leaf: A(child) = S * A(parent) + (1 - S^2) * up(child)
        j = ppos[i]
        s = sim[wpar[i]]
        f = 1.0 - s * s
        agg[i, 0] = s * agg[j, 0] + f * agg[i, 0]
        agg[i, 1] = s * agg[j, 1] + f * agg[i, 1]
    return agg


@njit(cache=True)
def _combine(order, agg, d_mvs, d_mono, alpha):
    """Eq. 5 and 13 per pixel; falls back to ``d_mono`` where ``J^A + alpha == 0``."""
    N = order.shape[0]
    out = np.empty(N, np.float32)
    for i in range(N):
        p = order[i]
        v = d_mvs[p]
        if v > 0:  # known, or +inf: passed through
            out[p] = v
        else:
            den = agg[i, 0] + alpha
            out[p] = (alpha * d_mono[p] + agg[i, 1]) / den if den > 0 else d_mono[p]
    return out


@njit(cache=True)
def _unpermute(order, agg):
    N = order.shape[0]
    j_a = np.empty(N, np.float64)
    d_a = np.empty(N, np.float64)
    for i in range(N):
        j_a[order[i]] = agg[i, 0]
        d_a[order[i]] = agg[i, 1]
    return j_a, d_a


@njit(cache=True)
def _tree_filter(parent, order, edge_weight, data, sigma):
    N, K = data.shape
    agg = data.copy()
    for i in range(N - 1, 0, -1):
        p = order[i]
        s = math.exp(-edge_weight[p] / sigma)
        for k in range(K):
            agg[parent[p], k] += s * agg[p, k]
    for i in range(1, N):
        p = order[i]
        s = math.exp(-edge_weight[p] / sigma)
        f = 1.0 - s * s
        for k in range(K):
            agg[p, k] = s * agg[parent[p], k] + f * agg[p, k]
    return agg


# --------------------------------------------------------------------------------------------- checks


def _check_rgb(rgb: np.ndarray) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8:
        raise ValueError(f'rgb must be a uint8 array, got {getattr(rgb, "dtype", type(rgb).__name__)}')
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f'rgb must have shape (H, W, 3) with H, W > 0, got {rgb.shape}')


def _check_depth(name: str, d: np.ndarray, shape: tuple[int, ...]) -> None:
    if not isinstance(d, np.ndarray) or d.dtype != np.float32:
        raise ValueError(f'{name} must be a float32 array, got {getattr(d, "dtype", type(d).__name__)}')
    if d.shape != shape:
        raise ValueError(f'{name} has shape {d.shape}, expected {shape} (the rgb image size)')


def _check_sigma(sigma: float) -> float:
    s = float(sigma)
    if not (s > 0 and math.isfinite(s)):
        raise ValueError(f'sigma must be positive and finite, got {sigma}')
    return s


def _tree(rgb: np.ndarray):
    _check_rgb(rgb)
    H, W = rgb.shape[:2]
    we, cnt = _edge_weights(np.ascontiguousarray(rgb))
    nbr = _kruskal(we, cnt, H, W)
    return _bfs(nbr, we, W)


def _similarity(sigma: float) -> NDArray[np.float64]:
    return np.exp(-(np.arange(256) / 255.0) / sigma)


# --------------------------------------------------------------------------------------------- public


def build_mst(rgb: np.ndarray) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.float64]]:
    """Minimum spanning tree of the 4-connected pixel grid of ``rgb`` (uint8 H x W x 3).

    Edge weight: ``max_c |rgb[p, c] - rgb[q, c]| / 255``.  Ties are broken by edge order (right edge
    of ``p`` = ``2p``, lower edge = ``2p + 1``, pixels row-major), so the tree is deterministic.

    Returns ``(parent, order, edge_weight)``, each of length ``N = H * W`` indexed by pixel
    ``y * W + x``: ``parent[p]`` (-1 at the root, pixel 0); ``order``, the pixels in breadth-first
    order from the root (every parent precedes its children); ``edge_weight[p]``, the weight of the
    edge from ``p`` to its parent (0 at the root).
    """
    order, ppos, wpar = _tree(rgb)
    parent = np.empty_like(order)
    parent[order] = order[ppos]
    parent[order[0]] = -1
    edge_weight = np.empty(order.shape[0], np.float64)
    edge_weight[order] = wpar / 255.0
    return parent, order, edge_weight


def tree_filter(
    parent: np.ndarray, order: np.ndarray, edge_weight: np.ndarray, data: np.ndarray, sigma: float
) -> NDArray[np.float64]:
    """Yang's non-local aggregation ``A(p) = sum_q exp(-Dis(p, q) / sigma) data(q)`` on a tree.

    ``parent``, ``order``, ``edge_weight`` as returned by :func:`build_mst`; ``data`` (N,) or (N, K);
    the sum includes ``q = p``.  Returns float64 of the shape of ``data``.  O(N K).
    """
    s = _check_sigma(sigma)
    d = np.asarray(data, np.float64)
    flat = d.reshape(d.shape[0], -1)
    n = flat.shape[0]
    for name, a in (('parent', parent), ('order', order), ('edge_weight', edge_weight)):
        if np.shape(a) != (n,):
            raise ValueError(f'{name} must have shape ({n},) like data, got {np.shape(a)}')
    out = _tree_filter(
        np.asarray(parent, np.int64),
        np.asarray(order, np.int64),
        np.asarray(edge_weight, np.float64),
        np.ascontiguousarray(flat),
        s,
    )
    return out.reshape(d.shape)


def mvs_support(
    rgb: np.ndarray, d_mvs: np.ndarray, sigma: float = 0.06
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Aggregated MVS confidence and depth ``(J^A, D^A)`` of Eq. 11-12, float64 H x W each.

    Known MVS pixels (``Psi``) are those with a finite depth > 0; ``D^A / J^A`` is the MVS depth
    propagated along the tree and ``J^A`` (in ``[0, inf)``) how strongly MVS supports a pixel.
    """
    _check_rgb(rgb)
    H, W = rgb.shape[:2]
    _check_depth('d_mvs', d_mvs, (H, W))
    order, ppos, wpar = _tree(rgb)
    agg = _aggregate(
        order, ppos, wpar, np.ascontiguousarray(d_mvs).reshape(-1), _similarity(_check_sigma(sigma))
    )
    j_a, d_a = _unpermute(order, agg)
    return j_a.reshape(H, W), d_a.reshape(H, W)


def fuse_depth(
    rgb: np.ndarray, d_mvs: np.ndarray, d_mono: np.ndarray, sigma: float = 0.06, alpha: float = 1e-5
) -> NDArray[np.float32]:
    """Fused depth of Eq. 5 and 13 (float32 H x W, metres).

    ``rgb`` uint8 H x W x 3; ``d_mvs`` float32 pruned MVS depth (known where finite and > 0);
    ``d_mono`` float32 remapped monocular depth.  Known MVS pixels pass through unchanged, and so do
    +inf ones (which take no part in the aggregation); every other pixel ``p`` gets

        (alpha * d_mono[p] + D^A(p)) / (J^A(p) + alpha)

    so small holes take the surrounding MVS depth and pixels far (in tree distance) from any MVS
    sample take ``d_mono``.  ``alpha = 0`` is the pure-propagation ablation; pixels whose ``J^A``
    underflows to 0 there (no MVS depth within reach) fall back to ``d_mono``.
    """
    return fuse_with_support(rgb, d_mvs, d_mono, sigma, alpha)[0]


def fuse_with_support(
    rgb: np.ndarray, d_mvs: np.ndarray, d_mono: np.ndarray, sigma: float = 0.06, alpha: float = 1e-5
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """:func:`fuse_depth` and the MVS support ``J^A`` (Eq. 11) of each pixel, both float32 H x W,
    from one tree (the support feeds :func:`~ibr_ros.core.depth.confidence.depth_confidence`)."""
    _check_rgb(rgb)
    H, W = rgb.shape[:2]
    _check_depth('d_mvs', d_mvs, (H, W))
    _check_depth('d_mono', d_mono, (H, W))
    s = _check_sigma(sigma)
    a = float(alpha)
    if not (a >= 0 and math.isfinite(a)):
        raise ValueError(f'alpha must be finite and >= 0, got {alpha}')
    order, ppos, wpar = _tree(rgb)
    dm = np.ascontiguousarray(d_mvs).reshape(-1)
    agg = _aggregate(order, ppos, wpar, dm, _similarity(s))
    fused = _combine(order, agg, dm, np.ascontiguousarray(d_mono).reshape(-1), a).reshape(H, W)
    return fused, _unpermute(order, agg)[0].astype(np.float32).reshape(H, W)
