# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pruning median filters: exact against brute force, and what they keep and remove."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth.prune import median_filter_valid, prune_depth, weighted_median_filter_valid


def windows(shape: tuple[int, int], size: int):
    h, w = shape
    r = size // 2
    for y in range(h):
        for x in range(w):
            yield y, x, np.s_[max(0, y - r) : y + r + 1, max(0, x - r) : x + r + 1]


def brute_median(d: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros(d.shape, np.float32)
    for y, x, win in windows(d.shape, size):
        vals = np.sort(d[win][d[win] > 0])
        if vals.size:
            out[y, x] = vals[(vals.size - 1) // 2]  # lower median
    return out


def brute_weighted_median(d: np.ndarray, rgb: np.ndarray, size: int, sigma_c: float):
    """Lower weighted median with float64 exp weights; also whether it is ambiguous at 1e-5."""
    out = np.zeros(d.shape, np.float32)
    ambiguous = np.zeros(d.shape, bool)
    c = rgb.astype(np.float64) / 255
    for y, x, win in windows(d.shape, size):
        known = d[win] > 0
        vals = d[win][known]
        if not vals.size:
            continue
        w = np.exp(-((c[win][known] - c[y, x]) ** 2).sum(-1) / (2 * sigma_c**2))
        order = np.argsort(vals, kind='stable')
        cum = np.cumsum(w[order])
        k = np.searchsorted(2 * cum, cum[-1])  # first index with 2 cum >= W
        out[y, x] = vals[order][k]
        ambiguous[y, x] = np.any(np.abs(2 * cum - cum[-1]) < 1e-5 * cum[-1])
    return out, ambiguous


def random_view(seed: int, shape=(18, 23), unknown=0.35, far=0.15):
    rng = np.random.default_rng(seed)
    d = rng.uniform(5, 6, shape).astype(np.float32)
    d[rng.random(shape) < unknown] = 0
    d[rng.random(shape) < far] *= np.float32(1.3)  # depths beyond the 10% band
    rgb = (120 + rng.integers(-12, 13, (*shape, 3))).astype(np.uint8)  # weights spread over (0, 1]
    return d, rgb


@pytest.mark.parametrize('size', [1, 3, 5])
def test_median_filter_matches_brute_force(size):
    d, _ = random_view(1)
    d[10:, 15:] = 0  # a region with no known sample at all
    np.testing.assert_array_equal(median_filter_valid(d, size), brute_median(d, size))
    assert (median_filter_valid(d, size)[12:, 17:] == 0).all()


@pytest.mark.parametrize(('size', 'sigma_c'), [(7, 0.1), (31, 0.033), (5, 0.3)])
def test_weighted_median_matches_brute_force(size, sigma_c):
    d, rgb = random_view(2)
    ref, ambiguous = brute_weighted_median(d, rgb, size, sigma_c)
    out = weighted_median_filter_valid(d, rgb, size, sigma_c)
    assert ambiguous.mean() < 0.05
    np.testing.assert_array_equal(out[~ambiguous], ref[~ambiguous])


def test_unit_weights_give_the_lower_median():
    d, rgb = random_view(3)
    rgb[:] = 77
    np.testing.assert_array_equal(weighted_median_filter_valid(d, rgb, 5), median_filter_valid(d, 5))


def brute_prune(d, rgb, small, large, sigma_c, lo=0.9, hi=1.1):
    m = brute_median(d, small)
    v = np.where((d > 0) & (lo * m <= d) & (d <= hi * m), d, 0).astype(np.float32)
    wm, ambiguous = brute_weighted_median(v, rgb, large, sigma_c)
    keep = (v > 0) & (lo * wm <= v) & (v <= hi * wm)
    return np.where(keep, d, 0).astype(np.float32), ambiguous & (v > 0)


PRUNE_CASES = [(4, 5, 31, 0.033), (5, 3, 9, 0.1), (6, 5, 15, 1.0)]


@pytest.mark.parametrize(('seed', 'small', 'large', 'sigma_c'), PRUNE_CASES)
def test_prune_matches_brute_force(seed, small, large, sigma_c):
    d, rgb = random_view(seed, shape=(24, 30), far=0.35)
    ref, ambiguous = brute_prune(d, rgb, small, large, sigma_c)
    out = prune_depth(d, rgb, small=small, large=large, sigma_c=sigma_c)
    assert out.dtype == np.float32
    assert ambiguous.mean() < 0.05
    np.testing.assert_array_equal(out[~ambiguous], ref[~ambiguous])
    assert 0 < (out > 0).sum() < (d > 0).sum()  # the case prunes some, keeps some
    assert (out != prune_depth(d, rgb, small=small, large=1)).any()  # ... in the large pass too


def smooth_scene(shape=(60, 80)):
    """A slanted plane (3% depth change per 31 px) with mild noise, uniform noisy colour."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    d = (20.0 + 0.02 * xx + 0.01 * yy) * (1 + 0.005 * rng.standard_normal(shape))
    rgb = np.clip(120 + rng.normal(0, 2, (*shape, 3)), 0, 255).astype(np.uint8)
    return d.astype(np.float32), rgb


def test_correct_depths_are_kept():
    d, rgb = smooth_scene()
    d[np.random.default_rng(8).random(d.shape) < 0.3] = 0
    np.testing.assert_array_equal(prune_depth(d, rgb), d)


def test_outliers_are_removed():
    d, rgb = smooth_scene()
    truth = d.copy()
    rng = np.random.default_rng(9)
    spikes = rng.random(d.shape) < 0.02
    d[spikes] *= rng.choice(np.array([0.5, 2.0], np.float32), spikes.sum())  # isolated samples
    d[20:24, 30:34] *= np.float32(1.5)  # a 4x4 cluster: survives the 5x5 median, same colour
    out = prune_depth(d, rgb)
    assert (out[spikes] == 0).all()
    assert (out[20:24, 30:34] == 0).all()
    good = ~spikes
    good[20:24, 30:34] = False
    assert (out[good] == truth[good]).mean() > 0.99


def test_colour_weighting_keeps_a_distinct_object():
    d, rgb = smooth_scene()
    d[20:28, 30:38] = 8.0  # a nearer object of its own colour
    rgb[20:28, 30:38] = (200, 30, 30)
    obj = np.zeros(d.shape, bool)
    obj[20:28, 30:38] = True
    weighted = prune_depth(d, rgb, small=1)
    unweighted = prune_depth(d, rgb, small=1, sigma_c=100.0)
    np.testing.assert_array_equal(weighted, d)
    assert (unweighted[obj] == 0).all()


def test_unknown_samples_pass_through():
    d, rgb = smooth_scene((20, 25))
    d[3, 4], d[5, 6], d[7, 8], d[9, 10] = 0, np.nan, -1, np.inf
    out = prune_depth(d, rgb)
    assert out[3, 4] == 0
    assert np.isnan(out[5, 6])
    assert out[7, 8] == -1
    assert out[9, 10] == np.inf
    d2 = d.copy()
    d2[5, 6], d2[7, 8], d2[9, 10] = 0, 0, 0
    np.testing.assert_array_equal(np.nan_to_num(out, nan=0, posinf=0).clip(0), prune_depth(d2, rgb))


def test_errors():
    d = np.ones((6, 7), np.float32)
    rgb = np.zeros((6, 7, 3), np.uint8)
    with pytest.raises(ValueError, match='depth must be a float32 array, got float64'):
        prune_depth(d.astype(np.float64), rgb)
    with pytest.raises(ValueError, match=r'rgb has shape \(7, 6, 3\), expected \(6, 7, 3\)'):
        prune_depth(d, rgb.transpose(1, 0, 2))
    with pytest.raises(ValueError, match='rgb must be a uint8 array'):
        weighted_median_filter_valid(d, rgb.astype(np.float32))
    with pytest.raises(ValueError, match='small must be an odd positive int, got 4'):
        prune_depth(d, rgb, small=4)
    with pytest.raises(ValueError, match='size must be an odd positive int, got 0'):
        median_filter_valid(d, 0)
    with pytest.raises(ValueError, match='sigma_c must be positive'):
        prune_depth(d, rgb, sigma_c=0.0)
    with pytest.raises(ValueError, match='ratio must be'):
        prune_depth(d, rgb, ratio=(1.2, 1.1))


@pytest.mark.parametrize('r', [0, 1, 3, 15])
def test_window_min_max_matches_brute_force(r):
    from ibr_ros.core.depth.prune import _column_min_max, _row_min_max

    d, _ = random_view(10, shape=(13, 17))
    row_min, row_max = _row_min_max(d, r)
    win_min, win_max = _column_min_max(row_min, row_max, r)
    for y, x, win in windows(d.shape, 2 * r + 1):
        vals = d[win][d[win] > 0]
        assert win_min[y, x] == (vals.min() if vals.size else np.inf)
        assert win_max[y, x] == (vals.max() if vals.size else 0)
        row = d[y, max(0, x - r) : x + r + 1]
        assert row_min[y + r, x] == (row[row > 0].min() if (row > 0).any() else np.inf)
    assert (row_min[:r] == np.inf).all()
    assert (row_max[len(row_max) - r :] == 0).all()
