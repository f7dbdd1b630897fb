# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.camera_info and ibr_ros.core.geometry.undistort."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message

from ibr_ros.core.geometry.camera import CameraError, PinholeCamera, Roi
from ibr_ros.core.geometry.undistort import undistort_image, undistort_points
from msg_utils import (
    MessageError,
    camera_info_to_pinhole,
    is_rosbags_message,
    make_header,
    new_message,
    pinhole_to_camera_info,
    stamp_to_ns,
    typestore,
)

FLAVORS = ('rclpy', 'rosbags')


@st.composite
def cameras(draw) -> PinholeCamera:
    w, h = draw(st.integers(1, 5000)), draw(st.integers(1, 5000))
    f = st.floats(1.0, 1e4, allow_nan=False)
    c = st.floats(-100.0, 5000.0, allow_nan=False)
    coef = st.floats(-1.0, 1.0, allow_nan=False)
    model = draw(st.sampled_from(['plumb_bob', 'rational_polynomial']))
    d = draw(
        st.lists(coef, min_size=5 if model == 'plumb_bob' else 8, max_size=5 if model == 'plumb_bob' else 8)
    )
    k = [[draw(f), draw(coef), draw(c)], [0.0, draw(f), draw(c)], [0.0, 0.0, 1.0]]
    p = None
    if draw(st.booleans()):
        p = np.hstack([np.asarray(k), [[draw(st.floats(-500, 500))], [0.0], [0.0]]])
    r = cv2.Rodrigues(np.array([draw(coef), draw(coef), draw(coef)]) * 0.1)[0]
    roi = Roi(
        draw(st.integers(0, 99)), draw(st.integers(0, 99)), draw(st.integers(0, 99)), draw(st.integers(0, 99))
    )
    roi = Roi(roi.x_offset, roi.y_offset, roi.height, roi.width, draw(st.booleans()))
    return PinholeCamera(w, h, k, d, model, r, p, draw(st.integers(0, 4)), draw(st.integers(0, 4)), roi)


@settings(max_examples=60, deadline=None)
@given(cam=cameras(), flavor=st.sampled_from(FLAVORS))
def test_camera_info_round_trip(cam, flavor):
    msg = pinhole_to_camera_info(cam, make_header(42, 'camera_optical', flavor), flavor=flavor)
    assert is_rosbags_message(msg) == (flavor == 'rosbags')
    assert (stamp_to_ns(msg.header.stamp), msg.header.frame_id) == (42, 'camera_optical')
    assert camera_info_to_pinhole(msg) == cam


@settings(max_examples=15, deadline=None)
@given(cam=cameras())
def test_flavours_serialize_to_identical_cdr(cam):
    """CameraInfo built in both flavours gives the same CDR (modulo uninitialised padding)."""
    r = pinhole_to_camera_info(cam, make_header(5, 'cam'))
    b = pinhole_to_camera_info(cam, make_header(5, 'cam', 'rosbags'), flavor='rosbags')
    ts, name = typestore(), 'sensor_msgs/msg/CameraInfo'
    raw_r, raw_b = bytes(serialize_message(r)), bytes(ts.serialize_cdr(b, name))
    assert len(raw_r) == len(raw_b)
    assert bytes(ts.serialize_cdr(ts.deserialize_cdr(raw_r, name), name)) == raw_b
    assert all(raw_b[i] == 0 for i in range(len(raw_b)) if raw_b[i] != raw_r[i])
    assert deserialize_message(raw_b, type(r)) == r
    assert camera_info_to_pinhole(ts.deserialize_cdr(raw_r, name)) == cam


def info(flavor: str = 'rclpy', **fields):
    base = {
        'height': 480,
        'width': 640,
        'distortion_model': 'plumb_bob',
        'd': [0.0] * 5,
        'k': [500.0, 0, 320, 0, 500, 240, 0, 0, 1],
        'r': [0.0] * 9,
        'p': [0.0] * 12,
    }
    base.update(fields)
    for key in ('d', 'k', 'r', 'p'):
        base[key] = np.asarray(base[key], dtype=np.float64) if flavor == 'rosbags' else base[key]
    return new_message('sensor_msgs/msg/CameraInfo', flavor, **base)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_unset_r_and_p_mean_identity_and_k(flavor):
    cam = camera_info_to_pinhole(info(flavor))
    assert np.array_equal(cam.r, np.eye(3))
    assert np.array_equal(cam.p, np.hstack([cam.k, np.zeros((3, 1))]))
    assert (cam.width, cam.height, cam.fx, cam.cx) == (640, 480, 500.0, 320.0)


