# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""job_depth and PhotometricCache: each keyframe's photometric depth swept once, reused by later jobs."""

from __future__ import annotations

import threading
from dataclasses import replace

import cv2
import numpy as np
import pytest

from ibr_ros.core.depth import job_mvs, mvs
from ibr_ros.core.depth.job_mvs import ROI_MARGIN_PX, PhotometricCache, guided_roi, job_depth
from ibr_ros.core.depth.mvs import MvsOptions, MvsView, compute_depth_maps
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.jobs.warmup import plane_views

OPTIONS = MvsOptions(max_neighbours=2, neighbour_roi=False)  # job_depth as compute_depth_maps
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


def _strip_views(xs: list[float], size: tuple[int, int] = (256, 192)) -> list[MvsView]:
    """Nadir views of a random-textured plane z = 0 from 20 m up, at the x positions ``xs`` (m)."""
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (768, 768, 3), dtype=np.uint8), (0, 0), 1.0)
    tex_to_plane = np.array([[0.1, 0.0, -38.4], [0.0, 0.1, -38.4], [0.0, 0.0, 1.0]])  # 0.1 m per texel
    cam = PinholeCamera.from_fov(size[0], size[1], 60.0)
    views = []
    for x in xs:
        t_wc = look_at([x, -2.0, 20.0], [x, 0.0, 0.0])
        t_cw = np.linalg.inv(t_wc)
        plane_to_img = cam.k @ np.column_stack([t_cw[:3, 0], t_cw[:3, 1], t_cw[:3, 3]])
        rgb = cv2.warpPerspective(texture, plane_to_img @ tex_to_plane, size, flags=cv2.INTER_LINEAR)
        views.append(MvsView(np.ascontiguousarray(rgb), cam, t_wc))
    return views


STRIP = (0.0, 4.0, -4.0, 8.0)  # the reference, then its neighbours
STRIP_RANGE = (17.0, 25.0)
STRIP_OPTIONS = MvsOptions(max_neighbours=3, neighbour_roi=False)


def _recorded_sweeps(monkeypatch: pytest.MonkeyPatch) -> list[tuple[tuple[int, int], list[int], float]]:
    """(reference image shape, source image ids, reference x position in m) of every mvs_depth call
    of job_depth, in the order they start."""
    calls: list[tuple[tuple[int, int], list[int], float]] = []
    real = job_mvs.mvs_depth

    def record(ref_rgb, ref_cam, ref_pose, src_rgbs, *a, **k):  # type: ignore[no-untyped-def]
        calls.append((np.asarray(ref_rgb).shape[:2], [id(s) for s in src_rgbs], float(ref_pose[0, 3])))
        return real(ref_rgb, ref_cam, ref_pose, src_rgbs, *a, **k)

    monkeypatch.setattr(job_mvs, 'mvs_depth', record)
    return calls


def _agreement(r, full) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Share of ``full``'s kept pixels ``r`` keeps, and their median relative depth difference."""
    both = (r.depth > 0) & (full.depth > 0)
    return both.sum() / max(1, (full.depth > 0).sum()), float(
        np.median(np.abs(r.depth[both] / full.depth[both] - 1))
    )


def test_neighbour_sweeps_take_the_reference_and_the_best_others(monkeypatch):
    views = _strip_views(list(STRIP))
    stamps = [1, 2, 3, 4]
    calls = _recorded_sweeps(monkeypatch)
    full = job_depth(views, stamps, STRIP_RANGE, STRIP_OPTIONS)
    assert len(calls) == 4  # the reference and 3 neighbours
    n_full = [len(s) for _, s, _ in calls]
    assert n_full[0] == 3
    assert min(n_full[1:]) >= 2
    for sources in (1, 2):
        calls.clear()
        r = job_depth(views, stamps, STRIP_RANGE, replace(STRIP_OPTIONS, neighbour_sources=sources))
        assert len(calls) == 4
        assert len(calls[0][1]) == 3  # the reference's own sweep is unchanged
        for (_, src, _), n in zip(calls[1:], n_full[1:], strict=True):
            assert len(src) == min(sources, n)
            assert src[0] == id(views[0].rgb)  # the reference comes first
        kept, err = _agreement(r, full)
        assert kept > 0.5, sources
        assert err < 0.005, sources


