# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Excess flicker metric on known sequences and the smooth novel path."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ibr_ros.core.evaluation.flicker import (
    block_excess,
    excess_flicker,
    smooth_path,
    summarise_flicker,
    worst_mean,
)
from ibr_ros.core.geometry.transforms import look_at, rotation_angle_deg


def _img(value: int, shape: tuple[int, int] = (32, 48)) -> np.ndarray:
    return np.full((*shape, 3), value, np.uint8)


def test_change_the_truth_also_has_is_not_flicker() -> None:
    rng = np.random.default_rng(0)
    seq = [rng.integers(0, 256, (32, 48, 3), dtype=np.uint8) for _ in range(5)]
    assert np.all(excess_flicker(seq, seq, block=1) == 0.0)
    assert np.all(excess_flicker(seq, seq) == 0.0)
    # a static render of a moving truth: less change than the truth, never negative
    assert np.all(excess_flicker([seq[0]] * 5, seq) == 0.0)


def test_a_pop_counts_its_full_size_once() -> None:
    """Truth constant; the render jumps by 10 levels in one frame: excess 10 there, 0 elsewhere."""
    truth = [_img(100)] * 4
    render = [_img(100), _img(100), _img(110), _img(110)]
    assert excess_flicker(render, truth, block=1).tolist() == [0.0, 10.0, 0.0]
    assert excess_flicker(render, truth, block=16).tolist() == [0.0, 10.0, 0.0]
    # on a quarter of the image (one 16 px block of the 2x3): a sixth per block, a quarter per pixel
    half = _img(100)
    half[:16, :16] = 110
    assert block_excess(_img(100), half, _img(100), _img(100), block=16) == pytest.approx(10 / 6)
    assert block_excess(_img(100), half, _img(100), _img(100), block=1) == pytest.approx(10 * 256 / (32 * 48))


def test_blocks_forgive_misregistration_pixels_do_not() -> None:
    """A render that is the truth shifted by one pixel changes about as much in each block."""
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (32, 52, 3), dtype=np.uint8)
    truth = [base[:, k : k + 48] for k in range(3)]
    render = [base[:, k + 1 : k + 49] for k in range(3)]
    per_pixel = excess_flicker(render, truth, block=1)
    per_block = excess_flicker(render, truth, block=16)
    assert per_pixel.min() > 10.0
    assert per_block.max() < 0.2 * per_pixel.min()


def test_invalid_pixels_and_blocks_are_left_out() -> None:
    render = [_img(0), _img(200)]
    truth = [_img(0), _img(0)]
    valid = np.zeros((32, 48), bool)
    assert math.isnan(block_excess(*render, *truth, valid, block=16))
    valid[:16, :16] = True
    assert block_excess(*render, *truth, valid, block=16) == pytest.approx(200.0)
    assert block_excess(*render, *truth, valid, block=1) == pytest.approx(200.0)


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match='r_cur'):
        block_excess(_img(0), _img(0)[:, :, 0], _img(0), _img(0))
    with pytest.raises(ValueError, match='g_cur'):
        block_excess(_img(0), _img(0), _img(0), _img(0, (8, 8)))
    with pytest.raises(ValueError, match='truths'):
        excess_flicker([_img(0)] * 3, [_img(0)] * 2)


def test_worst_one_percent_and_summary() -> None:
    v = np.arange(200, dtype=float)
    assert worst_mean(v) == pytest.approx(198.5)  # the worst 2 of 200
    assert worst_mean([3.0, math.nan, 1.0]) == 3.0
    s = summarise_flicker(v)
    assert (s['mean'], s['max'], s['frames']) == (99.5, 199.0, 200)
    assert math.isnan(summarise_flicker([])['mean'])


def test_smooth_path_is_continuous_and_off_the_poses() -> None:
    eyes = [(0.0, 0.0, 30.0), (10.0, 2.0, 31.0), (20.0, 0.0, 29.0), (30.0, -3.0, 30.0)]
    poses = [look_at(e, (e[0] + 5.0, 40.0, 0.0)) for e in eyes]
    path = smooth_path(poses, 20, (1.0, -2.0, 0.0))
    assert len(path) == 3 * 20 + 1
    for k, p in enumerate(poses):  # every 20th pose: a source pose moved by the offset in its frame
        np.testing.assert_allclose(path[20 * k][:3, 3], p[:3, 3] + p[:3, :3] @ [1.0, -2.0, 0.0], atol=1e-9)
        assert rotation_angle_deg(path[20 * k][:3, :3], p[:3, :3]) < 1e-5
    steps = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(path)])
    turns = np.array([rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in itertools.pairwise(path)])
    assert steps.max() < 1.5 * np.median(steps)  # no jumps
    assert turns.max() < 1.0
    for p in path:
        np.testing.assert_allclose(p[:3, :3] @ p[:3, :3].T, np.eye(3), atol=1e-9)
    with pytest.raises(ValueError, match='2 poses'):
        smooth_path(poses[:1], 10)
