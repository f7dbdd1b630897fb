# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Incremental SfM registration of pose-less keyframes (``ibr_ros.core.registration.sfm_session``).

Eight frames of the shipped synthetic orbit (every 24th, ~19 m apart), registered at 320x180: the
poses must match the ground truth up to a similarity, keep their frame when more views arrive, and
follow the documented gauge (z up, first view above the origin, unit = first baseline or a hint).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from node_harness import shipped_frames

from ibr_ros.core.geometry.transforms import matrix_from_rt
from ibr_ros.core.registration.sfm import SfmError, umeyama
from ibr_ros.core.registration.sfm_session import ScaleHint, SfmSession

FRAMES = tuple(range(0, 192, 24))


@pytest.fixture(scope='module')
def views(repo) -> list[dict]:
    """stamp, rgb (640x360), camera and GT pose of FRAMES."""
    return shipped_frames(repo, FRAMES)


def _rot_deg(r_a: np.ndarray, r_b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(r_a.T @ r_b) - 1.0) / 2.0))))


def _mean_rotation(rs: list[np.ndarray]) -> np.ndarray:
    u, _, vt = np.linalg.svd(sum(rs))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _fit(update, views) -> tuple[np.ndarray, float, float]:
    """Similarity estimate -> GT over the registered views: (matrix, scale, centre RMS in metres)."""
    gt = {v['stamp']: v['pose'] for v in views}
    stamps = [s for s, p in update.poses.items() if p is not None]
    est = np.array([update.poses[s][:3, 3] for s in stamps])
    ref = np.array([gt[s][:3, 3] for s in stamps])
    m = umeyama(est, ref)
    rms = float(np.sqrt(np.mean(np.sum((est @ m[:3, :3].T + m[:3, 3] - ref) ** 2, axis=1))))
    return m, float(np.cbrt(np.linalg.det(m[:3, :3]))), rms


def test_incremental_registration_keeps_one_frame(views):
    session = SfmSession(max_side=320)
    for v in views[:5]:
        session.add(v['stamp'], v['rgb'], v['camera'])
    first = session.update()
    print(f'update 1: {first.num_registered}/{first.num_views} in {first.seconds:.2f} s')
    assert first.accepted
    assert first.reset
    assert first.frame == 'sfm'
    assert not first.metric
    assert first.num_registered == 5
    assert first.new == tuple(v['stamp'] for v in views[:5])
    assert first.camera is not None
    assert (first.camera.width, first.camera.height) == (640, 360)  # back at the input resolution
    assert abs(first.camera.fx / views[0]['camera'].fx - 1.0) < 0.02
    baseline = float(np.linalg.norm(views[1]['pose'][:3, 3] - views[0]['pose'][:3, 3]))  # ~19 m
    m, scale, rms = _fit(first, views)
    print(f'update 1: centre RMS {rms:.3f} m (baseline {baseline:.1f} m), scale {scale:.2f}')
    assert rms < 0.02 * baseline
    # Gauge: first view above the origin, unit = first baseline, z up (the fit is a rotation about z).
    p0, p1 = first.poses[views[0]['stamp']], first.poses[views[1]['stamp']]
    np.testing.assert_allclose(p0[:2, 3], 0.0, atol=1e-9)
    assert p0[2, 3] > 0
    assert abs(np.linalg.norm(p1[:3, 3] - p0[:3, 3]) - 1.0) < 1e-9
    assert abs(scale / baseline - 1.0) < 0.02
    # Orientations: the rotation to GT from the orientations (the centres lie on a short arc).
    r_align = _mean_rotation([v['pose'][:3, :3] @ first.poses[v['stamp']][:3, :3].T for v in views[:5]])
    assert _rot_deg(r_align, m[:3, :3] / scale) < 2.0
    assert r_align[2, 2] > math.cos(math.radians(3.0))
    for v in views[:5]:
        assert _rot_deg(r_align @ first.poses[v['stamp']][:3, :3], v['pose'][:3, :3]) < 0.3

    for v in views[5:]:
        session.add(v['stamp'], v['rgb'], v['camera'])
    second = session.update()
    print(f'update 2: {second.num_registered}/{second.num_views} in {second.seconds:.2f} s')
    assert second.accepted
    assert not second.reset
    assert second.frame == 'sfm'
    assert second.num_registered == 8
    assert second.new == tuple(v['stamp'] for v in views[5:])
    assert session.generation == 1
    _, _, rms2 = _fit(second, views)
    print(f'update 2: centre RMS {rms2:.3f} m, frame RMS {second.frame_rms:.4f} (first baselines)')
    assert rms2 < 0.02 * baseline
    assert second.frame_rms < 0.01
    for v in views[:5]:  # the earlier poses stay where they were (in units of the first baseline)
        a, b = first.poses[v['stamp']], second.poses[v['stamp']]
        assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 0.01
        assert _rot_deg(a[:3, :3], b[:3, :3]) < 0.2
    np.testing.assert_array_equal(session.pose(views[7]['stamp']), second.poses[views[7]['stamp']])
    assert second.points.shape[1] == 3
    assert len(second.points) > 100


