# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""SLIC superpixels and per-superpixel depth statistics."""

from __future__ import annotations

import cv2
import numba
import numpy as np
import pytest

from ibr_ros.core.render.superpixels import SuperpixelStats, slic, split_at_depth_edges, superpixel_stats


def natural_image(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Procedural 'photo': shaded background, filled shapes, stripes and fine noise texture."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[..., 0] = 90 + 60 * xx / w
    img[..., 1] = 140 - 50 * yy / h
    img[..., 2] = 110 + 30 * np.sin(xx / 37.0) * np.cos(yy / 23.0)
    for _ in range(40):
        colour = rng.uniform(0, 255, 3).tolist()
        cx, cy = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        size = int(rng.uniform(0.02, 0.12) * w)
        if rng.random() < 0.5:
            cv2.circle(img, (cx, cy), size, colour, -1)
        else:
            pts = rng.normal(0, size, (5, 2)) + np.array([cx, cy])
            cv2.fillPoly(img, [pts.astype(np.int32)], colour)
    stripes = (np.sin((xx + 0.5 * yy) / 3.0) > 0)[..., None] * np.float32(25.0)
    img[int(0.7 * h) :, : int(0.3 * w)] += stripes[int(0.7 * h) :, : int(0.3 * w)]
    img += rng.normal(0, 6, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def piecewise_image(h: int, w: int, n_regions: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Voronoi regions of well-separated colours, mild noise: the image and its region ids."""
    rng = np.random.default_rng(seed)
    seeds = rng.uniform((0, 0), (h, w), (n_regions, 2))
    yy, xx = np.mgrid[0:h, 0:w]
    d = (yy[..., None] - seeds[:, 0]) ** 2 + (xx[..., None] - seeds[:, 1]) ** 2
    region = np.argmin(d, axis=2)
    palette = np.array([(r, g, b) for r in (30, 130, 230) for g in (30, 130, 230) for b in (30, 130, 230)])
    colours = palette[rng.integers(0, len(palette), n_regions)]
    img = colours[region].astype(np.float32) + rng.normal(0, 3, (h, w, 3))
    return np.clip(img, 0, 255).astype(np.uint8), region


def edges(labels: np.ndarray) -> np.ndarray:
    """Pixels whose right or lower neighbour has another label."""
    e = np.zeros(labels.shape, bool)
    e[:, :-1] |= labels[:, :-1] != labels[:, 1:]
    e[:-1, :] |= labels[:-1, :] != labels[1:, :]
    return e


def assert_connected_contiguous(labels: np.ndarray) -> None:
    k = int(labels.max()) + 1
    assert np.array_equal(np.unique(labels), np.arange(k)), 'labels are not contiguous 0..K-1'
    for label in range(k):
        n, _ = cv2.connectedComponents((labels == label).astype(np.uint8), connectivity=4)
        assert n == 2, f'label {label} has {n - 1} 4-connected components'


@pytest.fixture(scope='module')
def big() -> tuple[np.ndarray, np.ndarray]:
    img = natural_image(540, 960)
    return img, slic(img)


def test_label_count_and_dtype_at_960x540(big):
    img, labels = big
    assert labels.shape == img.shape[:2]
    assert labels.dtype == np.int32
    k = int(labels.max()) + 1
    assert 1000 <= k <= 2000, k
    assert np.array_equal(np.unique(labels), np.arange(k))
    sizes = np.bincount(labels.ravel())
    step2 = 540 * 960 / 1500
    assert sizes.min() >= int(0.25 * step2)  # orphans were merged away
    assert np.median(sizes) == pytest.approx(step2, rel=0.5)


def test_label_count_follows_n_segments():
    img = natural_image(270, 480, seed=3)
    counts = [int(slic(img, n_segments=n).max()) + 1 for n in (200, 800)]
    assert 150 <= counts[0] <= 260, counts
    assert 600 <= counts[1] <= 1000, counts


@pytest.mark.parametrize('seed', [1, 2])
def test_every_label_is_one_4_connected_region(seed):
    img = natural_image(120, 160, seed=seed)
    img = np.clip(img.astype(int) + np.random.default_rng(seed).normal(0, 25, img.shape), 0, 255).astype(
        np.uint8
    )
    raw = slic(img, n_segments=150, enforce_connectivity=False)
    assert_connected_contiguous(slic(img, n_segments=150))
    # the noisy image does fragment without enforcement, so the enforcement was exercised
    n_components = sum(
        cv2.connectedComponents((raw == k).astype(np.uint8), connectivity=4)[0] - 1
        for k in range(raw.max() + 1)
    )
    assert n_components > raw.max() + 1


def test_connectivity_at_full_size(big):
    _, labels = big
    k = labels.max() + 1
    ys, xs = np.divmod(np.arange(labels.size), labels.shape[1])
    lo = np.full((k, 2), labels.size)
    hi = np.full((k, 2), -1)
    for axis, coord in enumerate((ys, xs)):
        np.minimum.at(lo[:, axis], labels.ravel(), coord)
        np.maximum.at(hi[:, axis], labels.ravel(), coord)
    for label in range(k):  # connected components of each label's bounding-box crop
        crop = labels[lo[label, 0] : hi[label, 0] + 1, lo[label, 1] : hi[label, 1] + 1] == label
        n, _ = cv2.connectedComponents(crop.astype(np.uint8), connectivity=4)
        assert n == 2, f'label {label} has {n - 1} components'


def test_boundary_recall_on_piecewise_constant_image():
    img, region = piecewise_image(240, 320, n_regions=40, seed=5)
    labels = slic(img, n_segments=300)
    truth = edges(region)
    near = cv2.dilate(edges(labels).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # within 2 px
    recall = (truth & near).sum() / truth.sum()
    assert recall >= 0.9, recall


def test_deterministic_and_thread_independent(big):
    img, labels = big
    assert np.array_equal(slic(img), labels)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert np.array_equal(slic(img), labels)
    finally:
        numba.set_num_threads(threads)


def test_options_run():
    img = natural_image(90, 130, seed=4)
    for kwargs in (
        {'seed_on_gradient': False},
        {'iterations': 1},
        {'compactness': 40.0},
        {'enforce_connectivity': False},
        {'n_segments': 1},
        {'n_segments': 10**6},
    ):
        labels = slic(img, **kwargs)
        k = int(labels.max()) + 1
        assert np.array_equal(np.unique(labels), np.arange(k)), kwargs
    assert slic(img, n_segments=1).max() == 0
    # higher compactness: smoother, shorter boundaries
    assert edges(slic(img, compactness=40.0)).sum() < edges(slic(img, compactness=2.0)).sum()


@pytest.mark.parametrize(
    ('args', 'kwargs', 'match'),
    [
        ((np.zeros((10, 10, 3), np.float32),), {}, 'uint8'),
        ((np.zeros((10, 10), np.uint8),), {}, 'uint8'),
        ((np.zeros((0, 10, 3), np.uint8),), {}, 'pixels high'),
        ((np.zeros((10, 10, 3), np.uint8),), {'n_segments': 0}, 'n_segments'),
        ((np.zeros((10, 10, 3), np.uint8),), {'compactness': 0.0}, 'compactness'),
        ((np.zeros((10, 10, 3), np.uint8),), {'iterations': 0}, 'iterations'),
    ],
)
def test_slic_rejects_bad_input(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        slic(*args, **kwargs)


# ------------------------------------------------------------------------------------------------ stats


@pytest.mark.parametrize('quantised', [False, True])
def test_stats_match_numpy(big, quantised):
    _, labels = big
    rng = np.random.default_rng(7)
    depth = rng.uniform(1, 50, labels.shape).astype(np.float32)
    if quantised:  # many ties
        depth = np.round(depth / 10).astype(np.float32) + 1
    depth[rng.random(labels.shape) < 0.3] = 0.0
    depth[rng.random(labels.shape) < 0.05] = np.nan
    depth[rng.random(labels.shape) < 0.02] = -1.0
    depth[:40] = np.inf  # a sky band
    st = superpixel_stats(labels, depth)
    k = labels.max() + 1
    assert isinstance(st, SuperpixelStats)
    assert st.n_labels == k
    assert st.shape == labels.shape
    assert np.array_equal(st.count, np.bincount(labels.ravel(), minlength=k))
    assert st.offsets[0] == 0
    assert st.offsets[-1] == labels.size
    flat_l = labels.ravel()
    flat_d = depth.ravel()
    ys, xs = np.divmod(np.arange(labels.size), labels.shape[1])
    for label in range(0, k, 5):
        idx = np.flatnonzero(flat_l == label)
        assert np.array_equal(st.pixels(label), idx)
        assert st.bbox[label].tolist() == [xs[idx].min(), ys[idx].min(), xs[idx].max(), ys[idx].max()]
        np.testing.assert_allclose(st.centroid[label], [xs[idx].mean(), ys[idx].mean()])
        d = flat_d[idx]
        known = d[d > 0]
        assert st.n_depth[label] == known.size
        if known.size:
            np.testing.assert_allclose(st.median_depth[label], np.median(known), rtol=1e-6)
        else:
            assert np.isnan(st.median_depth[label])
    # sky superpixels (entirely in the +inf band) have an infinite median and count as known
    sky = np.unique(labels[:30])
    only_sky = [s for s in sky if st.bbox[s, 3] < 40]
    assert only_sky
    assert np.all(np.isposinf(st.median_depth[only_sky]))
    assert np.all(st.has_depth[only_sky])


def test_has_depth_rule():
    labels = np.repeat(np.arange(5, dtype=np.int32), 400).reshape(20, 100)  # 5 labels x 400 px
    depth = np.zeros(labels.shape, np.float32)
    flat = depth.ravel()
    known = {0: 0, 1: 10, 2: 19, 3: 20, 4: 400}
    for label, n in known.items():
        flat[label * 400 : label * 400 + n] = 3.0 + label
    st = superpixel_stats(labels, depth)  # needs max(10, 5 % of 400 = 20) samples
    assert st.n_depth.tolist() == [0, 10, 19, 20, 400]
    assert st.has_depth.tolist() == [False, False, False, True, True]
    assert np.isnan(st.median_depth[0])
    assert st.median_depth[3] == 6.0
    relaxed = superpixel_stats(labels, depth, min_samples=10, min_fraction=0.0)
    assert relaxed.has_depth.tolist() == [False, True, True, True, True]


def test_stats_empty_labels_and_validation():
    labels = np.array([[0, 0, 2], [2, 2, 2]], np.int32)
    depth = np.full(labels.shape, 5.0, np.float32)
    st = superpixel_stats(labels, depth, n_labels=4, min_samples=1, min_fraction=0.0)
    assert st.count.tolist() == [2, 0, 4, 0]
    assert st.has_depth.tolist() == [True, False, True, False]
    assert st.bbox[1].tolist() == [-1, -1, -1, -1]
    assert np.isnan(st.centroid[1]).all()
    assert st.pixels(2).tolist() == [2, 3, 4, 5]
    with pytest.raises(ValueError, match='depth'):
        superpixel_stats(labels, depth[:1])
    with pytest.raises(ValueError, match='labels'):
        superpixel_stats(labels.astype(np.float32), depth)
    with pytest.raises(ValueError, match='labels must be >= 0'):
        superpixel_stats(labels - 1, depth)
    with pytest.raises(ValueError, match='n_labels'):
        superpixel_stats(labels, depth, n_labels=2)


# ------------------------------------------------------------------------------------ depth edges


def _components(labels: np.ndarray) -> int:
    return sum(
        cv2.connectedComponents((labels == k).astype(np.uint8), connectivity=4)[0] - 1
        for k in np.unique(labels)
    )


def test_split_at_depth_edges_cuts_along_depth_steps_only():
    rng = np.random.default_rng(0)
    h, w = 60, 80
    labels = (np.arange(h)[:, None] // 20 * 4 + np.arange(w)[None, :] // 20).astype(np.int32)  # 12 blocks
    depth = np.full((h, w), 50.0, np.float32) * rng.uniform(0.995, 1.005, (h, w)).astype(np.float32)
    depth[:, 30:] = 40.0  # a 22 % step through the blocks of column 1
    depth[:8, :] = np.inf  # sky over the top row of blocks
    depth[50:, 70:] = np.nan  # unknown: stays with the nearer part
    out = split_at_depth_edges(labels, depth)
    assert out.dtype == np.int32
    assert out.shape == labels.shape
    assert np.array_equal(np.unique(out), np.arange(out.max() + 1))
    assert _components(out) == out.max() + 1  # every label one 4-connected region
    # no label mixes the sides of the step, or sky with ground; noise (+-0.5 %) splits nothing
    for k in range(out.max() + 1):
        m = out == k
        assert len(np.unique(labels[m])) == 1
        finite = depth[m][np.isfinite(depth[m])]
        assert finite.size == 0 or finite.max() / finite.min() < 1.02
        assert np.isinf(depth[m]).all() or not np.isinf(depth[m]).any()
    # 12 blocks + 3 split by the step + 4 top-row blocks with sky = 19
    assert out.max() + 1 == 19
    assert np.array_equal(split_at_depth_edges(labels, np.full((h, w), 7.0, np.float32)), labels)


def test_split_at_depth_edges_merges_fragments_below_min_size():
    labels = np.zeros((20, 20), np.int32)
    depth = np.full((20, 20), 10.0, np.float32)
    depth[5, 5] = 20.0  # one far pixel: a 1-px fragment
    assert split_at_depth_edges(labels, depth, min_size=1).max() == 1
    assert split_at_depth_edges(labels, depth, min_size=2).max() == 0
    assert split_at_depth_edges(labels, depth, log_gap=1.0).max() == 0  # a step of log 2 < 1


@pytest.mark.parametrize(
    ('args', 'kwargs', 'match'),
    [
        ((np.zeros((4, 4), np.float32), np.ones((4, 4), np.float32)), {}, 'labels must be'),
        ((np.zeros((4, 4), np.int32), np.ones((4, 5), np.float32)), {}, 'depth must be'),
        ((np.zeros((4, 4), np.int32), np.ones((4, 4), np.float32)), {'log_gap': 0.0}, 'log_gap > 0'),
        ((np.full((4, 4), -1, np.int32), np.ones((4, 4), np.float32)), {}, 'labels must be in'),
    ],
)
def test_split_at_depth_edges_rejects_bad_input(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        split_at_depth_edges(*args, **kwargs)
