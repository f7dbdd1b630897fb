# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""depth_vs_points / split_observed: refined depth checked against held-back SfM points."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.evaluation import depth_vs_points, split_observed
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at


def test_points_on_the_ground_check_a_nadir_depth_map():
    cam = PinholeCamera.from_fov(64, 48, 60.0)
    t_wc = look_at([0.0, 0.0, 40.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-22, 22, 400), rng.uniform(-15, 15, 400), np.zeros(400)]
    depth = np.full((48, 64), 40.0, np.float32)
    conf = np.full_like(depth, 0.8)
    depth[:, :8] = 100.0  # a wrong strip, deeper than 2 x the height
    conf[:, :4] = 0.1  # half of it doubted
    r = depth_vs_points(depth, conf, cam, t_wc, pts)
    assert r['sparse_depth_m'] == pytest.approx(40.0)
    assert r['deeper_than_2x'] == pytest.approx(8 / 64)
    assert r['points'] == r['confident_points'] + r['filled_points'] > 50
    assert 0 < r['confident_off'] < 0.2  # the confident half of the strip
    assert r['max_rel'] == pytest.approx(1.5)
    assert r['filled_off'] == 1.0
    assert depth_vs_points(depth, None, cam, t_wc, np.zeros((0, 3))) == {'points': 0.0}


def test_split_is_reproducible_and_disjoint():
    obs = {5: np.arange(300.0).reshape(100, 3), 2: np.zeros((0, 3))}
    seeds, checks = split_observed(obs, 0.2, seed=1)
    again = split_observed(obs, 0.2, seed=1)
    assert all(np.array_equal(seeds[k], again[0][k]) for k in obs)
    assert len(seeds[5]) + len(checks[5]) == 100
    assert 5 <= len(checks[5]) <= 40
    assert not set(map(tuple, seeds[5])) & set(map(tuple, checks[5]))
    with pytest.raises(ValueError, match='fraction must be in'):
        split_observed(obs, 1.0, seed=1)