def _plane_depth(view: MvsView) -> np.ndarray:
    """z-depth (m) of the plane z = 0 at every pixel of ``view``."""
    cam, t = view.camera, view.t_wc
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    rays = np.linalg.inv(cam.k) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    z = -t[2, 3] / (t[2, :3] @ rays)
    return z.reshape(cam.height, cam.width).astype(np.float32)


def test_neighbour_sweeps_cover_only_what_sees_the_reference_depth(monkeypatch):
    views = _strip_views(list(STRIP))
    cam = views[0].camera
    truth = _plane_depth(views[0])
    roi = guided_roi(truth, cam, views[0].t_wc, cam, views[3].t_wc)
    assert roi is not None
    (x0, y0, x1, y1), (near, far) = roi
    assert (x0, y0, y1) == (0, 0, cam.height)  # the reference lies to its left: the right is cut
    assert x1 < 0.85 * cam.width
    assert all(v % 2 == 0 for v in roi[0])
    seen = _plane_depth(views[3])[:, : x1 - ROI_MARGIN_PX]
    assert near < seen.min()
    assert far > seen.max()
    assert STRIP_RANGE[0] < near < far < STRIP_RANGE[1]
    assert guided_roi(truth, cam, views[0].t_wc, cam, views[0].t_wc)[0] == (0, 0, cam.width, cam.height)
    far_away = views[0].t_wc.copy()
    far_away[0, 3] += 200.0
    assert guided_roi(truth, cam, views[0].t_wc, cam, far_away) is None
    assert guided_roi(np.zeros_like(truth), cam, views[0].t_wc, cam, views[3].t_wc) is None

    stamps = [1, 2, 3, 4]
    full = job_depth(views, stamps, STRIP_RANGE, STRIP_OPTIONS)
    calls = _recorded_sweeps(monkeypatch)
    r = job_depth(views, stamps, STRIP_RANGE, replace(STRIP_OPTIONS, neighbour_roi=True))
    assert calls[0][0] == (cam.height, cam.width)
    farthest = [shape for shape, _, x in calls if x == STRIP[3]]
    assert len(farthest) == 1
    assert farthest[0][1] < 0.85 * cam.width  # cropped
    swept = sum(s[0] * s[1] for s, _, _ in calls[1:])
    assert swept < 0.95 * 3 * cam.height * cam.width
    kept, err = _agreement(r, full)
    assert kept > 0.97
    assert err < 0.002
    assert (r.depth > 0).sum() < 1.03 * (full.depth > 0).sum()
    calls.clear()
    cache = PhotometricCache()  # reuse_neighbour_depth: whole maps, for the later jobs too
    job_depth(views, stamps, STRIP_RANGE, replace(STRIP_OPTIONS, neighbour_roi=True), cache=cache)
    assert [s for s, _, _ in calls] == [(cam.height, cam.width)] * 4
    assert len(cache) == 4


