# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe selection: blur measure and rejection, overlap rule, baseline/rotation/interval rules,
offline target count."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from ibr_ros.core.flight.keyframes import (
    IntervalSelector,
    KeyframeConfig,
    KeyframeSelector,
    blur_px,
    detail_score,
    select_keyframes,
    select_keyframes_for_target,
    target_baseline,
)
from ibr_ros.core.geometry.transforms import look_at, matrix_from_rt, rotation_from_ypr
from ibr_ros.core.synth import SceneConfig, build_scene, flight_camera, make_trajectory, render_view


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    return matrix_from_rt(rotation_from_ypr(np.radians(yaw_deg), -0.5, 0.0), [x, 0.0, 50.0])


SHARP, BLURRED = 2.0, 6.0  # blur_px of a sharp and of a blurred frame (max_blur_px 3 by default)


def _textured(rng: np.random.Generator) -> np.ndarray:
    """A sharp, busy scene: random grey 4 px blocks (a town, a forest), 480x360 rgb8."""
    blocks = rng.integers(0, 256, (90, 120), dtype=np.uint8)
    gray = cv2.GaussianBlur(cv2.resize(blocks, (480, 360), interpolation=cv2.INTER_NEAREST), (0, 0), 0.7)
    return np.ascontiguousarray(np.repeat(gray[..., None], 3, axis=2))


