# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""job_depth and PhotometricCache: each keyframe's photometric depth swept once, reused by later jobs."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth import job_mvs
from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth
from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.jobs.warmup import plane_views

OPTIONS = MvsOptions(max_neighbours=2)
RANGE = (10.0, 60.0)


def test_the_cache_keeps_the_most_recently_used_maps():
    c = PhotometricCache(capacity=2)
    a, b, d = (np.full((2, 3), v, np.float32) for v in (1, 2, 3))
    c.put(1, a)
    c.put(2, b)
    assert c.get(1) is not None  # 1 is now the most recent
    c.put(3, d)
    assert len(c) == 2
    assert c.get(2) is None
    assert c.get(1) is not None
    got = c.get(3)
    assert got is not None
    assert not got.flags.writeable
    np.testing.assert_array_equal(got, d)
    assert (c.hits, c.misses) == (3, 1)
    c.clear()
    assert len(c) == 0
    none = PhotometricCache(capacity=0)
    none.put(1, a)
    assert none.get(1) is None
    with pytest.raises(ValueError, match='capacity'):
        PhotometricCache(-1)


def test_without_a_cache_it_is_the_batch_geometric_depth_of_the_reference():
    views = plane_views()
    r = job_depth(views, [1, 2, 3], RANGE, OPTIONS)
    batch = compute_depth_maps(views, options=OPTIONS, depth_range=RANGE)[0]
    np.testing.assert_array_equal(r.depth, batch.depth)
    np.testing.assert_array_equal(r.n_consistent, batch.n_consistent)
    np.testing.assert_array_equal(r.confidence, batch.confidence)
    assert r.neighbours == (1, 2)
    assert r.reason == ''
    assert (r.depth > 0).mean() > 0.5


def test_a_cached_neighbour_is_not_swept_again(monkeypatch):
    views = plane_views()
    cache = PhotometricCache()
    first = job_depth(views, [1, 2, 3], RANGE, OPTIONS, cache=cache)
    assert len(cache) == 3  # the reference and both neighbours
    sweeps = []
    real = job_mvs.mvs_depth
    monkeypatch.setattr(job_mvs, 'mvs_depth', lambda *a, **k: sweeps.append(1) or real(*a, **k))
    again = job_depth(views, [1, 2, 3], RANGE, OPTIONS, cache=cache)
    assert len(sweeps) == 1  # the reference only
    np.testing.assert_array_equal(again.depth, first.depth)
    swapped = job_depth([views[1], views[0], views[2]], [2, 1, 3], RANGE, OPTIONS, cache=cache)
    assert len(sweeps) == 2
    assert (swapped.depth > 0).mean() > 0.5


def test_a_sweep_beyond_the_horizon_picks_the_neighbours_of_the_scene_depth():
    """far_ratio only moves the sweep's far end: neighbours are probed at the scene depth."""
    jobs = []
    for far in (4.0, 1000.0):
        s = RefineScheduler(ScheduleConfig(min_neighbours=1, scene_depth_m=25.0, far_ratio=far, mvs=OPTIONS))
        for i, v in enumerate(plane_views()):
            s.add(i + 1, v)
        job = s.next_job(flush=True)
        assert job is not None
        jobs.append(job)
    assert jobs[0].neighbours == jobs[1].neighbours
    assert len(jobs[0].neighbours) == 2
    assert jobs[1].depth_range == pytest.approx((6.25, 25000.0))
    assert jobs[1].probe_range == pytest.approx((6.25, 100.0))
    r = job_depth(
        jobs[1].views, jobs[1].stamps, jobs[1].depth_range, OPTIONS, probe_range=jobs[1].probe_range
    )
    truth = compute_depth_maps(jobs[0].views, options=OPTIONS, depth_range=RANGE)[0].depth
    both = (r.depth > 0) & (truth > 0)
    assert both.mean() > 0.5
    assert np.median(np.abs(r.depth[both] / truth[both] - 1)) < 0.01


def test_it_needs_a_neighbour_and_one_stamp_per_view():
    views = plane_views()
    with pytest.raises(ValueError, match='stamps'):
        job_depth(views, [1, 2], RANGE, OPTIONS)
    with pytest.raises(ValueError, match='at least one neighbour'):
        job_depth(views[:1], [1], RANGE, OPTIONS)


def test_a_flight_reuses_neighbour_depth_only_when_asked():
    assert PhotometricCache.for_flight(False).capacity == 0  # the default: each job sweeps its own
    assert PhotometricCache.for_flight(True).capacity == job_mvs.FLIGHT_CAPACITY
