# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The model for viewers: keyframe points against the depth and the pose, frustum geometry, TF chains."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.viz import (
    FRUSTUM_SEGMENTS,
    T_BODY_FROM_OPTICAL,
    CloudConfig,
    FrameNames,
    VizConfig,
    VizModel,
    camera_transforms,
    frustum_segments,
    grid,
    keyframe_frame,
    keyframe_points,
)

W, H = 80, 48


def _keyframe(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, PinholeCamera, np.ndarray]:
    """A synthetic keyframe: depth (a slanted plane, with unknown, sky and low-confidence patches),
    rgb, confidence, camera and a pose looking down at the origin from an oblique angle."""
    rng = np.random.default_rng(seed)
    cam = PinholeCamera.from_fov(W, H, 70.0)
    v, u = np.mgrid[0:H, 0:W]
    depth = (20.0 + 0.1 * u + 0.05 * v).astype(np.float32)
    depth[:6] = np.inf  # sky
    depth[10:14, 10:20] = np.nan  # unknown (REP-118)
    depth[30:34, 40:60] = 0.0  # unknown (msg_utils)
    conf = np.ones((H, W), np.float32)
    conf[20:24] = 0.2
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    t_wc = look_at([12.0, -9.0, 15.0], [0.0, 0.0, 0.0])
    return depth, rgb, conf, cam, t_wc


def test_points_lie_on_the_depth_along_the_pixel_rays_with_their_pixel_colours():
    depth, rgb, conf, cam, t_wc = _keyframe()
    cfg = CloudConfig(stride=4, min_confidence=0.5, max_points=0)
    xyz, col = keyframe_points(depth, rgb, cam, t_wc, conf, cfg)
    assert xyz.dtype == np.float32
    assert col.dtype == np.uint8
    # Every point projects back to a pixel of the stride grid, at that pixel's depth, with its colour.
    t_cw = np.linalg.inv(t_wc)
    pc = xyz.astype(np.float64) @ t_cw[:3, :3].T + t_cw[:3, 3]
    uv, z = cam.project(pc)
    u, v = np.rint(uv).astype(int).T
    np.testing.assert_allclose(uv, np.stack([u, v], axis=1), atol=1e-3)
    assert set(u % 4) == {2}
    assert set(v % 4) == {2}
    np.testing.assert_allclose(z, depth[v, u], rtol=1e-5)
    np.testing.assert_array_equal(col, rgb[v, u])
    # Exactly the grid pixels with a finite known depth and enough confidence.
    g = grid(depth, 4)
    expected = np.isfinite(g) & (g > 0) & (grid(conf, 4) >= 0.5)
    assert len(xyz) == int(expected.sum())
    assert not ((v < 6) | ((v >= 20) & (v < 24))).any()  # no sky, no low confidence
    # Without a confidence map every known depth counts.
    assert len(keyframe_points(depth, rgb, cam, t_wc, None, cfg)[0]) > len(xyz)


def test_points_from_the_kept_grid_equal_points_from_the_full_images():
    depth, rgb, conf, cam, t_wc = _keyframe(1)
    cfg = CloudConfig(stride=3)
    full = keyframe_points(depth, rgb, cam, t_wc, conf, cfg)
    kept = keyframe_points(grid(depth, 3), grid(rgb, 3), cam, t_wc, grid(conf, 3), cfg)
    for a, b in zip(full, kept):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match='depth is'):
        keyframe_points(depth[:-5], rgb, cam, t_wc, conf, cfg)


def test_max_points_thins_evenly_and_bad_configs_are_rejected():
    depth, rgb, _, cam, t_wc = _keyframe()
    xyz, _ = keyframe_points(depth, rgb, cam, t_wc, None, CloudConfig(stride=1, max_points=100))
    assert len(xyz) == 100
    with pytest.raises(ValueError, match='stride'):
        CloudConfig(stride=0)
    with pytest.raises(ValueError, match='min_confidence'):
        CloudConfig(min_confidence=1.5)