def _low_texture(rng: np.random.Generator) -> np.ndarray:
    """A sharp, nearly empty scene: smooth shading, a few field/shore edges of 30-60 grey levels and
    sensor grain (a lawn, a lake, farmland), 480x360 rgb8."""
    yy, xx = np.mgrid[0:360, 0:480].astype(np.float32)
    gray = 110 + 15 * np.sin(xx / 90 + rng.uniform(0, 6)) + 10 * np.cos(yy / 70)
    for _ in range(3):  # fields: quadrilaterals at any angle, 30-60 grey levels off the ground
        corners = rng.uniform(40, 440, 2) + rng.uniform(-70, 70, (4, 2))
        contrast = float(rng.choice([-1, 1]) * rng.uniform(30, 60))
        cv2.fillPoly(gray, [np.round(corners).astype(np.int32)], 110 + contrast, cv2.LINE_AA)
    cv2.circle(gray, (int(rng.integers(100, 380)), 180), 50, 170.0, -1, cv2.LINE_AA)  # a pond
    gray = cv2.GaussianBlur(gray, (0, 0), 0.7) + rng.normal(0.0, 1.5, gray.shape)
    gray = np.clip(gray, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(np.repeat(gray[..., None], 3, axis=2))


def _blurs(img: np.ndarray) -> dict[str, np.ndarray]:
    """Defocus (Gaussian sigma 1.5 px) and linear motion blur: 5 px across, 5.7 px diagonal."""
    return {
        'gauss 1.5': cv2.GaussianBlur(img, (0, 0), 1.5),
        'motion 5 px horizontal': cv2.filter2D(img, -1, np.full((1, 5), 0.2, np.float32)),
        'motion 5.7 px diagonal': cv2.filter2D(img, -1, np.eye(4, dtype=np.float32) / 4),
    }


def test_blur_px_is_independent_of_texture():
    """A sharp low-texture photo scores as sharp as a busy one (the variance of the Laplacian, the old
    score, differs by far more); every blurred copy of either is over max_blur_px."""
    rng = np.random.default_rng(0)
    low, busy = _low_texture(rng), _textured(rng)
    laplacian = [cv2.Laplacian(cv2.cvtColor(i, cv2.COLOR_RGB2GRAY), cv2.CV_32F).var() for i in (low, busy)]
    assert laplacian[1] > 20 * laplacian[0]  # content-dependent: a lake "blurred" next to a town
    limit = KeyframeConfig().max_blur_px
    sharp = [blur_px(low), blur_px(busy)]
    assert max(sharp) < limit - 0.4
    assert abs(sharp[0] - sharp[1]) < 0.6
    for img in (low, busy):
        for name, blurred in _blurs(img).items():
            assert blur_px(blurred) > limit + 0.3, name
    assert blur_px(busy[..., 0]) == pytest.approx(sharp[1], abs=0.05)  # mono8 as rgb8
    # Working resolution: a 2x larger copy is measured at max_side, not at its own size.
    big = cv2.resize(busy, (960, 720), interpolation=cv2.INTER_CUBIC)
    assert blur_px(big, max_side=480) == pytest.approx(sharp[1], abs=0.5)


def test_featureless_image_is_not_judged():
    """No edge to measure: NaN, and NaN is never blurred (a calm lake is not rejected)."""
    flat = np.full((240, 320, 3), 128, np.uint8)
    noise = np.clip(128 + np.random.default_rng(1).normal(0, 2, (240, 320)), 0, 255).astype(np.uint8)
    assert math.isnan(blur_px(flat))
    assert math.isnan(blur_px(noise))
    assert math.isnan(blur_px(flat[:20, :20]))  # smaller than the span
    sel = KeyframeSelector()
    assert sel.decide(0, _pose(0), math.nan).reason == 'first'


def test_rules_in_order():
    sel = KeyframeSelector(KeyframeConfig(baseline_ratio=0.1, max_rotation_deg=20, max_interval_s=10))
    s = 1_000_000_000
    assert sel.decide(0, _pose(0), SHARP, 50.0).reason == 'first'
    assert sel.decide(1 * s, _pose(2), SHARP, 50.0).reason == 'not_moved'  # 2 m < 0.1 x 50 m
    d = sel.decide(2 * s, _pose(6), SHARP, 50.0)
    assert (d.keep, d.reason, d.baseline_m, d.blur) == (True, 'baseline', 6.0, SHARP)
    assert sel.decide(3 * s, _pose(6, yaw_deg=25), SHARP, 50.0).reason == 'rotation'
    assert sel.decide(14 * s, _pose(6, yaw_deg=25), SHARP, 50.0).reason == 'interval'
    # A blurred frame that would be a keyframe (6 m from the last) is held for the next frame: that one
    # is 7 m and 25 deg from the last keyframe, within 2 spacings (10 m, 40 deg): the held one is dropped.
    assert sel.decide(15 * s, _pose(12), BLURRED, 50.0).reason == 'held'
    d = sel.decide(16 * s, _pose(13), SHARP, 50.0)
    assert (d.keep, d.reason) == (True, 'baseline')
    assert d.previous is not None
    assert (d.previous.keep, d.previous.reason, d.previous.blur) == (False, 'blurred', BLURRED)
    assert sel.decide(17 * s, _pose(13.5), BLURRED, 50.0).reason == 'blurred'  # not moved: dropped
    assert sel.flush() is None
    assert sel.count == 5


def _final(sel: KeyframeSelector, frames: list[tuple[int, np.ndarray, float]]) -> list[str]:
    """The final reason of every frame (a held frame's from the next decision's ``previous``)."""
    out: list[str] = []
    for stamp, pose, blur in frames:
        d = sel.decide(stamp, pose, blur)
        if d.previous is not None:
            out[-1] = d.previous.reason
        out.append(d.reason)
    if (last := sel.flush()) is not None:
        out[-1] = last.reason
    return out


def test_blurred_frame_kept_for_overlap_with_poses():
    """A blurred frame that would be a keyframe is decided with the next frame: dropped when that one
    is within overlap_gap (2) spacings of the last keyframe (video), else kept (survey stills)."""
    s = 1_000_000_000
    # Video: 1 m per frame, a keyframe every 5 m; frames 5-12 blurred.
    video = [(i * s // 10, _pose(i), BLURRED if 5 <= i <= 12 else SHARP) for i in range(15)]
    reasons = _final(KeyframeSelector(KeyframeConfig(min_baseline_m=5.0)), video)
    assert reasons[:5] == ['first'] + ['not_moved'] * 4
    assert reasons[5:9] == ['blurred'] * 4  # frames 6-9 are within 10 m of the last keyframe
    assert reasons[9] == 'overlap'  # frame 10 is 10 m away: without 9 the gap would be 2 spacings
    assert reasons[10:] == ['blurred'] * 3 + ['not_moved', 'baseline']
    # Survey stills 8 m apart with the same spacing: without a blurred still its neighbours would be
    # 16 m apart, so each is kept; not the first (no keyframe before) nor the last (none after).
    stills = [(i * 6 * s, _pose(8.0 * i), BLURRED if i in (0, 3, 4, 6) else SHARP) for i in range(7)]
    reasons = _final(KeyframeSelector(KeyframeConfig(min_baseline_m=5.0)), stills)
    assert reasons == ['blurred', 'first', 'baseline', 'overlap', 'overlap', 'baseline', 'blurred']
    # overlap_gap 0: blurred frames are always dropped, never held.
    reasons = _final(KeyframeSelector(KeyframeConfig(min_baseline_m=5.0, overlap_gap=0.0)), stills[1:5])
    assert reasons == ['first', 'baseline', 'blurred', 'blurred']


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
    blur = [SHARP] * len(samples)
    blur[50] = BLURRED  # one blurred frame is never chosen (its neighbours are sharp)
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
    limit = KeyframeConfig().max_blur_px
    assert blur_px(f.rgb) < limit < blur_px(cv2.GaussianBlur(f.rgb, (0, 0), 2.0))
    with pytest.raises(ValueError, match='overlap_gap'):
        KeyframeConfig(overlap_gap=0.5)
    with pytest.raises(ValueError, match='max_blur_px'):
        KeyframeConfig(max_blur_px=-1.0)
    with pytest.raises(ValueError, match='one entry per frame'):
        select_keyframes([0, 1], [np.eye(4)], [1.0, 1.0])


def _picks(picks: list) -> list[tuple[int, str, str]]:
    return [(p.stamp, p.item, p.reason) for p in picks]


def test_interval_selector_keeps_the_sharpest_frame_per_window():
    sel = IntervalSelector(1.0, KeyframeConfig())
    ms = 1_000_000
    out = []
    blur = {0: 2.0, 300: 1.8, 600: 6.0, 900: 1.9, 1200: 2.2, 1500: 2.1, 2100: 2.0, 2400: 7.0}
    for t, b in blur.items():
        out += sel.push(t * ms, b, f'frame {t}')
    assert _picks(out) == [(300 * ms, 'frame 300', 'sharpest'), (1500 * ms, 'frame 1500', 'sharpest')]
    assert sel.push(500 * ms, 0.5, 'late') == []  # an older window is closed
    assert sel.rejected == {'blurred': 2, 'late': 1}  # 600 ms and 2400 ms are blurred
    assert _picks(sel.flush()) == [(2100 * ms, 'frame 2100', 'sharpest')]
    assert sel.flush() == []
    assert sel.count == 3
    assert sel.kept_for_overlap == 0
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


def test_interval_selector_ranks_unblurred_frames_by_detail():
    """With ``detail``, a window keeps its unblurred frame with the most detail (stills: the most
    textured), never a blurred one however detailed."""
    rng = np.random.default_rng(4)
    lawn, town = _low_texture(rng), _textured(rng)
    frames = [('lawn', lawn), ('town', town), ('town blurred', cv2.GaussianBlur(town, (0, 0), 1.5))]
    sel: IntervalSelector[str] = IntervalSelector(20.0, KeyframeConfig())
    for i, (name, img) in enumerate(frames):
        assert sel.push(i * 6_000_000_000, blur_px(img), name, detail=detail_score(img)) == []
    assert [(p.item, p.reason) for p in sel.flush()] == [('town', 'sharpest')]
    assert sel.rejected['blurred'] == 1
    assert detail_score(frames[2][1]) > detail_score(lawn)  # the blurred town is still "more detailed"


def test_interval_selector_keeps_blurred_stills_needed_for_overlap():
    """Stills 6 s apart (1 s windows): each is its own window; a blurred one is kept for overlap, except
    the first (no keyframe before it) and the last (none after it)."""
    s = 1_000_000_000
    blurred = {0, 3, 4, 7}
    sel: IntervalSelector[int] = IntervalSelector(1.0, KeyframeConfig())
    out = []
    for i in range(8):
        out += sel.push(i * 6 * s, BLURRED if i in blurred else SHARP, i)
    out += sel.flush()
    assert [(p.item, p.reason) for p in out] == [
        (1, 'sharpest'), (2, 'sharpest'), (3, 'overlap'), (4, 'overlap'), (5, 'sharpest'), (6, 'sharpest')
    ]  # fmt: skip
    assert (sel.kept_for_overlap, sel.rejected, sel.count) == (2, {'blurred': 2, 'late': 0}, 6)
    # overlap_gap 0: every blurred still is dropped.
    sel = IntervalSelector(1.0, KeyframeConfig(overlap_gap=0.0))
    out = [p for i in range(8) for p in sel.push(i * 6 * s, BLURRED if i in blurred else SHARP, i)]
    assert [p.item for p in out + sel.flush()] == [1, 2, 5, 6]
    assert sel.rejected == {'blurred': 4, 'late': 0}


def test_interval_selector_video_drops_a_blurred_window_but_not_two():
    """Video at 10 Hz, 1 s windows: one whole blurred window leaves its neighbours' keyframes at most
    2 s apart (dropped); a second one in a row would not (its least blurred frame is kept)."""
    ms = 1_000_000
    sel: IntervalSelector[int] = IntervalSelector(1.0, KeyframeConfig())
    blur = {t: SHARP for t in range(0, 6000, 100)}
    blur.update({t: BLURRED + t / 1000 for t in range(1000, 2000, 100)})  # window 1: all blurred
    blur.update({t: BLURRED + (t % 1000) / 1000 for t in range(3000, 5000, 100)})  # windows 3, 4
    out = [p for t, b in blur.items() for p in sel.push(t * ms, b, t)] + sel.flush()
    assert [(p.item // 1000, p.reason) for p in out] == [
        (0, 'sharpest'), (2, 'sharpest'), (4, 'overlap'), (5, 'sharpest')
    ]  # fmt: skip
    assert [p.item for p in out if p.reason == 'overlap'] == [4000]  # the least blurred of window 4
    assert sel.rejected['blurred'] == 29


def test_stills_of_different_content_are_all_kept():
    """Survey stills alternating between busy and nearly empty scenes (the old relative rule dropped
    the empty ones): none is blurred; their blurred copies are."""
    rng = np.random.default_rng(3)
    stills = [(_low_texture if i % 3 else _textured)(rng) for i in range(9)]
    s = 1_000_000_000
    sel: IntervalSelector[int] = IntervalSelector(1.0, KeyframeConfig())
    out = [p for i, img in enumerate(stills) for p in sel.push(i * 5 * s, blur_px(img), i)] + sel.flush()
    assert [p.item for p in out] == list(range(9))
    assert [p.reason for p in out] == ['sharpest'] * 9
    assert sel.rejected == {'blurred': 0, 'late': 0}
    limit = KeyframeConfig().max_blur_px
    assert all(blur_px(cv2.GaussianBlur(img, (0, 0), 1.5)) > limit for img in stills)