def test_scale_hint_then_gps_switches_to_enu(views):
    first_views, gps_views = views[:3], views[3:]
    # The hint: the distance between the first two registered views (by stamp) is known.
    baseline = float(np.linalg.norm(views[1]['pose'][:3, 3] - views[0]['pose'][:3, 3]))
    session = SfmSession(max_side=320, scale_hint=ScaleHint('baseline', baseline))
    for v in first_views:
        session.add(v['stamp'], v['rgb'], v['camera'])
    first = session.update()
    assert (first.accepted, first.frame, first.metric) == (True, 'sfm', True)
    _, scale, _ = _fit(first, views)
    assert abs(scale - 1.0) < 0.02  # metres
    # Five more views carry GPS (here their exact centres, spread off a line by ~2 m): ENU, a reset.
    for v in gps_views:
        session.add(v['stamp'], v['rgb'], v['camera'], gps_enu=v['pose'][:3, 3])
    second = session.update()
    assert (second.accepted, second.reset, second.frame, second.metric) == (True, True, 'enu', True)
    assert session.generation == 2
    assert len(second.new) == 8
    err = [np.linalg.norm(second.poses[v['stamp']][:3, 3] - v['pose'][:3, 3]) for v in views]
    print(f'ENU from 5 GPS positions: max centre error {max(err):.2f} m')
    assert max(err) < 0.1 * baseline  # 5 GPS positions on a gentle arc: roll about it is weak


def test_bad_input_and_too_few_views(views):
    v = views[0]
    session = SfmSession(max_side=320)
    assert not session.update().accepted  # no views
    session.add(v['stamp'], v['rgb'], v['camera'])
    only = session.update()
    assert not only.accepted
    assert 'at least 2' in only.reason
    assert only.poses == {v['stamp']: None}
    with pytest.raises(SfmError, match=f'stamp {v["stamp"]} ns was already added'):
        session.add(v['stamp'], v['rgb'], v['camera'])
    with pytest.raises(SfmError, match='rgb of stamp 1 ns must be HxWx3 uint8'):
        session.add(1, v['rgb'][..., 0], v['camera'])
    with pytest.raises(SfmError, match='camera of stamp 2 ns is 320x180 but its image is 640x360'):
        session.add(2, v['rgb'], v['camera'].scaled(0.5))
    with pytest.raises(SfmError, match='session registers one camera of 640x360'):
        session.add(3, v['rgb'][::2, ::2].copy(), v['camera'].scaled(0.5))
    with pytest.raises(SfmError, match='gps_enu of stamp 4 ns must be 3 finite numbers'):
        session.add(4, v['rgb'], v['camera'], gps_enu=np.array([1.0, np.nan, 2.0]))
    with pytest.raises(ValueError, match=r'ScaleHint\.kind'):
        ScaleHint('height', 50.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r'ScaleHint\.metres'):
        ScaleHint('altitude', 0.0)
    grey = np.full_like(v['rgb'], 128)
    session.add(5, grey, v['camera'])
    failed = session.update()
    assert not failed.accepted
    assert failed.reason.startswith('SfM failed')
    assert session.frame is None


def test_frame_fit_collinear_centres_and_inconsistent_models():
    """The alignment to the previous frame: collinear centres use the orientations; outliers reject."""
    rng = np.random.default_rng(0)
    truth = {}
    for k in range(6):  # a straight flight line, all cameras looking the same way
        truth[k] = matrix_from_rt(np.eye(3), [10.0 * k, 0.0, 50.0])
    r = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    r *= np.sign(np.linalg.det(r))
    move = np.eye(4)
    move[:3, :3], move[:3, 3] = 0.3 * r, [5.0, -2.0, 1.0]
    session = SfmSession()
    session._poses = dict(truth)
    session._frame = 'sfm'
    moved = {}
    for k, t in truth.items():
        p = np.eye(4)
        p[:3, :3], p[:3, 3] = r @ t[:3, :3], move[:3, :3] @ t[:3, 3] + move[:3, 3]
        moved[k] = p
    fit, why = session._fit_to_previous(moved)
    assert fit is not None, why
    m, rms = fit
    assert rms < 1e-9
    for k in truth:
        np.testing.assert_allclose(m[:3, :3] @ moved[k][:3, 3] + m[:3, 3], truth[k][:3, 3], atol=1e-9)
    broken = {k: p.copy() for k, p in moved.items()}
    for k in (0, 2, 4, 5):  # most views disagree: the new model is rejected
        broken[k][:3, 3] += rng.normal(size=3) * 5.0
    fit, why = session._fit_to_previous(broken)
    assert fit is None
    assert 'common views consistent' in why
