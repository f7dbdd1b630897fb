# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MST non-local fusion (Eq. 5-13): the tree, the aggregation against brute force, the behaviour."""

from __future__ import annotations

import heapq

import numpy as np
import pytest

from ibr_ros.core.depth.fusion import build_mst, fuse_depth, mvs_support, tree_filter


def grid_edges(rgb: np.ndarray):
    h, w = rgb.shape[:2]
    c = rgb.astype(np.int32)
    for y in range(h):
        for x in range(w):
            p = y * w + x
            if x + 1 < w:
                yield p, p + 1, np.abs(c[y, x] - c[y, x + 1]).max() / 255
            if y + 1 < h:
                yield p, p + w, np.abs(c[y, x] - c[y + 1, x]).max() / 255


def prim_weight(rgb: np.ndarray) -> float:
    """Total weight of a minimum spanning tree (unique even when the tree is not)."""
    n = rgb.shape[0] * rgb.shape[1]
    adj: list[list[tuple[float, int]]] = [[] for _ in range(n)]
    for p, q, wt in grid_edges(rgb):
        adj[p].append((wt, q))
        adj[q].append((wt, p))
    seen, heap, total = set(), [(0.0, 0)], 0.0
    while heap:
        wt, p = heapq.heappop(heap)
        if p in seen:
            continue
        seen.add(p)
        total += wt
        for e in adj[p]:
            heapq.heappush(heap, e)
    return total


def tree_distances(parent: np.ndarray, edge_weight: np.ndarray) -> np.ndarray:
    """All-pairs path lengths on the tree, by a traversal from every node: O(N^2)."""
    n = parent.size
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for p in range(n):
        if parent[p] >= 0:
            adj[p].append((int(parent[p]), edge_weight[p]))
            adj[parent[p]].append((p, edge_weight[p]))
    dist = np.full((n, n), np.nan)
    for s in range(n):
        dist[s, s] = 0.0
        stack = [s]
        while stack:
            p = stack.pop()
            for q, wt in adj[p]:
                if np.isnan(dist[s, q]):
                    dist[s, q] = dist[s, p] + wt
                    stack.append(q)
    return dist


