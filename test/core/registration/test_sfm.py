# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Camera registration (``ibr_ros.core.registration.sfm`` and ``ibr_ros.jobs.register_bag``).

Two end-to-end runs: the real brighton_beach bag (18 DJI photos with EXIF GPS, must come out in
metric ENU) and a synthetic flight with exact ground truth (no GPS: correct up to similarity).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from ibr_ros.cli import register as register_cli
from ibr_ros.core import synth
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.registration.sfm import SfmError, SfmOptions, register_images, robust_similarity, umeyama
from ibr_ros.jobs import register_bag as register_bag_job
from ibr_ros.jobs.register_bag import BagRegistration, interpolate_positions, register_bag, select_indices


def _rotation_error_deg(r_a: np.ndarray, r_b: np.ndarray) -> float:
    c = (np.trace(r_a.T @ r_b) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _check_observations(res, i: int) -> float:
    """Mean distance (px) between observed keypoints and their reprojected 3D points in image i."""
    cw = np.linalg.inv(res.poses[i])
    pc = res.points[res.observation_ids[i]] @ cw[:3, :3].T + cw[:3, 3]
    np.testing.assert_allclose(pc[:, 2], res.observations[i][:, 2], rtol=1e-9)
    uv, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), res.camera.k, res.camera.d)
    return float(np.linalg.norm(uv[:, 0] - res.observations[i][:, :2], axis=1).mean())


# -- the real photos ---------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def brighton(repo) -> BagRegistration:
    return register_bag(repo / 'bags' / 'brighton_beach')


def test_brighton_all_registered_and_accurate(brighton):
    res = brighton.result
    print('brighton:', json.dumps(res.summary()))
    assert res.num_registered == 18
    assert res.registered.all()
    assert res.mean_reprojection_error_px < 1.0
    assert len(res.points) > 1000
    assert res.camera.width == 1000
    assert res.camera.height == 562
    assert res.camera.distortion_model == 'plumb_bob'
    assert np.all(res.camera.d[1:] == 0)
    assert abs(res.camera.cx - 499.5) < 1e-6
    assert abs(res.camera.cy - 280.5) < 1e-6
    assert np.all(np.isfinite(res.poses))
    for i in (0, 9, 17):
        assert _check_observations(res, i) < 1.0
    assert res.timing['total'] < 120.0


def test_brighton_is_metric_enu(brighton):
    res, gps = brighton.result, brighton.gps_enu
    assert res.metric
    assert res.alignment is not None
    a = res.alignment
    assert len(a.inliers) == 18
    assert a.num_used == 18
    assert a.rms_m < 3.0
    centres = res.camera_centres()
    assert np.sqrt(np.mean(np.sum((centres - gps) ** 2, axis=1))) < 3.0
    assert brighton.origin is not None
    assert np.allclose(gps[0], 0.0)
    # Scale: the drone flew ~40 m above its take-off point (XMP relative altitude) over a flat beach.
    altitude = np.median(centres[:, 2]) - np.median(res.points[:, 2])
    assert 35.0 < altitude < 45.0, altitude
    # Nadir photos: every optical axis points down.
    axes = res.poses[:, :3, 2]
    assert np.all(axes[:, 2] < -0.95)
    depths = np.concatenate([o[:, 2] for o in res.observations])
    assert 30.0 < np.median(depths) < 50.0


