# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""RefineScheduler: which keyframe is refined when, with which neighbours and depth range (no DDS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ibr_ros.core.depth.mvs import MvsOptions, MvsView, probe_points, select_neighbours
from ibr_ros.core.depth.schedule import (
    NeighbourIndex,
    RefineScheduler,
    ScheduleConfig,
    axis_scene_depth,
    parse_depth_range,
    shard_of,
)
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at

CAM = PinholeCamera(64, 48, np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]))
RGB = np.zeros((48, 64, 3), np.uint8)
T0 = 1_700_000_000_000_000_000


def orbit_view(deg: float, radius: float = 100.0, height: float = 60.0) -> MvsView:
    """A camera on a circle around the origin, looking at it (distance ~117 m)."""
    a = math.radians(deg)
    return MvsView(RGB, CAM, look_at([radius * math.cos(a), radius * math.sin(a), height], [0.0, 0.0, 0.0]))


def nadir_view(x: float) -> MvsView:
    """A camera 50 m up looking straight down (parallel optical axes along a line)."""
    return MvsView(RGB, CAM, look_at([x, 0.0, 50.0], [x, 0.0, 0.0], up=(0.0, 1.0, 0.0)))


def sched(**kw) -> RefineScheduler:
    return RefineScheduler(ScheduleConfig(**kw))


def drain(s: RefineScheduler, flush: bool = False) -> list[tuple[int, int, bool]]:
    """Run every due job to completion: (stamp, neighbour count, again) in order."""
    out = []
    while (job := s.next_job(flush)) is not None:
        out.append((job.stamp, len(job.neighbours), job.again))
        s.done(job)
    return out


def test_config_errors_name_the_field_and_value():
    with pytest.raises(ValueError, match=r'worker_index 2 must be in \[0, num_workers 2\)'):
        ScheduleConfig(num_workers=2, worker_index=2)
    with pytest.raises(ValueError, match='max_neighbours 1 must be >= min_neighbours 2'):
        ScheduleConfig(mvs=MvsOptions(max_neighbours=1))
    with pytest.raises(ValueError, match=r'depth_range .* got \[5.0, 1.0\]'):
        ScheduleConfig(depth_range=(5.0, 1.0))
    with pytest.raises(ValueError, match='scene_depth_m'):
        ScheduleConfig(scene_depth_m=-1.0)
    assert parse_depth_range([0, 0]) is None
    assert parse_depth_range([1, 20]) == (1.0, 20.0)
    for bad in ([1.0], [0.0, 5.0], [3.0, 2.0], [1.0, math.inf]):
        with pytest.raises(ValueError, match='depth_range must be'):
            parse_depth_range(bad)


def test_waits_for_min_neighbours_then_refines_oldest_first():
    s = sched(min_neighbours=2)
    assert s.add(T0, orbit_view(0))
    assert not s.add(T0, orbit_view(5))
    assert len(s) == 1
    assert s.next_job() is None  # a single keyframe
    s.add(T0 + 2, orbit_view(8))
    assert s.next_job() is None  # one neighbour each, two needed
    s.add(T0 + 1, orbit_view(4))  # out of order: the scheduler sorts by stamp
    job = s.next_job()
    assert job.stamp == T0
    assert set(job.neighbours) == {T0 + 1, T0 + 2}
    assert not job.again
    assert job.views[0] is job.view
    assert len(job.views) == 3
    s.done(job)
    assert drain(s) == [(T0 + 1, 2, False), (T0 + 2, 2, False)]
    assert s.refined() == [T0, T0 + 1, T0 + 2]
    assert s.unrefined() == []
    s.add(T0 + 3, orbit_view(12))
    assert [j[0] for j in drain(s)] == [T0 + 3]  # no refine_again: the others stay done


def test_flush_refines_with_one_neighbour_and_refine_again_adds_more():
    s = sched(min_neighbours=2, refine_again=True)
    s.add(T0, orbit_view(0))
    s.add(T0 + 1, orbit_view(6))
    assert s.next_job(flush=False) is None
    assert drain(s, flush=True) == [(T0, 1, False), (T0 + 1, 1, False)]
    s.add(T0 + 2, orbit_view(12))
    assert drain(s) == [(T0, 2, True), (T0 + 1, 2, True), (T0 + 2, 2, False)]
    assert drain(s, flush=True) == []


def test_failed_job_is_retried_only_with_more_neighbours():
    s = sched(min_neighbours=1)
    s.add(T0, orbit_view(0))
    s.add(T0 + 1, orbit_view(6))
    job = s.next_job()
    assert job.stamp == T0
    s.failed(job)
    assert s.next_job().stamp == T0 + 1  # the failed one is skipped
    s.failed(s.next_job())
    assert s.next_job(flush=True) is None
    assert s.unrefined() == [T0, T0 + 1]
    s.add(T0 + 2, orbit_view(12))
    assert [j[:2] for j in drain(s)] == [(T0, 2), (T0 + 1, 2), (T0 + 2, 2)]