def view(seed: int, shape=(7, 9), levels: int | None = None):
    rng = np.random.default_rng(seed)
    hi = 256 if levels is None else levels
    rgb = (rng.integers(0, hi, (*shape, 3)) * (255 // (hi - 1))).astype(np.uint8)
    d_mvs = rng.uniform(2, 20, shape).astype(np.float32)
    d_mvs[rng.random(shape) < 0.5] = 0
    d_mono = rng.uniform(2, 20, shape).astype(np.float32)
    return rgb, d_mvs, d_mono


@pytest.mark.parametrize(('seed', 'levels'), [(0, None), (1, 3), (2, 2)])
def test_build_mst_is_a_minimum_spanning_tree(seed, levels):
    rgb, _, _ = view(seed, levels=levels)  # few colour levels: many ties
    h, w = rgb.shape[:2]
    parent, order, edge_weight = build_mst(rgb)
    n = h * w
    assert parent.shape == order.shape == edge_weight.shape == (n,)
    assert (order[0], parent[0], edge_weight[0]) == (0, -1, 0)
    assert sorted(order.tolist()) == list(range(n))
    pos = np.empty(n, int)
    pos[order] = np.arange(n)
    weights = {(min(p, q), max(p, q)): wt for p, q, wt in grid_edges(rgb)}
    for p in order[1:]:
        q = parent[p]
        assert pos[q] < pos[p]  # parents first: a breadth-first order from the root
        assert edge_weight[p] == weights[(min(p, q), max(p, q))]  # a grid edge, with its weight
    assert edge_weight.sum() == pytest.approx(prim_weight(rgb), abs=1e-12)


def test_build_mst_degenerate_shapes():
    for shape in [(1, 1), (1, 6), (5, 1)]:
        rgb = np.random.default_rng(0).integers(0, 256, (*shape, 3)).astype(np.uint8)
        parent, _, edge_weight = build_mst(rgb)
        assert (parent >= 0).sum() == rgb.shape[0] * rgb.shape[1] - 1
        assert edge_weight.sum() == pytest.approx(prim_weight(rgb))


@pytest.mark.parametrize(('seed', 'sigma'), [(3, 0.06), (4, 0.5), (5, 0.01)])
def test_tree_filter_matches_brute_force(seed, sigma):
    rgb, _, _ = view(seed)
    parent, order, edge_weight = build_mst(rgb)
    data = np.random.default_rng(seed).uniform(-1, 1, (parent.size, 2))
    s = np.exp(-tree_distances(parent, edge_weight) / sigma)
    np.testing.assert_allclose(tree_filter(parent, order, edge_weight, data, sigma), s @ data, rtol=1e-9)
    np.testing.assert_allclose(
        tree_filter(parent, order, edge_weight, data[:, 0], sigma), s @ data[:, 0], rtol=1e-9
    )


def brute_fusion(rgb, d_mvs, d_mono, sigma, alpha):
    parent, _, edge_weight = build_mst(rgb)
    s = np.exp(-tree_distances(parent, edge_weight) / sigma)
    known = (d_mvs > 0).ravel()
    j_a = s[:, known].sum(1)  # Eq. 11
    d_a = s[:, known] @ d_mvs.ravel()[known].astype(np.float64)  # Eq. 12
    with np.errstate(invalid='ignore', divide='ignore'):
        inp = (alpha * d_mono.ravel() + d_a) / (j_a + alpha)  # Eq. 13
    fused = np.where(known, d_mvs.ravel(), inp)  # Eq. 5
    return j_a.reshape(d_mvs.shape), d_a.reshape(d_mvs.shape), fused.reshape(d_mvs.shape)


@pytest.mark.parametrize(('seed', 'sigma', 'alpha'), [(6, 0.06, 1e-5), (7, 0.06, 0.0), (8, 0.3, 0.5)])
def test_fusion_matches_brute_force(seed, sigma, alpha):
    rgb, d_mvs, d_mono = view(seed)
    j_ref, d_ref, fused_ref = brute_fusion(rgb, d_mvs, d_mono, sigma, alpha)
    j_a, d_a = mvs_support(rgb, d_mvs, sigma)
    np.testing.assert_allclose(j_a, j_ref, rtol=1e-9)
    np.testing.assert_allclose(d_a, d_ref, rtol=1e-9)
    fused = fuse_depth(rgb, d_mvs, d_mono, sigma, alpha)
    assert fused.dtype == np.float32
    assert fused.shape == d_mvs.shape
    np.testing.assert_allclose(fused, fused_ref, rtol=1e-6)


def test_known_pixels_pass_through():
    rgb, d_mvs, d_mono = view(9, shape=(20, 30))
    d_mvs[0, :3] = [np.inf, np.nan, -2.0]
    fused = fuse_depth(rgb, d_mvs, d_mono)
    known = d_mvs > 0
    np.testing.assert_array_equal(fused[known], d_mvs[known])  # +inf included
    assert np.isfinite(fused[~known]).all()
    j_a, _ = mvs_support(rgb, d_mvs)
    j_finite, _ = mvs_support(rgb, np.where(np.isfinite(d_mvs), d_mvs, 0).astype(np.float32))
    np.testing.assert_array_equal(j_a, j_finite)  # +inf and NaN take no part in the aggregation


def stripes(width: int) -> np.ndarray:
    """1 x width alternating black and white: every edge has weight 1."""
    rgb = np.zeros((1, width, 3), np.uint8)
    rgb[0, 1::2] = 255
    return rgb


def test_alpha_zero_propagates_mvs_and_falls_back_where_support_underflows():
    rgb = stripes(60)
    d_mvs = np.zeros((1, 60), np.float32)
    d_mvs[0, 0] = 7.0
    d_mono = np.full((1, 60), 30.0, np.float32)
    j_a, _ = mvs_support(rgb, d_mvs)
    assert (j_a[0, :44] > 0).all()
    assert (j_a[0, 45:] == 0).all()  # exp(-45 / 0.06) underflows
    fused = fuse_depth(rgb, d_mvs, d_mono, alpha=0.0)
    reached = j_a[0] > 0
    np.testing.assert_allclose(fused[0, reached], 7.0, rtol=1e-4)  # (J^A is denormal near x = 44)
    assert (fused[0, ~reached] == 30.0).all()
    default = fuse_depth(rgb, d_mvs, d_mono)  # alpha = 1e-5 > exp(-1 / 0.06): mono wins at once
    assert (default[0, 1:] > 29.8).all()


def test_small_holes_follow_mvs_and_big_holes_follow_mono():
    rng = np.random.default_rng(10)
    h, w = 60, 80
    rgb = np.clip(128 + rng.normal(0, 2, (h, w, 3)), 0, 255).astype(np.uint8)
    # A structure of its own (textured) colour, entirely missing from MVS: a big hole.
    rgb[15:45, 40:70] = np.clip(40 + rng.normal(0, 6, (30, 30, 3)), 0, 255).astype(np.uint8)
    d_mvs = np.full((h, w), 10.0, np.float32)
    d_mvs[15:45, 40:70] = 0
    d_mvs[28:30, 10:12] = 0  # a small hole in the background
    d_mono = np.full((h, w), 10.0, np.float32)
    d_mono[15:45, 40:70] = 4.0  # mono sees the structure, nearer
    d_mono[28:30, 10:12] = 25.0  # and is wrong in the small hole
    fused = fuse_depth(rgb, d_mvs, d_mono)
    np.testing.assert_allclose(fused[28:30, 10:12], 10.0, rtol=1e-3)
    near_mono = np.abs(fused[15:45, 40:70] / 4.0 - 1) < 0.01
    assert near_mono.mean() > 0.75  # MVS depth leaks in only near where the tree enters the hole
    assert near_mono[:, 20:].all()


def test_errors():
    rgb, d_mvs, d_mono = view(11)
    with pytest.raises(ValueError, match='rgb must be a uint8 array, got float32'):
        fuse_depth(rgb.astype(np.float32), d_mvs, d_mono)
    with pytest.raises(ValueError, match=r'rgb must have shape \(H, W, 3\)'):
        build_mst(rgb[..., :2])
    with pytest.raises(ValueError, match='d_mono must be a float32 array, got float64'):
        fuse_depth(rgb, d_mvs, d_mono.astype(np.float64))
    with pytest.raises(ValueError, match=r'd_mvs has shape \(9, 7\), expected \(7, 9\)'):
        fuse_depth(rgb, d_mvs.T.copy(), d_mono)
    with pytest.raises(ValueError, match='sigma must be positive and finite, got 0'):
        fuse_depth(rgb, d_mvs, d_mono, sigma=0)
    with pytest.raises(ValueError, match='alpha must be finite and >= 0, got -1'):
        fuse_depth(rgb, d_mvs, d_mono, alpha=-1)
    with pytest.raises(ValueError, match=r'order must have shape \(63,\)'):
        tree_filter(np.zeros(63), np.zeros(62), np.zeros(63), np.zeros(63), 0.1)
