# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe selection: blur rejection, baseline/rotation/interval rules, offline target count."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from ibr_ros.core.flight.keyframes import (
    IntervalSelector,
    KeyframeConfig,
    KeyframeSelector,
    blur_score,
    select_keyframes,
    select_keyframes_for_target,
    target_baseline,
)
from ibr_ros.core.geometry.transforms import look_at, matrix_from_rt, rotation_from_ypr
from ibr_ros.core.synth import SceneConfig, build_scene, flight_camera, make_trajectory, render_view


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    return matrix_from_rt(rotation_from_ypr(np.radians(yaw_deg), -0.5, 0.0), [x, 0.0, 50.0])


def test_blur_score_orders_sharpness():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (540, 960, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (3, 3), 0.8)
    blurred = cv2.GaussianBlur(img, (0, 0), 3.0)
    assert blur_score(img) > 5 * blur_score(blurred)
    assert blur_score(img[..., 0]) > 0


def test_rules_in_order():
    sel = KeyframeSelector(KeyframeConfig(baseline_ratio=0.1, max_rotation_deg=20, max_interval_s=10))
    s = 1_000_000_000
    assert sel.decide(0, _pose(0), 100.0, 50.0).reason == 'first'
    assert sel.decide(1 * s, _pose(2), 100.0, 50.0).reason == 'not_moved'  # 2 m < 0.1 x 50 m
    d = sel.decide(2 * s, _pose(6), 100.0, 50.0)
    assert (d.keep, d.reason, d.baseline_m) == (True, 'baseline', 6.0)
    assert sel.decide(3 * s, _pose(6, yaw_deg=25), 100.0, 50.0).reason == 'rotation'
    assert sel.decide(14 * s, _pose(6, yaw_deg=25), 100.0, 50.0).reason == 'interval'
    assert sel.decide(15 * s, _pose(30), 20.0, 50.0).reason == 'blurred'  # far below the median 100
    assert sel.count == 4


def test_unknown_depth_uses_min_baseline_and_min_interval():
    sel = KeyframeSelector(KeyframeConfig(min_baseline_m=3.0, min_interval_s=0.5))
    assert sel.decide(0, _pose(0), 1.0).keep
    assert sel.decide(100_000_000, _pose(10), 1.0).reason == 'too_soon'
    assert not sel.decide(600_000_000, _pose(2), 1.0).keep
    assert sel.decide(700_000_000, _pose(3.5), 1.0).keep


def test_offline_target_count_on_a_synthetic_flight():
    samples = make_trajectory('orbit', duration_s=20, fps=10, seed=0)
    poses = [s.t_wc for s in samples]
    stamps = [int(s.t_s * 1e9) for s in samples]
    blur = [100.0] * len(samples)
    blur[50] = 1.0  # one blurred frame is never chosen
    picked = select_keyframes(stamps, poses, blur, target=25, scene_depth_m=[80.0] * len(samples))
    assert 23 <= len(picked) <= 27
    assert 50 not in picked
    assert picked == sorted(picked)
    assert picked[0] == 0
    # the same selection with its scale: the streaming selector at that scale picks exactly these
    chosen = select_keyframes_for_target(stamps, poses, blur, target=25, scene_depth_m=[80.0] * len(samples))
    assert chosen.indices == picked
    assert [i for i, d in enumerate(chosen.decisions) if d.keep] == picked
    cfg = KeyframeConfig()
    sel = KeyframeSelector(replace(cfg, baseline_ratio=cfg.baseline_ratio * chosen.scale,
                                   min_baseline_m=cfg.min_baseline_m * chosen.scale))  # fmt: skip
    again = [i for i in range(len(stamps)) if sel.decide(stamps[i], poses[i], blur[i], 80.0).keep]
    assert again == picked


def test_synthetic_frames_blur_and_bad_config():
    scene = build_scene(SceneConfig(seed=0))
    cam = flight_camera((160, 90), 70)
    f = render_view(scene, cam, look_at([-80, -60, 50], [0, 0, 0]))
    assert blur_score(f.rgb) > blur_score(cv2.GaussianBlur(f.rgb, (0, 0), 2.0))
    with pytest.raises(ValueError, match='blur_ratio'):
        KeyframeConfig(blur_ratio=2.0)
    with pytest.raises(ValueError, match='one entry per frame'):
        select_keyframes([0, 1], [np.eye(4)], [1.0, 1.0])


def test_interval_selector_keeps_the_sharpest_frame_per_window():
    sel = IntervalSelector(1.0, KeyframeConfig(blur_ratio=0.5))
    ms = 1_000_000
    out = []
    blur = {0: 100.0, 300: 120.0, 600: 30.0, 900: 110.0, 1200: 90.0, 1500: 95.0, 2100: 100.0, 2400: 10.0}
    for t, b in blur.items():
        out += sel.push(t * ms, b, f'frame {t}')
    assert out == [(300 * ms, 'frame 300'), (1500 * ms, 'frame 1500')]
    assert sel.push(500 * ms, 500.0, 'late') == []  # an older window is closed
    assert sel.rejected == {'blurred': 2, 'late': 1}  # 600 ms and 2400 ms are blurred
    assert sel.flush() == [(2100 * ms, 'frame 2100')]
    assert sel.flush() == []
    assert sel.count == 3
    with pytest.raises(ValueError, match='interval_s must be > 0'):
        IntervalSelector(0.0)


def test_target_baseline():
    assert target_baseline(0, 0.0) is None  # off
    assert target_baseline(0, 500.0) is None
    assert target_baseline(25, 500.0) == 20.0
    with pytest.raises(ValueError, match='needs expected_path_m > 0'):
        target_baseline(25, 0.0)
    with pytest.raises(ValueError, match='>= 0'):
        target_baseline(-1, 100.0)
