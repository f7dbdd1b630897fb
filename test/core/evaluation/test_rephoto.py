# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Shiftable-L1 rephotography error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ibr_ros.core.evaluation.rephoto import RephotoScore, error_curve, score, shiftable_l1


def brute_force(gt: np.ndarray, synth: np.ndarray, patch: int, shift: int) -> np.ndarray:
    """The definition, literally: float64 patch means, minimum over shifts, NaN outside."""
    h, w = gt.shape[:2]
    r = patch // 2
    g = gt.astype(np.float64)
    s = synth.astype(np.float64)
    out = np.full((h, w), np.nan, np.float32)
    for y in range(h):
        for x in range(w):
            best = np.inf
            for dy in range(-shift, shift + 1):
                for dx in range(-shift, shift + 1):
                    y0, x0, y1, x1 = y - r + dy, x - r + dx, y + r + dy, x + r + dx
                    if min(y - r, x - r, y0, x0) < 0 or max(y + r, y1) >= h or max(x + r, x1) >= w:
                        best = np.nan
                        break
                    a = g[y - r : y + r + 1, x - r : x + r + 1]
                    best = min(best, float(np.abs(a - s[y0 : y1 + 1, x0 : x1 + 1]).mean()))
                if np.isnan(best):
                    break
            out[y, x] = best
    return out


def smooth_texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.uniform(0, 255, (h // 4 + 2, w // 4 + 2, 3)).astype(np.float32), (w, h))
    img += rng.normal(0, 8, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize(
    ('h', 'w', 'patch', 'shift'), [(13, 17, 3, 1), (16, 21, 5, 2), (15, 15, 7, 0), (24, 19, 7, 2)]
)
def test_matches_brute_force(h, w, patch, shift):
    rng = np.random.default_rng(h * w + patch)
    gt = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    noise = rng.integers(-40, 41, (h, w, 3))
    synth = np.clip(np.roll(gt, (1, -1), axis=(0, 1)).astype(int) + noise, 0, 255).astype(np.uint8)
    got = shiftable_l1(gt, synth, patch, shift)
    want = brute_force(gt, synth, patch, shift)
    assert got.dtype == np.float32
    assert got.shape == (h, w)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=0)


def test_identical_images_give_zero():
    img = smooth_texture(60, 80)
    e = shiftable_l1(img, img)
    valid = e[~np.isnan(e)]
    assert valid.size == (60 - 10) * (80 - 10)  # m = 7 // 2 + 2 = 5
    assert np.all(valid == 0)


def test_one_pixel_translation():
    gt = smooth_texture(64, 96, seed=2)
    synth = np.roll(gt, 1, axis=1)  # synth(x) = gt(x - 1): shift sx = +1 realigns it
    for shift in (1, 2):
        e = shiftable_l1(gt, synth, 7, shift)
        assert np.all(e[~np.isnan(e)] == 0), shift
    e0 = shiftable_l1(gt, synth, 7, 0)
    assert np.all(e0[~np.isnan(e0)] > 0)


@pytest.mark.parametrize(('patch', 'shift'), [(1, 0), (3, 0), (7, 2), (5, 3)])
def test_nan_border_exactly(patch, shift):
    h, w = 30, 41
    e = shiftable_l1(smooth_texture(h, w), smooth_texture(h, w, seed=9), patch, shift)
    m = patch // 2 + shift
    expect_valid = np.zeros((h, w), bool)
    expect_valid[m : h - m, m : w - m] = True
    assert np.array_equal(~np.isnan(e), expect_valid)


def test_image_smaller_than_window_is_all_nan():
    img = smooth_texture(8, 8)
    assert np.isnan(shiftable_l1(img, img, 7, 1)).all()
    with pytest.raises(ValueError, match='too small'):
        score(img, img, patch=7, shift=1)


def test_error_curve():
    errors = np.array([[np.nan, 3.0, 1.0], [2.0, np.nan, 4.0]], np.float32)
    percent, e = error_curve(errors)
    assert e.tolist() == [1.0, 2.0, 3.0, 4.0]
    assert percent.tolist() == [25.0, 50.0, 75.0, 100.0]
    p, e = error_curve(np.full((2, 2), np.nan))
    assert p.size == 0
    assert e.size == 0


def test_score_statistics():
    gt = smooth_texture(120, 160, seed=3)
    synth = gt.copy()
    synth[40:60, 50:90] = 0  # a black hole
    mask = np.ones(gt.shape[:2], bool)
    mask[40:60, 50:90] = False
    s = score(gt, synth, mask)
    assert isinstance(s, RephotoScore)
    e = shiftable_l1(gt, synth)
    valid = np.sort(e[~np.isnan(e)])
    assert s.n_pixels == valid.size == (120 - 10) * (160 - 10)
    assert s.auc == pytest.approx(valid.mean(dtype=np.float64))
    assert s.median == pytest.approx(float(np.median(valid)))
    assert s.tail == pytest.approx(valid[-int(np.ceil(0.01 * valid.size)) :].mean(dtype=np.float64))
    assert s.tail >= s.auc > 0
    assert s.completeness == pytest.approx(1 - 20 * 40 / (120 * 160))
    assert (s.patch, s.shift) == (7, 2)
    perfect = score(gt, gt)
    assert (perfect.auc, perfect.tail, perfect.median, perfect.completeness) == (0.0, 0.0, 0.0, 1.0)


def test_larger_shift_never_increases_the_error():
    gt = smooth_texture(50, 70, seed=4)
    synth = smooth_texture(50, 70, seed=5)
    e1 = shiftable_l1(gt, synth, 5, 1)
    e2 = shiftable_l1(gt, synth, 5, 2)
    inner = ~np.isnan(e2)
    assert np.all(e2[inner] <= e1[inner])


@pytest.mark.parametrize(
    ('gt', 'synth', 'kwargs', 'match'),
    [
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 21, 3), np.uint8), {}, 'shapes differ'),
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 20, 3), np.float32), {}, 'synth must be a uint8'),
        (np.zeros((20, 20), np.uint8), np.zeros((20, 20), np.uint8), {}, 'gt must be a uint8'),
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 20, 3), np.uint8), {'patch': 6}, 'patch=6'),
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 20, 3), np.uint8), {'patch': 0}, 'patch=0'),
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 20, 3), np.uint8), {'shift': -1}, 'shift=-1'),
        (np.zeros((20, 20, 3), np.uint8), np.zeros((20, 20, 3), np.uint8), {'shift': 1.5}, 'shift=1.5'),
    ],
)
def test_rejects_bad_input(gt, synth, kwargs, match):
    with pytest.raises(ValueError, match=match):
        shiftable_l1(gt, synth, **kwargs)
    with pytest.raises(ValueError, match=match):
        score(gt, synth, **kwargs)


def test_rejects_bad_mask():
    img = np.zeros((20, 20, 3), np.uint8)
    with pytest.raises(ValueError, match='valid_mask'):
        score(img, img, np.ones((20, 21), bool))
    with pytest.raises(ValueError, match='valid_mask'):
        score(img, img, np.ones((20, 20), np.uint8))
