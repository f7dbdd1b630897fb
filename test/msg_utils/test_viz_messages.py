# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Viewer messages: PointCloud2 (xyz + packed rgb), LINE_LIST markers, PoseArray, TFMessage."""

from __future__ import annotations

import numpy as np
import pytest

import msg_utils
from ibr_ros.bag.typestore import TYPESTORE, serialize
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.viz import frustum_segments

FLAVORS = ('rclpy', 'rosbags')


def _cloud(n: int = 50, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(0, 10, (n, 3)).astype(np.float32), rng.integers(0, 256, (n, 3), dtype=np.uint8)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_cloud_round_trip_and_layout_as_rviz_reads_it(flavor):
    xyz, rgb = _cloud()
    header = msg_utils.make_header(7, 'map', flavor)
    msg = msg_utils.points_to_cloud(xyz, rgb, header, flavor=flavor)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 50, 16, 800)
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1), ('rgb', 12, 7, 1)
    ]  # fmt: skip
    assert not msg.is_bigendian
    assert msg.is_dense
    assert msg.header.frame_id == 'map'
    back_xyz, back_rgb = msg_utils.cloud_to_points(msg)
    np.testing.assert_array_equal(back_xyz, xyz)
    np.testing.assert_array_equal(back_rgb, rgb)
    # RViz's RGB8 transformer and Foxglove read the float's bits as a little-endian 0x00RRGGBB.
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(50, 16)
    packed = data[:, 12:16].copy().view('<u4').ravel()
    np.testing.assert_array_equal(packed >> 24, 0)
    np.testing.assert_array_equal((packed >> 16) & 255, rgb[:, 0])
    np.testing.assert_array_equal(packed & 255, rgb[:, 2])
    msgtype, cdr = serialize(msg)
    assert msgtype == 'sensor_msgs/msg/PointCloud2'
    again = TYPESTORE.deserialize_cdr(cdr, msgtype)
    np.testing.assert_array_equal(msg_utils.cloud_to_points(again)[0], xyz)


def test_bad_clouds_are_message_errors():
    xyz, rgb = _cloud(4)
    with pytest.raises(msg_utils.MessageError, match='Nx3'):
        msg_utils.points_to_cloud(xyz[:, :2], rgb)
    with pytest.raises(msg_utils.MessageError, match='uint8'):
        msg_utils.points_to_cloud(xyz, rgb.astype(np.int32))
    xyz[0, 0] = np.nan
    with pytest.raises(msg_utils.MessageError, match='finite'):
        msg_utils.points_to_cloud(xyz, rgb)
    msg = msg_utils.points_to_cloud(np.zeros((2, 3), np.float32), rgb[:2])
    msg.fields = msg.fields[:3]
    with pytest.raises(msg_utils.MessageError, match="field 'rgb'"):
        msg_utils.cloud_to_points(msg)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_frustum_markers_are_valid_line_lists(flavor):
    cam = PinholeCamera.from_fov(64, 36, 60.0)
    t_wc = look_at([5.0, 0.0, 3.0], [0.0, 0.0, 0.0])
    seg = frustum_segments(cam, t_wc, 1.5)
    header = msg_utils.make_header(9, 'map', flavor)
    frustums = [('keyframes', 0, seg, (0.2, 0.6, 1.0, 1.0)), ('novel_view', 0, seg, (1.0, 0.5, 0.0, 1.0))]
    arr = msg_utils.frustums_to_marker_array(frustums, header, width=0.03, flavor=flavor)
    assert len(arr.markers) == 2
    for m, (ns, i, _, rgba) in zip(arr.markers, frustums):
        assert (m.ns, m.id, m.type, m.action) == (ns, i, 5, 0)  # LINE_LIST, ADD
        assert m.header.frame_id == 'map'
        assert msg_utils.stamp_to_ns(m.header.stamp) == 9
        assert len(m.points) == 2 * len(seg)
        assert m.scale.x == 0.03
        assert (m.color.r, m.color.g, m.color.b, m.color.a) == pytest.approx(rgba)
        q = m.pose.orientation
        assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)  # identity: points are in the header frame
        np.testing.assert_allclose([[p.x, p.y, p.z] for p in m.points], seg.reshape(-1, 3))
    assert serialize(arr)[0] == 'visualization_msgs/msg/MarkerArray'
    with pytest.raises(msg_utils.MessageError, match='segments'):
        msg_utils.segments_to_marker(np.zeros((3, 3)), ns='k', marker_id=0)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_pose_array(flavor):
    poses = [look_at([float(i), 2.0, 3.0], [0.0, 0.0, 0.0]) for i in range(3)]
    msg = msg_utils.matrices_to_pose_array(poses, msg_utils.make_header(1, 'map', flavor), flavor=flavor)
    assert len(msg.poses) == 3
    assert msg.header.frame_id == 'map'
    for p, t in zip(msg.poses, poses):
        np.testing.assert_allclose(msg_utils.pose_to_matrix(p), t, atol=1e-12)


def test_tf_messages_for_bags_and_for_rclpy_where_tf2_msgs_is_installed():
    t_wc = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    msg = msg_utils.transforms_to_tf([(5, 'map', 'cam', t_wc)], flavor='rosbags')
    (tf,) = msg.transforms
    assert (tf.header.frame_id, tf.child_frame_id, msg_utils.stamp_to_ns(tf.header.stamp)) == (
        'map',
        'cam',
        5,
    )
    np.testing.assert_allclose(msg_utils.transform_stamped_to_matrix(tf), t_wc, atol=1e-12)
    assert serialize(msg)[0] == 'tf2_msgs/msg/TFMessage'
    if msg_utils.tf_available():  # a ROS 2 install
        assert len(msg_utils.transforms_to_tf([(5, 'map', 'cam', t_wc)]).transforms) == 1
    else:  # PyPI: no tf2_msgs wheel; the error says so
        with pytest.raises(msg_utils.MessageError, match='tf2_msgs is not installed'):
            msg_utils.transforms_to_tf([(5, 'map', 'cam', t_wc)])
