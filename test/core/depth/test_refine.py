# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""DepthRefiner: the composition of Section III-A on synthetic ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth.mvs import MvsView
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.synth import LABEL_NAMES, SceneConfig, build_scene, flight_camera, render_view

TREE, WALL = LABEL_NAMES.index('tree'), LABEL_NAMES.index('wall')


@pytest.fixture(scope='module')
def frame():
    scene = build_scene(SceneConfig(seed=5))
    cam = flight_camera((320, 180), 70.0)
    t_wc = look_at([-120.0, -90.0, 55.0], [0.0, 0.0, 0.0])
    return cam, t_wc, render_view(scene, cam, t_wc)


def _simulated_mvs(frame_):
    """GT depth with the holes MVS leaves: sky, most foliage and walls, random dropouts, some outliers."""
    _, _, f = frame_
    rng = np.random.default_rng(0)
    d = np.where(np.isfinite(f.depth), f.depth, 0).astype(np.float32)
    d[(f.label == TREE) & (rng.random(d.shape) < 0.9)] = 0
    d[(f.label == WALL) & (rng.random(d.shape) < 0.6)] = 0
    d[rng.random(d.shape) < 0.3] = 0
    outliers = (rng.random(d.shape) < 0.005) & (d > 0)
    d[outliers] *= 1.5
    return d, outliers


def test_refined_depth_repairs_holes(frame):
    cam, t_wc, f = frame
    mvs, outliers = _simulated_mvs(frame)
    r = DepthRefiner().refine_from_mvs(MvsView(f.rgb, cam, t_wc), mvs)
    hole = (mvs == 0) & np.isfinite(f.depth) & ~r.sky
    rel = lambda d: np.abs(d[hole] - f.depth[hole]) / f.depth[hole]  # noqa: E731
    assert np.median(rel(r.fused)) < 0.05
    assert np.mean(rel(r.fused)) < np.mean(rel(r.mono_remapped))
    # Pruning removes most injected outliers and keeps most good samples.
    assert np.count_nonzero(r.mvs_pruned[outliers]) < 0.3 * outliers.sum()
    assert np.count_nonzero(r.mvs_pruned) > 0.9 * np.count_nonzero((mvs > 0) & ~outliers)
    # Known MVS depth passes through; sky (eroded) is +inf (REP-118), Eq. 14's depth is reported.
    keep = (r.mvs_pruned > 0) & ~r.sky
    np.testing.assert_array_equal(r.depth[keep], r.mvs_pruned[keep])
    assert r.sky_depth == pytest.approx(2 * r.mvs_pruned.max())
    assert r.sky.any()
    assert np.isposinf(r.depth[r.sky]).all()
    assert np.isfinite(r.depth[~r.sky]).all()
    assert r.depth.min() > 0
    assert set(r.timings_s) == {'prune', 'sky', 'mono', 'remap', 'fusion', 'sky_confidence'}
    # Confidence: MVS pixels >= 0.5, filled ones below, sky at its constant, all in [0, 1].
    c = r.confidence
    assert c is not None
    assert c.dtype == np.float32
    assert c.shape == r.depth.shape
    assert (c[keep] >= 0.45).all()  # MVS: 0.45 within 2 px of a depth step, >= 0.5 elsewhere
    assert np.mean(c[keep] >= 0.5) > 0.5  # (a small town view: trees and walls, many depth steps)
    assert (c[~keep & ~r.sky] < 0.5).all()
    assert c.min() >= 0.0
    assert c.max() <= 1.0
    # Confidence tracks error: the filled pixels it trusts more are nearer the truth.
    trusted = hole & (c >= np.median(c[hole]))
    doubted = hole & (c < np.median(c[hole]))
    err = np.abs(r.depth - f.depth) / f.depth
    assert np.mean(err[trusted]) < np.mean(err[doubted])


def test_depth_outside_the_plausible_range_becomes_unknown(frame):
    cam, t_wc, f = frame
    mvs, _ = _simulated_mvs(frame)
    view = MvsView(f.rgb, cam, t_wc)
    full = DepthRefiner(RefinerConfig(sky='none')).refine_from_mvs(view, mvs)
    finite = full.depth[np.isfinite(full.depth)]
    near, far = np.percentile(finite, [5, 90])
    r = DepthRefiner(RefinerConfig(sky='none')).refine_from_mvs(view, mvs, plausible=(near, far))
    out = (full.depth < near) | (full.depth > far)
    assert r.implausible == int(out.sum()) > 0
    assert (r.depth[out] == 0).all()
    assert (r.confidence[out] == 0).all()
    np.testing.assert_array_equal(r.depth[~out], full.depth[~out])


def test_alpha_zero_ablation_and_no_prune(frame):
    cam, t_wc, f = frame
    mvs, _ = _simulated_mvs(frame)
    r = DepthRefiner(RefinerConfig(alpha=0.0, prune=False, sky='none')).refine_from_mvs(
        MvsView(f.rgb, cam, t_wc), mvs
    )
    assert not r.sky.any()
    np.testing.assert_array_equal(r.mvs_pruned, r.mvs)
    assert np.isfinite(r.depth).all()


def test_bad_input_is_a_clear_error(frame):
    cam, t_wc, f = frame
    view = MvsView(f.rgb, cam, t_wc)
    refiner = DepthRefiner()
    with pytest.raises(RefineError, match='known pixels'):
        refiner.refine_from_mvs(view, np.zeros((180, 320), np.float32))
    with pytest.raises(RefineError, match='shape'):
        refiner.refine_from_mvs(view, np.ones((10, 10), np.float32))
    with pytest.raises(RefineError, match='no neighbours'):
        refiner.refine(view, [])
    # NaN and inf in the MVS map count as unknown, never propagate.
    mvs, _ = _simulated_mvs(frame)
    mvs[:5] = np.nan
    mvs[5:10] = np.inf
    r = refiner.refine_from_mvs(view, mvs)
    assert np.isfinite(r.depth[~r.sky]).all()
    assert (r.depth > 0).all()
    with pytest.raises(ValueError, match='mono'):
        RefinerConfig(mono='midas')  # type: ignore[arg-type]


def test_sfm_points_the_view_observed_seed_its_depth(frame):
    """Sparse points on a region MVS left empty (a wall) pull the fused depth there to the truth."""
    cam, t_wc, f = frame
    mvs, _ = _simulated_mvs(frame)
    wall = (f.label == WALL) & np.isfinite(f.depth)
    mvs[wall] = 0.0  # MVS found nothing on the walls
    view = MvsView(f.rgb, cam, t_wc)
    refiner = DepthRefiner(RefinerConfig(sky='none'))
    without = refiner.refine_from_mvs(view, mvs)
    v, u = np.nonzero(wall)
    pick = np.random.default_rng(1).choice(len(u), size=min(300, len(u)), replace=False)
    pc = cam.backproject(np.c_[u[pick], v[pick]], f.depth[v[pick], u[pick]])
    seeds_w = pc @ t_wc[:3, :3].T + t_wc[:3, 3]
    seeded = refiner.refine_from_mvs(view, mvs, seeds_w=seeds_w)
    err = lambda r: np.mean(np.abs(r.depth[wall] - f.depth[wall]) / f.depth[wall])  # noqa: E731
    assert err(seeded) < 0.5 * err(without)
    assert (seeded.confidence[v[pick], u[pick]] >= 0.45).all()  # a seed counts as a depth sample
