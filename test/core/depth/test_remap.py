# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Monocular depth remapping by the per-view lookup table (Eq. 1-4), its extrapolation beyond the
populated levels, and the two baselines."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibr_ros.core.depth.remap import (
    FAR_FACTOR,
    NEAR_FACTOR,
    build_lut,
    level_medians,
    linear_remap,
    lut_remap,
    median_factor_remap,
)


def pairs(samples: list[tuple[int, float]]) -> tuple[np.ndarray, np.ndarray]:
    """A 1 x n view from (G, d_mvs) pairs."""
    g = np.array([[s[0] for s in samples]], np.uint16)
    d = np.array([[s[1] for s in samples]], np.float32)
    return g, d


def paper_lut(med: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The paper's table (Eq. 3) from the level medians, held constant beyond the populated levels."""
    levels = np.arange(256)
    full = counts > 0
    d = np.interp(levels, levels[full], med[full])
    nxt = np.append(d[1:], d[-1])
    return ((nxt - d)[:, None] * (np.arange(256) / 256)[None, :] + d[:, None]).reshape(-1).astype(np.float32)


# Level 0: {10, 20, 40} -> 20 (invalid samples ignored); level 1 empty; level 2: {8, 12} -> 10
# (numpy's median of an even count: the mean of the middle two); levels 3-254 empty;
# level 255: {1, 2, 3, 4} -> 2.5.
HAND = [
    (1, 10.0),
    (100, 20.0),
    (255, 40.0),
    (7, 0.0),
    (8, np.nan),
    (9, np.inf),
    (10, -3.0),
    (512, 8.0),
    (767, 12.0),
    (65280, 1.0),
    (65535, 2.0),
    (65400, 3.0),
    (65300, 4.0),
]


def test_level_medians_by_hand():
    med, counts = level_medians(*pairs(HAND))
    assert counts[[0, 1, 2, 255]].tolist() == [3, 0, 2, 4]
    assert counts.sum() == 9
    assert med[[0, 2, 255]].tolist() == [20.0, 10.0, 2.5]
    assert np.isnan(med[1])
    assert np.isnan(med[3:255]).all()


def test_lut_by_hand():
    lut = build_lut(*pairs(HAND))
    assert lut.shape == (65536,)
    assert lut.dtype == np.float32
    d1 = 15.0  # empty level 1: halfway between levels 0 and 2
    assert lut[0] == 20.0
    assert lut[128] == pytest.approx(20.0 + (d1 - 20.0) * 0.5)
    assert lut[255] == pytest.approx(20.0 + (d1 - 20.0) * 255 / 256)
    assert lut[256] == d1
    assert lut[256 + 64] == pytest.approx(d1 + (10.0 - d1) * 0.25)
    assert lut[512] == 10.0
    d254 = 10.0 + (2.5 - 10.0) * 252 / 253  # empty levels 3-254: linear over the level index
    assert lut[254 * 256] == pytest.approx(d254)
    assert lut[254 * 256 + 128] == pytest.approx(d254 + (2.5 - d254) * 0.5)
    assert lut[255 * 256] == np.float32(2.5)
    # Beyond the anchor of the nearest level (no level 256): the inverse-depth trend, nearer.
    beyond = lut[255 * 256 :]
    assert (np.diff(beyond) <= 0).all()
    assert beyond[-1] < 2.5
    assert beyond[-1] >= NEAR_FACTOR * 1.0


def trend_samples(levels, a: float, b: float, per_level: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Samples at the centre of each level with depth exactly ``1 / (a * (i + 1/2) + b)``."""
    lv = np.repeat(np.asarray(levels), per_level)
    return pairs([(256 * i + 128, 1.0 / (a * (i + 0.5) + b)) for i in lv])


def test_extrapolation_follows_an_exact_inverse_depth_trend():
    # 1/d = a (x - 10) with x = G / 256: the horizon at level 10; MVS on levels 40..120 only.
    a = 1e-3
    g, d = trend_samples(range(40, 121), a, -10 * a)
    lut = build_lut(g, d).astype(np.float64)
    x = np.arange(65536) / 256
    d_max, d_min = float(d.max()), float(d.min())
    cap, floor = FAR_FACTOR * d_max, NEAR_FACTOR * d_min
    med, counts = level_medians(g, d)
    # Inside the populated levels: the paper's table, bit for bit.
    np.testing.assert_array_equal(
        lut[40 * 256 : 120 * 256 + 1], paper_lut(med, counts)[40 * 256 : 120 * 256 + 1]
    )
    # Beyond them: the trend itself (no half-level lag), within the caps.  Above the nearest
    # anchor the trend is behind d'_120 (placed at the level centre) for half a level: held there.
    with np.errstate(divide='ignore'):
        exact = 1.0 / (a * (x - 10))
    far = (x < 40) & (exact > 0) & (exact < cap)
    near = (x >= 120.5) & (exact > floor)
    assert far.sum() > 3000
    assert near.sum() > 20000
    np.testing.assert_allclose(lut[far], exact[far], rtol=1e-6)
    np.testing.assert_allclose(lut[near], exact[near], rtol=1e-6)
    assert np.all(lut[(x > 120) & (x < 120.5)] == np.float32(med[120]))
    # Past the caps, and beyond the horizon (1/d <= 0, levels 0..10): FAR_FACTOR x the largest MVS
    # depth; NEAR_FACTOR x the smallest on the near side.
    assert np.all(lut[(x < 40) & ~far] == np.float32(cap))
    assert np.all(lut[(x >= 120.5) & ~near] == np.float32(floor))
    assert lut[0] == np.float32(cap)


def test_far_ground_beyond_the_mvs_range():
    """A view whose MVS depth stops at 25 m: the farther half of the image follows G's trend."""
    g, _, z = inverse_depth_view(4000.0)
    d = np.where(z < 25, z, 0).astype(np.float32)
    med, counts = level_medians(g, d)
    beyond = g < 256 * np.flatnonzero(counts)[0]
    assert beyond.mean() > 0.4
    rel = np.abs(lut_remap(g, d) / z - 1)
    assert rel[beyond].max() < 0.002
    # The paper's table held constant there: the far ground squashed to the farthest MVS level.
    held = paper_lut(med, counts)[g]
    assert np.median(np.abs(held / z - 1)[beyond]) > 0.2


def test_robust_to_an_outlier_level():
    a, b = 2e-4, 1e-3
    g, d = trend_samples(range(60, 200, 2), a, b, per_level=20)
    g_bad, d_bad = trend_samples([100], a, b, per_level=20)
    g2 = np.concatenate([g, g_bad], axis=1)
    d2 = np.concatenate([d, d_bad * 3], axis=1)  # level 100 three times too far (MVS outliers)
    x = np.arange(30 * 256, 60 * 256) / 256  # farther, the cap (2x the outliers' depth) starts
    lut = build_lut(g2, d2)[30 * 256 : 60 * 256]
    np.testing.assert_allclose(lut, 1.0 / (a * x + b), rtol=0.01)


def test_single_level():
    g, d = pairs([(1000, 7.0), (1001, 9.0)])
    assert (build_lut(g, d) == 8.0).all()


def test_two_levels_give_their_line():
    g, d = pairs([(10 * 256 + 128, 1 / 0.02), (20 * 256 + 128, 1 / 0.04)])  # 1/d = 0.002 (x - 0.5)
    lut = build_lut(g, d)
    np.testing.assert_allclose(1 / lut[[5 * 256 + 128, 25 * 256 + 128]], [0.01, 0.05], rtol=1e-6)


def test_no_trend_holds_the_ends():
    # Depth growing with G (against the convention): no extrapolation, the paper's constant ends.
    g, d = pairs([(3 * 256 + 10, 5.0), (3 * 256 + 20, 5.0), (10 * 256, 30.0)])
    lut = build_lut(g, d)
    assert (lut[: 3 * 256 + 1] == 5.0).all()
    assert (lut[10 * 256 :] == 30.0).all()
    assert lut[3 * 256 + 128] == pytest.approx(5.0 + (5.0 + (30.0 - 5.0) / 7 - 5.0) * 0.5)


def test_g_zero_is_no_prediction():
    # MVS depth where G = 0 (e.g. above the ground plane's horizon) takes no part in level 0.
    g, d = pairs([(0, 900.0), (0, 950.0), (100, 40.0), (50 * 256, 20.0), (100 * 256, 10.0)])
    med, counts = level_medians(g, d)
    assert counts[0] == 1
    assert med[0] == 40.0
    # Only G = 0 samples: they are all there is, the table is constant.
    g0, d0 = pairs([(0, 4.0), (0, 6.0)])
    assert level_medians(g0, d0)[1][0] == 2
    assert (build_lut(g0, d0) == 5.0).all()


def test_lut_remap_is_table_lookup():
    rng = np.random.default_rng(3)
    g = rng.integers(0, 65536, (30, 40)).astype(np.uint16)
    d = rng.uniform(1, 100, (30, 40)).astype(np.float32)
    d[rng.random(d.shape) < 0.5] = 0
    out = lut_remap(g, d)
    assert out.dtype == np.float32
    assert out.shape == g.shape
    np.testing.assert_array_equal(out, build_lut(g, d)[g])


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.integers(0, 65535), min_size=1, max_size=200),
    st.lists(st.floats(0.5, 500.0, width=32), min_size=256, max_size=256),
    st.randoms(use_true_random=False),
)
def test_monotone_medians_give_monotone_output(gs, level_depths, rnd):
    # One depth per level, decreasing with the level (larger G = nearer): monotone medians.
    per_level = np.sort(np.array(level_depths, np.float32))[::-1]
    g = np.array(gs, np.uint16)
    d = per_level[g >> 8].copy()
    d[[rnd.random() < 0.3 for _ in gs]] = 0  # some unknown samples
    if not (d > 0).any():
        d[0] = per_level[g[0] >> 8]
    med, counts = level_medians(g[None], d[None])
    full = med[counts > 0]
    assert (np.diff(full) <= 0).all()
    lut = build_lut(g[None], d[None])
    assert (np.diff(lut) <= 0).all()
    valid = d[d > 0]
    assert lut.min() >= np.float32(NEAR_FACTOR * valid.min())
    assert lut.max() <= np.float32(FAR_FACTOR * valid.max())
    out = lut_remap(g[None], d[None])[0]
    assert (np.diff(out[np.argsort(g, kind='stable')]) <= 0).all()