def test_failed_refine_again_is_not_retried_in_a_loop():
    s = sched(min_neighbours=1, refine_again=True)
    s.add(T0, orbit_view(0))
    s.add(T0 + 1, orbit_view(6))
    drain(s)
    s.add(T0 + 2, orbit_view(12))
    job = s.next_job()
    assert job.again
    assert len(job.neighbours) == 2
    s.failed(job)
    assert s.next_job().stamp != T0


def test_shards_split_the_keyframes_exactly_once():
    stamps = [T0 + k * 100_000_000 for k in range(8)]
    done = []
    for w in (0, 1):
        s = sched(num_workers=2, worker_index=w, min_neighbours=1)
        for k, st in enumerate(stamps):
            s.add(st, orbit_view(5 * k))
        refined = [j[0] for j in drain(s)]
        assert all(shard_of(st, 2) == w for st in refined)
        assert all(s.is_mine(st) for st in refined)
        done.append(set(refined))
    assert done[0] | done[1] == set(stamps)
    assert not done[0] & done[1]


def test_depth_range_sources_and_the_parallel_axes_warning():
    views = [orbit_view(10 * k) for k in range(4)]
    s = sched()
    for k, v in enumerate(views):
        s.add(T0 + k, v)
    dist = float(np.linalg.norm(views[0].t_wc[:3, 3]))
    near, far = s.depth_range(T0)
    assert near == pytest.approx(0.25 * dist, rel=0.02)
    assert far == pytest.approx(1000 * dist, rel=0.02)  # beyond the horizon: far_ratio 1000
    assert axis_scene_depth(views[0].t_wc, [v.t_wc for v in views[1:]]) == pytest.approx(dist, rel=0.02)
    fixed = sched(depth_range=(5.0, 50.0))
    fixed.add(T0, views[0])
    assert fixed.depth_range(T0) == (5.0, 50.0)
    hint = sched(scene_depth_m=80.0, near_ratio=0.5, far_ratio=2.0)
    hint.add(T0, views[0])
    assert hint.depth_range(T0) == (40.0, 160.0)
    assert s.pop_warnings() == []

    nadir = sched()
    for k in range(3):
        nadir.add(T0 + k, nadir_view(4.0 * k))
    assert nadir.depth_range(T0) == pytest.approx((12.5 * 6 * 0.25, 12.5 * 6 * 1000))  # mean of 4 m and 8 m
    nadir.depth_range(T0 + 1)
    [warning] = nadir.pop_warnings()  # once, however often the range is guessed
    assert 'set scene_depth_m or depth_range' in warning
    assert nadir.pop_warnings() == []


def test_a_keyframe_without_neighbours_is_reported_once_on_flush():
    s = sched(min_neighbours=1, scene_depth_m=100.0)
    s.add(T0, orbit_view(0))
    s.add(T0 + 1, orbit_view(180))  # facing each other across the orbit: no overlap
    assert s.next_job(flush=False) is None
    assert s.pop_warnings() == []
    assert s.next_job(flush=True) is None
    warnings = s.pop_warnings()
    assert len(warnings) == 2
    assert all('has no neighbour' in w for w in warnings)
    assert s.next_job(flush=True) is None
    assert s.pop_warnings() == []


def test_sparse_points_give_each_keyframe_its_depth_range_and_bound_its_depth():
    """Nadir keyframes 50 m above ground: SfM-like points on the ground (z = 0 +- 2 m) replace the
    spacing guess (the sweep would reach 300 m) and become the job's plausible range."""
    rng = np.random.default_rng(0)
    s = sched(min_neighbours=1, scene_depth_m=40.0)
    for k in range(3):
        s.add(T0 + k, nadir_view(4.0 * k))
    assert s.depth_range(T0) == (10.0, 40000.0)  # scene_depth_m x (near_ratio, far_ratio)
    assert s.next_job(flush=True).plausible is None
    ground = np.c_[rng.uniform(-30, 40, 500), rng.uniform(-30, 30, 500), rng.uniform(-2, 2, 500)]
    s.set_points(np.r_[ground, [[np.nan, 0.0, 0.0]]], {T0: ground[:7]})  # non-finite points are ignored
    near, far = s.depth_range(T0)
    assert 0.5 * 48 <= near <= 0.5 * 49.5  # percentiles 1 / 99 of the depths, times 0.5 / 1.5
    assert 1.5 * 50.5 <= far <= 1.5 * 52
    job = s.next_job(flush=True)
    assert job.plausible == job.depth_range == s.depth_range(job.stamp)
    assert job.stamp == T0
    np.testing.assert_array_equal(job.seeds_w, ground[:7])  # the points this keyframe observed
    s.set_points(np.zeros((0, 3)))  # none: back to the configured rule
    assert s.depth_range(T0) == (10.0, 40000.0)
    with pytest.raises(ValueError, match=r'points_w must be Px3, got shape \(4,\)'):
        s.set_points(np.zeros(4))