def test_frustum_corners_project_to_the_image_corners_at_the_cut_depth():
    _, _, _, cam, t_wc = _keyframe()
    seg = frustum_segments(cam, t_wc, 2.5)
    assert seg.shape == (FRUSTUM_SEGMENTS, 2, 3)
    np.testing.assert_allclose(seg[:4, 0], np.tile(t_wc[:3, 3], (4, 1)))  # from the camera centre
    t_cw = np.linalg.inv(t_wc)
    corners = seg[:4, 1] @ t_cw[:3, :3].T + t_cw[:3, 3]
    uv, z = cam.project(corners)
    np.testing.assert_allclose(z, 2.5)
    np.testing.assert_allclose(uv, [[0, 0], [W, 0], [W, H], [0, H]], atol=1e-9)
    np.testing.assert_allclose(seg[4:8, 0], seg[:4, 1])  # the image rectangle joins the corners
    np.testing.assert_allclose(seg[4:8, 1], np.roll(seg[:4, 1], -1, axis=0))
    up = seg[8, 1] - seg[8, 0]  # the tick points to the image's top: -y of the optical frame
    np.testing.assert_allclose(up / np.linalg.norm(up), -t_wc[:3, 1], atol=1e-12)
    with pytest.raises(ValueError, match='depth_m'):
        frustum_segments(cam, t_wc, 0.0)


def test_tf_chain_composes_to_the_pose_and_the_body_frame_is_rep103():
    _, _, _, _, t_wc = _keyframe()
    chain = camera_transforms(t_wc, 'map', 'camera_optical_frame', 'camera_link')
    assert [(p, c) for p, c, _ in chain] == [('map', 'camera_link'), ('camera_link', 'camera_optical_frame')]
    np.testing.assert_allclose(chain[0][2] @ chain[1][2], t_wc, atol=1e-12)
    # Body x (forward) is the optical z (viewing direction), body z (up) is optical -y.
    t_wb = chain[0][2]
    np.testing.assert_allclose(t_wb[:3, 0], t_wc[:3, 2], atol=1e-12)
    np.testing.assert_allclose(t_wb[:3, 2], -t_wc[:3, 1], atol=1e-12)
    np.testing.assert_allclose(T_BODY_FROM_OPTICAL[:3, :3] @ [0, 0, 1], [1, 0, 0])
    (direct,) = camera_transforms(t_wc, 'map', 'cam', '')
    assert direct[:2] == ('map', 'cam')
    np.testing.assert_allclose(direct[2], t_wc)
    assert keyframe_frame('keyframe_', 12) == 'keyframe_12_optical_frame'


def test_model_products_appear_as_the_fields_arrive():
    depth, rgb, conf, cam, t_wc = _keyframe()
    names = FrameNames('cam_optical', '', 'kf_')
    model = VizModel(VizConfig(CloudConfig(stride=4), names, frustum_depth_m=0.0))
    assert model.put_pose(200, t_wc, 'map')
    assert not model.put_pose(200, t_wc, 'map')  # a mirror's copy
    assert model.points(200) is None
    assert model.frustums() == []  # no camera yet
    model.put_camera(200, cam)
    model.put_image(200, rgb)
    assert model.frustum_depth() == 1.0  # before any depth
    assert model.put_depth(200, depth)
    assert model.frustum_depth() == pytest.approx(
        0.15 * np.median(grid(depth, 4)[np.isfinite(grid(depth, 4)) & (grid(depth, 4) > 0)])
    )
    n_plain = len(model.points(200)[0])
    assert model.put_confidence(200, conf)
    assert len(model.points(200)[0]) < n_plain
    t2 = t_wc.copy()
    t2[:3, 3] += 1.0
    model.put_pose(100, t2, 'map')  # an older stamp arriving later keeps its arrival order
    model.put_camera(100, cam)
    assert [i for i, _ in model.frustums()] == [0, 1]
    assert [s for s, *_ in model.static_transforms()] == [200, 100]
    assert model.static_transforms()[0][1:3] == ('map', 'kf_200_optical_frame')
    np.testing.assert_allclose(model.poses()[1], t2)
    with pytest.raises(ValueError, match="frame 'sfm'"):
        model.put_pose(300, t_wc, 'sfm')
    lines = model.frustum_lines()
    assert [(ns, i) for ns, i, *_ in lines] == [('keyframes', 0), ('keyframes', 1)]
    model.set_novel_view(cam, t_wc)
    assert model.frustum_lines()[-1][:2] == ('novel_view', 0)
    model.drop(200)
    assert [i for i, _ in model.frustums()] == [1]  # ids are not reused
    assert model.camera_transforms(t_wc)[0][:2] == ('map', 'cam_optical')