def inverse_depth_view(offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GT depth 5..50 m, G an affine function of inverse depth, MVS = GT on half the pixels."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:300]
    z = 5.0 + 45.0 * (0.6 * xx / 299 + 0.4 * (yy / 199) ** 2)
    g = np.round(2.9e5 / z + offset).astype(np.uint16)
    d = np.where(rng.random(z.shape) < 0.5, z, 0).astype(np.float32)
    return g, d, z


@pytest.mark.parametrize('offset', [0.0, 4000.0])
def test_recovers_depth_from_affine_inverse_depth(offset):
    g, d, z = inverse_depth_view(offset)
    rel = np.abs(lut_remap(g, d) / z - 1)
    # Eq. 3 anchors the median of [256 i, 256 i + 256) at G = 256 i: the table lags by about half a
    # level (up to a whole one where a level is only partly covered), |dz / z| <~ 256 / (G - offset).
    assert rel.max() < 256 / (g.min() - offset)
    assert np.median(rel) < 0.015
    if offset:  # the baselines cannot absorb the offset
        for baseline in (median_factor_remap, linear_remap):
            assert np.median(np.abs(baseline(g, d) / z - 1)) > 2 * np.median(rel)


def test_median_factor_exact_for_proportional_inverse_depth():
    g, d, z = inverse_depth_view(0.0)
    out = median_factor_remap(g, d)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, z, rtol=2e-4)  # only G's rounding to integers