def test_the_depth_window_ignores_sparse_outliers_but_keeps_a_small_surface():
    """guided_roi's window ends at depths enough reference pixels project at: sparse wrong depths
    (the sweep's outliers, 0.1 % of the pixels) do not stretch it, a 15x15 px roof does."""
    views = _strip_views(list(STRIP))
    cam, ref, nbr = views[0].camera, views[0].t_wc, views[1].t_wc
    truth = _plane_depth(views[0])
    clean = guided_roi(truth, cam, ref, cam, nbr)
    assert clean is not None
    rng = np.random.default_rng(2)
    noisy = truth.copy()
    idx = rng.choice(noisy.size, noisy.size // 1000, replace=False)
    noisy.flat[idx] = rng.uniform(5.0, 100.0, idx.size)
    got = guided_roi(noisy, cam, ref, cam, nbr)
    assert got is not None
    assert got[1] == pytest.approx(clean[1], rel=0.02)
    roof = noisy.copy()
    roof[90:105, 100:115] = 12.0  # nearer than the plane (17-25 m)
    near, far = guided_roi(roof, cam, ref, cam, nbr)[1]  # type: ignore[index]
    assert near < 12.0 < 0.8 * clean[1][0]
    assert far == pytest.approx(clean[1][1], rel=0.02)


def test_a_sweep_window_sweeps_only_the_planes_within_it(monkeypatch):
    views = plane_views()
    hypotheses: list[int] = []
    real = mvs._Stack.sweep

    def count(self, base, offsets, *a):  # type: ignore[no-untyped-def]
        hypotheses.append(np.asarray(offsets).size)
        return real(self, base, offsets, *a)

    monkeypatch.setattr(mvs._Stack, 'sweep', count)
    ref, src = views[0], views[1:]
    args = (ref.rgb, ref.camera, ref.t_wc, [v.rgb for v in src], ref.camera, np.stack([v.t_wc for v in src]))
    full = mvs.mvs_depth(*args, depth_range=RANGE, options=OPTIONS)
    n_full = hypotheses[0]
    hypotheses.clear()
    near, far = 17.0, 26.0  # the plane lies 19-24 m away
    win = mvs.mvs_depth(*args, depth_range=RANGE, options=OPTIONS, sweep_window=(near, far))
    assert hypotheses[0] < 0.5 * n_full
    both = (full.depth > 0) & (win.depth > 0)
    assert both.sum() > 0.95 * (full.depth > 0).sum()
    assert np.median(np.abs(win.depth[both] / full.depth[both] - 1)) < 1e-3
    outside = mvs.mvs_depth(*args, depth_range=RANGE, options=OPTIONS, sweep_window=(40.0, 60.0))
    assert (outside.depth > 0).mean() < 0.05  # the best planes lie at its near end: rejected


def test_neighbours_swept_at_once_give_the_depth_of_one_at_a_time(monkeypatch):
    """job_depth sweeps the neighbours on several threads (the numba threads shared out among
    them, the costliest first): the same depth as one after another."""
    views = _strip_views(list(STRIP))
    o = replace(STRIP_OPTIONS, neighbour_roi=True)
    monkeypatch.setattr(job_mvs.numba, 'get_num_threads', lambda: 1)
    alone = job_depth(views, [1, 2, 3, 4], STRIP_RANGE, o)
    shared: list[int] = []
    set_threads = job_mvs.numba.set_num_threads
    monkeypatch.setattr(job_mvs.numba, 'get_num_threads', lambda: 4)
    monkeypatch.setattr(job_mvs.numba, 'set_num_threads', lambda n: shared.append(n) or set_threads(n))
    threads: set[str] = set()
    real = job_mvs._photometric

    def record(*a, **k):  # type: ignore[no-untyped-def]
        threads.add(threading.current_thread().name)
        return real(*a, **k)

    monkeypatch.setattr(job_mvs, '_photometric', record)
    together = job_depth(views, [1, 2, 3, 4], STRIP_RANGE, o)
    assert shared == [1, 1, 1]  # 3 neighbours on 3 threads, 4 // 3 numba threads each
    assert threads
    assert all(t.startswith('mvs') for t in threads)
    np.testing.assert_array_equal(together.depth, alone.depth)
    np.testing.assert_array_equal(together.n_consistent, alone.n_consistent)
    threads.clear()
    monkeypatch.setattr(job_mvs, '_threading_layer', lambda: 'workqueue')  # not thread-safe
    again = job_depth(views, [1, 2, 3, 4], STRIP_RANGE, o)
    assert threads == {threading.current_thread().name}  # one at a time, in the caller's thread
    np.testing.assert_array_equal(again.depth, alone.depth)


def test_a_failing_neighbour_cancels_the_queued_ones(monkeypatch):
    """An error (or Ctrl-C) in one neighbour's sweep reaches the caller; queued ones never start."""
    monkeypatch.setattr(job_mvs.numba, 'get_num_threads', lambda: 2)
    started: list[int] = []

    def sweep(i: int) -> int:
        started.append(i)
        if i == 0:
            raise KeyboardInterrupt
        return i

    with pytest.raises(KeyboardInterrupt):
        job_mvs._map_shared(sweep, list(range(50)))
    assert len(started) < 50