def test_register_cli_writes_json_and_npz(brighton, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(register_bag_job, 'register_bag', lambda *a, **k: brighton)
    parser = argparse.ArgumentParser()
    register_cli.register(parser.add_subparsers())
    out, npz = tmp_path / 'r.json', tmp_path / 'r.npz'
    args = parser.parse_args(['register', 'some_bag', '--out', str(out), '--npz', str(npz)])
    assert args.func(args) == 0
    assert 'registered 18/18 images' in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc['metric'] is True
    assert len(doc['per_image']) == 18
    assert doc['per_image'][0]['registered'] is True
    np.testing.assert_allclose(doc['per_image'][3]['t_wc'], brighton.result.poses[3])
    arrays = np.load(npz)
    assert arrays['observations'].shape == (sum(len(o) for o in brighton.result.observations), 5)
    np.testing.assert_array_equal(arrays['points'], brighton.result.points)


# -- synthetic flight with ground truth ---------------------------------------------------------------
@pytest.fixture(scope='module')
def synthetic():
    scene = synth.build_scene(synth.SceneConfig(seed=3))
    camera = synth.flight_camera((640, 360), 70.0)
    poses, frames = [], []
    for i in range(8):
        x = -30.0 + 60.0 * i / 7
        # Zigzag in y and z: camera centres far from collinear, so aligning them fixes the rotation.
        poses.append(look_at([x, -45.0 + 12.0 * (i % 2), 60.0 + 4.0 * math.cos(i)], [0.5 * x, 10.0, 0.0]))
        frames.append(synth.render_view(scene, camera, poses[-1], antialias=False))
    grey = np.full_like(frames[0].rgb, 128)  # cannot be registered: flagged, not an error
    res = register_images([*(f.rgb for f in frames), grey], camera=camera)
    return camera, np.array(poses), frames, res


def test_synthetic_poses_match_ground_truth_up_to_similarity(synthetic):
    camera, gt, _, res = synthetic
    print('synthetic:', json.dumps(res.summary()))
    assert res.registered.tolist() == [True] * 8 + [False]
    assert np.isnan(res.poses[8]).all()
    assert res.observations[8].shape == (0, 3)
    res = replace(res, poses=res.poses[:8])
    assert not res.metric
    assert res.alignment is None
    assert res.mean_reprojection_error_px < 1.0
    assert abs(res.camera.fx / camera.fx - 1.0) < 0.01
    m = umeyama(res.camera_centres(), gt[:, :3, 3])
    s = float(np.cbrt(np.linalg.det(m[:3, :3])))
    r_align = m[:3, :3] / s
    centres = res.camera_centres() @ m[:3, :3].T + m[:3, 3]
    baseline = np.linalg.norm(gt[-1, :3, 3] - gt[0, :3, 3])
    assert np.linalg.norm(centres - gt[:, :3, 3], axis=1).max() < 0.005 * baseline
    for i in range(len(gt)):
        assert _rotation_error_deg(r_align @ res.poses[i, :3, :3], gt[i, :3, :3]) < 0.5


def test_synthetic_observations_match_ground_truth_depth(synthetic):
    _, gt, frames, res = synthetic
    s = float(np.cbrt(np.linalg.det(umeyama(res.camera_centres()[:8], gt[:, :3, 3])[:3, :3])))
    for i in (0, 4, 7):
        obs = res.observations[i]
        assert len(obs) > 100
        assert _check_observations(res, i) < 1.0
        u, v = np.round(obs[:, 0]).astype(int), np.round(obs[:, 1]).astype(int)
        z_gt = frames[i].depth[v, u].astype(np.float64)
        rel = np.abs(s * obs[:, 2] - z_gt) / z_gt
        assert np.median(rel) < 0.01, np.median(rel)


# -- errors ------------------------------------------------------------------------------------------
def test_input_errors():
    img = np.zeros((40, 60, 3), np.uint8)
    with pytest.raises(SfmError, match='at least 2 images'):
        register_images([img])
    with pytest.raises(SfmError, match='one size'):
        register_images([img, np.zeros((40, 61, 3), np.uint8)])
    with pytest.raises(SfmError, match='HxWx3 uint8'):
        register_images([img, img[:, :, 0]])
    with pytest.raises(SfmError, match='camera is 80x40'):
        register_images([img, img], camera=PinholeCamera.from_fov(80, 40, 60.0))
    with pytest.raises(SfmError, match='gps_enu must be 2x3'):
        register_images([img, img], gps_enu=np.zeros((3, 3)))
    with pytest.raises(ValueError, match='camera_model'):
        SfmOptions(camera_model='FISHEYE')  # type: ignore[arg-type]


def test_featureless_images_raise(tmp_path):
    grey = np.full((80, 100, 3), 128, np.uint8)
    with pytest.raises(SfmError, match='no reconstruction from 3 images'):
        register_images([grey] * 3, workdir=tmp_path / 'work')
    assert (tmp_path / 'work' / 'database.db').is_file()  # a given workdir is kept


# -- similarity estimation and bag helpers -----------------------------------------------------------
def test_umeyama_and_robust_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3)) * 10
    r = look_at([0, 0, 0], [1, 2, -3])[:3, :3]
    dst = 2.5 * src @ r.T + [100.0, -50.0, 7.0]
    np.testing.assert_allclose(umeyama(src, dst)[:3, :3], 2.5 * r, atol=1e-9)
    noisy = dst.copy()
    noisy[[3, 11]] += [40.0, 0.0, 0.0]
    fit = robust_similarity(src, noisy, inlier_m=1.0)
    assert fit is not None
    m, inl = fit
    assert inl.sum() == 18
    assert not inl[3]
    assert not inl[11]
    np.testing.assert_allclose(m[:3, 3], [100.0, -50.0, 7.0], atol=1e-6)
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.0])
    assert robust_similarity(line, 3 * line) is None


def test_select_indices_and_gps_interpolation():
    assert select_indices(5, None).tolist() == [0, 1, 2, 3, 4]
    assert select_indices(100, 4).tolist() == [0, 33, 66, 99]
    fix_t = np.array([0, 1_000_000_000, 10_000_000_000], dtype=np.int64)
    fix_p = np.array([[0.0, 0, 0], [10.0, 0, 0], [20.0, 0, 0]])
    stamps = np.array([500_000_000, 1_000_000_000, 5_000_000_000, 12_500_000_000], dtype=np.int64)
    out = interpolate_positions(stamps, fix_t, fix_p, gap_s=2.0)
    np.testing.assert_allclose(out[:2], [[5.0, 0, 0], [10.0, 0, 0]])
    assert np.isnan(out[2:]).all()
