# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.pose, msg_utils.navsat, msg_utils.flavor and ibr_ros.core.geometry.geodesy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message

from ibr_ros.core.geometry.geodesy import (
    WGS84_A,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)
from ibr_ros.core.geometry.transforms import GeometryError, look_at, matrix_from_rt, rotation_from_quaternion
from msg_utils import (
    GeoFix,
    MessageError,
    coerce_header,
    fix_to_navsatfix,
    is_rosbags_message,
    make_header,
    matrix_to_odometry,
    matrix_to_pose_stamped,
    matrix_to_transform_stamped,
    message_typename,
    navsatfix_to_fix,
    new_message,
    ns_to_stamp,
    odometry_to_matrix,
    pose_stamped_to_matrix,
    pose_to_matrix,
    stamp_to_ns,
    transform_stamped_to_matrix,
    typestore,
)

FLAVORS = ('rclpy', 'rosbags')
unit = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1)
translations = st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3)
stamps = st.integers(-(2**31) * 10**9, 2**31 * 10**9 - 1)

KINDS = {
    'PoseStamped': (
        lambda T, f, ns: matrix_to_pose_stamped(T, stamp_ns=ns, frame_id='map', flavor=f),
        pose_stamped_to_matrix,
    ),
    'TransformStamped': (
        lambda T, f, ns: matrix_to_transform_stamped(T, parent='map', child='cam', stamp_ns=ns, flavor=f),
        transform_stamped_to_matrix,
    ),
    'Odometry': (
        lambda T, f, ns: matrix_to_odometry(T, stamp_ns=ns, frame_id='map', child_frame_id='cam', flavor=f),
        odometry_to_matrix,
    ),
}


def assert_same_cdr(rclpy_msg, rosbags_msg) -> None:
    """Same CDR bytes from both flavours (rmw leaves alignment padding uninitialised)."""
    typename = message_typename(rclpy_msg)
    ts = typestore()
    raw_r, raw_b = bytes(serialize_message(rclpy_msg)), bytes(ts.serialize_cdr(rosbags_msg, typename))
    assert len(raw_r) == len(raw_b)
    assert bytes(ts.serialize_cdr(ts.deserialize_cdr(raw_r, typename), typename)) == raw_b
    assert all(raw_b[i] == 0 for i in range(len(raw_b)) if raw_b[i] != raw_r[i])
    assert deserialize_message(raw_b, type(rclpy_msg)) == rclpy_msg


@settings(max_examples=60, deadline=None)
@given(
    q=quaternions,
    t=translations,
    ns=stamps,
    kind=st.sampled_from(sorted(KINDS)),
    flavor=st.sampled_from(FLAVORS),
)
def test_pose_round_trip(q, t, ns, kind, flavor):
    T = matrix_from_rt(rotation_from_quaternion(q), t)
    to_msg, to_matrix = KINDS[kind]
    msg = to_msg(T, flavor, ns)
    assert is_rosbags_message(msg) == (flavor == 'rosbags')
    assert message_typename(msg).endswith('/' + kind)
    assert stamp_to_ns(msg.header.stamp) == ns
    assert msg.header.frame_id == 'map'
    assert np.abs(to_matrix(msg) - T).max() < 1e-9 * max(1.0, np.abs(t).max())


@settings(max_examples=15, deadline=None)
@given(q=quaternions, t=translations, ns=stamps, kind=st.sampled_from(sorted(KINDS)))
def test_flavours_serialize_to_identical_cdr(q, t, ns, kind):
    T = matrix_from_rt(rotation_from_quaternion(q), t)
    to_msg, _ = KINDS[kind]
    assert_same_cdr(to_msg(T, 'rclpy', ns), to_msg(T, 'rosbags', ns))


def test_written_quaternion_has_non_negative_w_and_frames():
    T = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    msg = matrix_to_transform_stamped(T, stamp_ns=1_500_000_000)
    assert msg.transform.rotation.w >= 0
    assert (msg.header.frame_id, msg.child_frame_id) == ('map', 'camera_optical')
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    assert matrix_to_odometry(T).child_frame_id == 'camera_optical'