# --------------------------------------------------------------------------- long flights: prefilter


def _reference_range(poses: list[np.ndarray], i: int, cfg: ScheduleConfig) -> tuple[float, float]:
    """The depth range rule over the whole flight, as before the prefilter (scene depth from the
    optical axes of all others, else 12.5 x the mean distance to the two nearest keyframes)."""
    others = poses[:i] + poses[i + 1 :]
    s = axis_scene_depth(poses[i], others)
    if s is None:
        d = sorted(float(np.linalg.norm(o[:3, 3] - poses[i][:3, 3])) for o in others)[:2]
        s = 12.5 * max(float(np.mean(d)), 0.1)
    return s * cfg.near_ratio, s * cfg.far_ratio


@pytest.mark.parametrize('kind', ['lawnmower', 'orbit', 'forward'])
def test_prefiltered_neighbours_and_ranges_match_the_search_over_the_whole_flight(kind):
    """Offline (all keyframes known): every job's neighbours and depth range are those of
    select_neighbours over all keyframes and of the range rule over all keyframes."""
    from ibr_ros.core.synth.trajectory import make_trajectory

    cam = PinholeCamera.from_fov(640, 360, 70.0)
    poses = [t.t_wc for t in make_trajectory(kind, duration_s=40.0, fps=2.0, seed=3)][:60]
    s = sched()
    for k, t in enumerate(poses):
        s.add(T0 + k, MvsView(RGB, cam, t))
    jobs = 0
    while (job := s.next_job(flush=True)) is not None:
        i = job.stamp - T0
        assert job.depth_range == _reference_range(poses, i, s.config)
        picks = select_neighbours(
            i, np.array(poses), cam, depth_range=job.probe_range, **s.config.mvs.neighbour_options()
        )
        assert job.neighbours == tuple(T0 + j for j in picks)
        s.done(job)
        jobs += 1
    assert jobs >= 50


def test_neighbour_index_keeps_every_possible_neighbour():
    """Random cameras around a scene: each keyframe's picks among all views lie in its candidates."""
    rng = np.random.default_rng(7)
    cam = PinholeCamera.from_fov(320, 240, 60.0)
    poses = [
        look_at(rng.uniform(-80, 80, 3) + np.array([0, 0, 60]), rng.uniform(-20, 20, 3) * [1, 1, 0])
        for _ in range(40)
    ]
    index = NeighbourIndex([MvsView(RGB, cam, t) for t in poses])
    opts = MvsOptions().neighbour_options()
    for i in range(len(poses)):
        probes = probe_points(cam, poses[i], 60.0)
        cands = set(index.candidates(i, probes, max_view_angle_deg=60.0, min_overlap=0.3).tolist())
        picks = select_neighbours(i, np.array(poses), cam, depth_range=(15.0, 240.0), **opts)
        assert set(picks) <= cands
        assert i not in cands


def test_neighbours_are_cached_until_a_keyframe_lands_nearby(monkeypatch):
    import ibr_ros.core.depth.schedule as schedule

    calls = []
    real = schedule.select_neighbours
    monkeypatch.setattr(schedule, 'select_neighbours', lambda *a, **kw: calls.append(a[0]) or real(*a, **kw))
    s = sched(min_neighbours=3, scene_depth_m=50.0)  # a fixed range: only arrivals matter
    for k in range(3):
        s.add(T0 + k, nadir_view(4.0 * k))
    assert s.next_job() is None  # two neighbours each, three needed
    assert len(calls) == 3
    assert s.next_job() is None
    assert len(calls) == 3  # nothing new: cached
    s.add(T0 + 3, nadir_view(5000.0))  # far away: no keyframe can see its scene
    assert s.next_job() is None
    assert len(calls) == 4  # only the new keyframe's own search
    s.add(T0 + 4, nadir_view(6.0))  # in the middle of the others: all searched again
    job = s.next_job()
    assert len(calls) == 5
    assert job.stamp == T0
    assert len(job.neighbours) == 3


def test_invalid_pose_is_refused_by_next_job():
    s = sched(min_neighbours=1)
    s.add(T0, orbit_view(0))
    bad = orbit_view(6).t_wc.copy()
    bad[:3, :3] *= 2.0
    s.add(T0 + 1, MvsView(RGB, CAM, bad))
    with pytest.raises(ValueError, match=f'keyframe {T0 + 1} ns t_wc rotation is not orthonormal'):
        s.next_job()