def test_empty_distortion_model_is_plumb_bob_without_distortion():
    cam = camera_info_to_pinhole(info(distortion_model='', d=[]))
    assert cam.distortion_model == 'plumb_bob'
    assert not cam.is_distorted


@pytest.mark.parametrize('flavor', FLAVORS)
def test_all_zero_k_is_refused(flavor):
    with pytest.raises(MessageError, match=r'CameraInfo\.k is all zeros'):
        camera_info_to_pinhole(info(flavor, k=[0.0] * 9))


@pytest.mark.parametrize(
    ('fields', 'match'),
    [
        ({'width': 0}, r'CameraInfo\.width x height 0x480'),
        ({'k': [500.0, 0, float('nan'), 0, 500, 240, 0, 0, 1]}, r'CameraInfo\.k must be finite'),
        ({'d': [0.1, float('inf'), 0, 0, 0]}, r'CameraInfo\.d must be finite'),
        ({'distortion_model': 'equidistant', 'd': [0.1] * 4}, "CameraInfo: distortion_model 'equidistant'"),
        ({'k': [-500.0, 0, 320, 0, 500, 240, 0, 0, 1]}, 'CameraInfo: K focal lengths must be positive'),
        ({'d': [0.1] * 8}, "CameraInfo: D has 8 coefficients, 'plumb_bob' takes at most 5"),
    ],
)
def test_bad_camera_info(fields, match):
    with pytest.raises(MessageError, match=match):
        camera_info_to_pinhole(info(**fields))


# -- undistortion ------------------------------------------------------------------------------

DISTORTED = PinholeCamera(
    160, 120, [[100.0, 0, 81.3], [0, 102.0, 58.7], [0, 0, 1]], d=[-0.28, 0.09, 0.001, -0.0015, -0.01]
)


def test_undistort_points_inverts_opencv_projection():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.7, 0.7, 200), rng.uniform(-0.5, 0.5, 200), np.ones(200)])
    distorted, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), DISTORTED.k, DISTORTED.d)
    ideal, _ = DISTORTED.project(pts)
    out = undistort_points(distorted.reshape(-1, 2), DISTORTED)
    assert out.shape == (200, 2)
    assert np.abs(out - ideal).max() < 1e-6


def test_undistort_points_without_distortion_is_identity():
    cam = PinholeCamera.from_fov(64, 48, 90)
    uv = np.array([[1.5, 2.5], [60.0, 40.0]])
    assert np.array_equal(undistort_points(uv, cam), uv)
    assert undistort_points(np.zeros((0, 2)), DISTORTED).shape == (0, 2)


def test_undistort_image_without_distortion_is_unchanged():
    cam = PinholeCamera.from_fov(64, 48, 90)
    img = np.zeros((48, 64, 3), np.uint8)
    out, new = undistort_image(img, cam)
    assert out is img
    assert new is cam


@pytest.mark.parametrize('alpha', [0.0, 1.0])
def test_undistort_image_samples_the_distorted_pixel(alpha):
    v, u = np.mgrid[0:120, 0:160].astype(np.float32)
    ramp = np.dstack([u, v])  # each pixel holds its own coordinates: remap must be exact for it
    out, cam = undistort_image(ramp, DISTORTED, alpha=alpha)
    assert out.shape == ramp.shape
    assert out.dtype == np.float32
    assert not cam.is_distorted
    assert np.array_equal(cam.r, np.eye(3))
    assert np.array_equal(cam.p[:, :3], cam.k)
    # Where the output has a source pixel, it holds the distorted position of its undistorted ray.
    vv, uu = np.mgrid[20:100:9, 30:130:11]
    rays = cam.backproject(np.column_stack([uu.ravel(), vv.ravel()]), np.ones(uu.size))
    src, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), DISTORTED.k, DISTORTED.d)
    src = src.reshape(-1, 2)
    inside = (src[:, 0] >= 0) & (src[:, 0] <= 159) & (src[:, 1] >= 0) & (src[:, 1] <= 119)
    got = out[vv.ravel(), uu.ravel()]
    assert inside.sum() > 50
    assert np.abs(got[inside] - src[inside]).max() < 0.05


def test_undistort_image_keeps_single_channel_shapes_and_checks_size():
    out, _ = undistort_image(np.ones((120, 160, 1), np.uint8), DISTORTED)
    assert out.shape == (120, 160, 1)
    out, _ = undistort_image(np.ones((120, 160), np.uint16), DISTORTED)
    assert out.shape == (120, 160)
    assert out.dtype == np.uint16
    with pytest.raises(CameraError, match='image is 100x120, camera is 160x120'):
        undistort_image(np.ones((120, 100), np.uint8), DISTORTED)