@pytest.mark.parametrize('flavor', FLAVORS)
def test_non_unit_quaternion_is_normalised(flavor):
    msg = matrix_to_pose_stamped(np.eye(4), flavor=flavor)
    msg.pose.orientation.w = 3.0
    assert np.allclose(pose_stamped_to_matrix(msg), np.eye(4))


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize(
    ('kind', 'path', 'field'),
    [
        ('PoseStamped', 'pose.orientation', 'PoseStamped.pose.orientation'),
        ('TransformStamped', 'transform.rotation', 'TransformStamped.transform.rotation'),
        ('Odometry', 'pose.pose.orientation', 'Odometry.pose.pose.orientation'),
    ],
)
def test_zero_quaternion_names_field(kind, path, field, flavor):
    to_msg, to_matrix = KINDS[kind]
    msg = to_msg(np.eye(4), flavor, 0)
    q = msg
    for part in path.split('.'):
        q = getattr(q, part)
    q.x = q.y = q.z = q.w = 0.0
    with pytest.raises(MessageError, match=rf'{field} is a zero quaternion'):
        to_matrix(msg)
    q.w = math.nan
    with pytest.raises(MessageError, match=rf'{field} must be finite'):
        to_matrix(msg)


@pytest.mark.parametrize('value', [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(
    ('kind', 'path', 'field'),
    [
        ('PoseStamped', 'pose.position', 'PoseStamped.pose.position'),
        ('TransformStamped', 'transform.translation', 'TransformStamped.transform.translation'),
        ('Odometry', 'pose.pose.position', 'Odometry.pose.pose.position'),
    ],
)
def test_non_finite_position_names_field(kind, path, field, value):
    to_msg, to_matrix = KINDS[kind]
    msg = to_msg(np.eye(4), 'rclpy', 0)
    p = msg
    for part in path.split('.'):
        p = getattr(p, part)
    p.y = value
    with pytest.raises(MessageError, match=rf'{field} must be finite'):
        to_matrix(msg)


def test_pose_to_matrix_field_prefix():
    pose = new_message('geometry_msgs/msg/Pose', 'rosbags')  # rosbags default quaternion is all zero
    with pytest.raises(MessageError, match=r'Pose\.orientation is a zero quaternion'):
        pose_to_matrix(pose)


def test_non_rigid_matrix_is_refused():
    with pytest.raises(GeometryError, match='T rotation is not orthonormal'):
        matrix_to_pose_stamped(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(GeometryError, match='T must be finite'):
        matrix_to_odometry(np.full((4, 4), np.nan))


# -- stamps, headers, construction ---------------------------------------------------------------


@settings(max_examples=50, deadline=None)
@given(ns=stamps, flavor=st.sampled_from(FLAVORS))
def test_stamp_round_trip(ns, flavor):
    stamp = ns_to_stamp(ns, flavor)
    assert 0 <= stamp.nanosec < 10**9
    assert stamp_to_ns(stamp) == ns


@pytest.mark.parametrize('ns', [2**31 * 10**9, -(2**31) * 10**9 - 1])
def test_stamp_out_of_int32_range(ns):
    with pytest.raises(MessageError, match='does not fit builtin_interfaces/Time'):
        ns_to_stamp(ns)


def test_headers_and_flavour_conversion():
    header = make_header(-1, 'map', 'rosbags')
    assert is_rosbags_message(header)
    assert (header.stamp.sec, header.stamp.nanosec) == (-1, 999_999_999)
    as_rclpy = coerce_header(header, 'rclpy')
    assert not is_rosbags_message(as_rclpy)
    assert (stamp_to_ns(as_rclpy.stamp), as_rclpy.frame_id) == (-1, 'map')
    assert coerce_header(header, 'rosbags') is header
    assert stamp_to_ns(coerce_header(None, 'rosbags').stamp) == 0


def test_new_message_errors():
    with pytest.raises(MessageError, match=r"sensor_msgs/msg/Image has no field\(s\) \['colour'\]"):
        new_message('sensor_msgs/msg/Image', 'rosbags', colour=1)
    with pytest.raises(MessageError, match=r"has no field\(s\) \['colour'\]"):
        new_message('sensor_msgs/msg/Image', 'rclpy', colour=1)
    with pytest.raises(MessageError, match="'package/msg/Name'"):
        new_message('Image')
    with pytest.raises(MessageError, match='not known to rosbags'):
        new_message('nope_msgs/msg/Nope', 'rosbags')
    with pytest.raises(ValueError, match='flavor must be'):
        new_message('std_msgs/msg/Header', 'ros1')


# -- NavSatFix ---------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    lat=st.floats(-90, 90),
    lon=st.floats(-180, 180),
    alt=st.floats(-500, 9000) | st.just(math.nan),
    ns=stamps,
    status=st.integers(-2, 2),
    cov=st.lists(st.floats(0, 100), min_size=9, max_size=9),
    flavor=st.sampled_from(FLAVORS),
)
def test_navsatfix_round_trip(lat, lon, alt, ns, status, cov, flavor):
    fix = GeoFix(ns, 'gps', lat, lon, alt, status, np.reshape(cov, (3, 3)), 2, service=1)
    msg = fix_to_navsatfix(fix, flavor=flavor)
    assert is_rosbags_message(msg) == (flavor == 'rosbags')
    assert navsatfix_to_fix(msg) == fix


def test_navsatfix_cdr_matches():
    fix = GeoFix(123, 'gps', 48.1, 11.5, 520.0, 0, np.diag([1.0, 2.0, 3.0]), 2)
    assert_same_cdr(fix_to_navsatfix(fix), fix_to_navsatfix(fix, flavor='rosbags'))


@pytest.mark.parametrize(
    ('field', 'value', 'match'),
    [
        ('latitude', math.nan, r'NavSatFix\.latitude nan'),
        ('latitude', 91.0, r'NavSatFix\.latitude 91\.0'),
        ('longitude', math.nan, r'NavSatFix\.longitude nan'),
        ('longitude', math.inf, r'NavSatFix\.longitude inf'),
    ],
)
def test_navsatfix_bad_position(field, value, match):
    msg = fix_to_navsatfix(GeoFix(0, 'gps', 1.0, 2.0, 3.0))
    setattr(msg, field, value)
    with pytest.raises(MessageError, match=match):
        navsatfix_to_fix(msg)


# -- geodesy -----------------------------------------------------------------------------------


def test_known_geodetic_values():
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), (WGS84_A, 0.0, 0.0))
    assert np.allclose(geodetic_to_ecef(90.0, 0.0, 0.0), (0.0, 0.0, 6356752.314245), atol=1e-6)
    assert np.allclose(ecef_to_geodetic(0.0, 0.0, 6356752.314245 + 10.0), (90.0, 0.0, 10.0), atol=1e-6)
    origin = (48.1, 11.5, 520.0)
    assert np.allclose(geodetic_to_enu(*origin, origin), 0.0, atol=1e-9)
    e, n, u = geodetic_to_enu(48.1 + 1e-3, 11.5, 520.0, origin)
    assert abs(e) < 1e-6
    assert n == pytest.approx(111.2, abs=0.1)  # one milli-degree of latitude, about 111.2 m
    assert u == pytest.approx(-n * n / (2 * 6.37e6), abs=1e-4)  # curvature drop
    e, n, u = geodetic_to_enu(48.1, 11.5 + 1e-3, 520.0, origin)
    assert e == pytest.approx(111.32 * math.cos(math.radians(48.1)), rel=5e-3)


@settings(max_examples=30, deadline=None)
@given(
    origin=st.tuples(st.floats(-89.9, 89.9), st.floats(-180, 180), st.floats(-100, 3000)),
    offsets=st.lists(st.tuples(*[st.floats(-5e4, 5e4)] * 3), min_size=1, max_size=20),
)
def test_enu_geodetic_round_trip(origin, offsets):
    e, n, u = np.array(offsets).T
    lat, lon, alt = enu_to_geodetic(e, n, u, origin)
    assert lat.shape == e.shape
    back = np.array(geodetic_to_enu(lat, lon, alt, origin))
    assert np.abs(back - np.array([e, n, u])).max() < 1e-6


def test_geodesy_rejects_bad_latitude():
    with pytest.raises(ValueError, match='latitude'):
        geodetic_to_ecef(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match='origin latitude'):
        geodetic_to_enu(0.0, 0.0, 0.0, (math.nan, 0.0, 0.0))
