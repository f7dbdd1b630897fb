# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pose and camera conventions (REP-103 optical frame, ENU world)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibr_ros.core.geometry.camera import CameraError, PinholeCamera
from ibr_ros.core.geometry.transforms import (
    GeometryError,
    look_at,
    matrix_from_rt,
    quaternion_from_rotation,
    rotation_angle_deg,
    rotation_from_quaternion,
    rotation_from_ypr,
    similarity_times_pose,
    validate_pose,
)

finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 1e-3))
def test_quaternion_round_trip(q):
    r = rotation_from_quaternion(q)
    assert r.T @ r == pytest.approx(np.eye(3), abs=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    q2 = quaternion_from_rotation(r)
    qn = np.asarray(q) / np.linalg.norm(q)
    assert min(np.abs(q2 - qn).max(), np.abs(q2 + qn).max()) < 1e-9


@pytest.mark.parametrize('q', [(0, 0, 0, 0), (float('nan'), 0, 0, 1), (0, float('inf'), 0, 1)])
def test_bad_quaternion_names_field(q):
    with pytest.raises(GeometryError, match='orientation'):
        rotation_from_quaternion(q)


def test_validate_pose_rejects_garbage():
    with pytest.raises(GeometryError, match='finite'):
        validate_pose(np.full((4, 4), np.nan))
    with pytest.raises(GeometryError, match='orthonormal'):
        validate_pose(np.diag([2.0, 1, 1, 1]))
    with pytest.raises(GeometryError, match='4x4'):
        validate_pose(np.eye(3))
    assert validate_pose(matrix_from_rt(np.eye(3), [1, 2, 3]))[2, 3] == 3


def test_ypr_axes():
    # Level camera looking east: optical z east, x south (right), y down.
    r = rotation_from_ypr(0.0, 0.0, 0.0)
    assert r[:, 2] == pytest.approx([1, 0, 0])
    assert r[:, 0] == pytest.approx([0, -1, 0])
    assert r[:, 1] == pytest.approx([0, 0, -1])
    # Yaw 90 deg looks north; pitch -90 deg looks straight down.
    assert rotation_from_ypr(math.pi / 2, 0, 0)[:, 2] == pytest.approx([0, 1, 0], abs=1e-12)
    assert rotation_from_ypr(0.3, -math.pi / 2, 0)[:, 2] == pytest.approx([0, 0, -1], abs=1e-12)
    # Positive roll (right-hand about forward) turns image right towards the ground.
    assert rotation_from_ypr(0, 0, 0.5)[2, 0] < 0


def test_look_at_points_optical_axis():
    t = look_at([0, 0, 50], [10, 20, 0])
    z = t[:3, 2]
    assert z == pytest.approx(np.array([10, 20, -50]) / np.linalg.norm([10, 20, -50]))
    assert t[:3, 1] @ [0, 0, 1] < 0  # image down points to the ground
    validate_pose(t)


def test_camera_project_backproject_round_trip():
    cam = PinholeCamera.from_fov(640, 360, 70)
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [640, 360], size=(100, 2))
    z = rng.uniform(1, 100, size=100)
    uv2, z2 = cam.project(cam.backproject(uv, z))
    assert uv2 == pytest.approx(uv)
    assert z2 == pytest.approx(z)
    assert cam.hfov_deg == pytest.approx(70)
    assert np.isnan(cam.project([[0, 0, -1]])[0]).all()


def test_camera_scaled_pixel_centres():
    cam = PinholeCamera.from_fov(640, 360, 70)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (320, 180)
    assert half.cx == pytest.approx((320 - 1) / 2)
    assert half.fx == pytest.approx(cam.fx / 2)


@pytest.mark.parametrize(
    ('kwargs', 'match'),
    [
        ({'k': np.zeros((3, 3))}, 'all zeros'),
        ({'k': [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}, 'focal'),
        ({'k': np.eye(3), 'distortion_model': 'equidistant'}, 'not supported'),
        ({'k': np.eye(3), 'd': np.zeros(9)}, 'at most 5'),
        ({'k': np.full((3, 3), np.nan)}, 'finite'),
    ],
)
def test_camera_rejects_bad_parameters(kwargs, match):
    with pytest.raises(CameraError, match=match):
        PinholeCamera(10, 10, **kwargs)


def test_rotation_angle_and_similarity_helpers() -> None:
    """rotation_angle_deg, similarity_times_pose and core.sfm.similarity_from_orientations agree."""
    from ibr_ros.core.registration.sfm import similarity_from_orientations

    r = rotation_from_ypr(0.3, -0.2, 0.1)
    assert rotation_angle_deg(r, r) == pytest.approx(0.0, abs=1e-6)
    turned = rotation_from_ypr(0.2 + math.radians(40), 0, 0)  # 40 deg more yaw about the world z axis
    assert rotation_angle_deg(rotation_from_ypr(0.2, 0, 0), turned) == pytest.approx(40.0)
    m = matrix_from_rt(2.5 * rotation_from_ypr(0.7, 0.1, -0.3), [1.0, -2.0, 3.0])
    rng = np.random.default_rng(0)
    poses = [
        matrix_from_rt(rotation_from_ypr(*rng.uniform(-1, 1, 3)), rng.uniform(-10, 10, 3)) for _ in range(4)
    ]
    moved = [similarity_times_pose(m, p) for p in poses]
    for p, q in zip(poses, moved, strict=True):
        np.testing.assert_allclose(q[:3, 3], m[:3, :3] @ p[:3, 3] + m[:3, 3])
        np.testing.assert_allclose(q[:3, :3] @ q[:3, :3].T, np.eye(3), atol=1e-12)  # still rigid
    fit = similarity_from_orientations(
        np.array([p[:3, 3] for p in poses]), np.array([q[:3, 3] for q in moved]),
        np.array([p[:3, :3] for p in poses]), np.array([q[:3, :3] for q in moved]),
    )  # fmt: skip
    np.testing.assert_allclose(fit, m, atol=1e-9)
    assert (
        similarity_from_orientations(np.zeros((3, 3)), np.zeros((3, 3)), *[np.stack([np.eye(3)] * 3)] * 2)
        is None
    )


def test_a_cropped_camera_sees_the_box_of_the_image():
    cam = PinholeCamera.from_fov(640, 480, 70.0)
    box = cam.cropped(100, 50, 420, 290)
    assert (box.width, box.height) == (320, 240)
    pts = np.array([[1.0, -0.5, 6.0], [-0.3, 0.2, 4.0]])
    uv, z = cam.project(pts)
    uv_box, z_box = box.project(pts)
    np.testing.assert_allclose(uv_box, uv - [100, 50])
    np.testing.assert_allclose(z_box, z)
    np.testing.assert_allclose(box.projection[:, :3], box.k)
    for bad in ((0, 0, 641, 10), (10, 10, 10, 20), (-1, 0, 5, 5)):
        with pytest.raises(CameraError, match='crop box'):
            cam.cropped(*bad)