def test_median_factor_treats_zero_as_one():
    g, d = pairs([(0, 4.0), (1, 4.0), (2, 2.0)])
    out = median_factor_remap(g, d)[0]
    assert out[0] == out[1]
    assert out[2] == pytest.approx(out[1] / 2)


def test_linear_remap_exact_for_affine_depth():
    rng = np.random.default_rng(1)
    g = rng.integers(0, 65536, (20, 30)).astype(np.uint16)
    d = (3.0 + 0.001 * g).astype(np.float32)
    d[rng.random(d.shape) < 0.3] = np.nan
    np.testing.assert_allclose(linear_remap(g, d), 3.0 + 0.001 * g, rtol=1e-5)


def test_linear_remap_constant_g():
    g, d = pairs([(500, 2.0), (500, 4.0)])
    assert (linear_remap(g, d) == 3.0).all()


@pytest.mark.parametrize('fn', [lut_remap, build_lut, level_medians, median_factor_remap, linear_remap])
def test_errors(fn):
    g = np.zeros((4, 5), np.uint16)
    d = np.ones((4, 5), np.float32)
    with pytest.raises(ValueError, match=r'g must be a uint16 array, got int32'):
        fn(g.astype(np.int32), d)
    with pytest.raises(ValueError, match=r'g must be 2-D'):
        fn(g[None], d[None])
    with pytest.raises(ValueError, match=r'd_mvs must be a float32 array, got float64'):
        fn(g, d.astype(np.float64))
    with pytest.raises(ValueError, match=r'd_mvs has shape \(5, 4\), expected \(4, 5\)'):
        fn(g, d.T.copy())
    with pytest.raises(ValueError, match=r'd_mvs has no valid depth .* 20 pixels'):
        fn(g, np.full_like(d, np.nan))
