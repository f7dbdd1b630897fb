# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The scene_viz node over DDS: the model topics in, viewer topics out; a late-joining viewer gets
the whole reconstruction (transient local)."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
from node_harness import in_process
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import MarkerArray

import msg_utils
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.viz import keyframe_points
from ibr_ros.node_config import SCENE_VIZ
from ibr_ros.nodes.common import latched_qos, model_qos, reliable_qos

pytestmark = pytest.mark.dds

W, H = 96, 54
T0 = 1_767_225_600_000_000_000


def _keyframes(n: int = 3) -> list[dict]:
    """``n`` synthetic keyframes around a tilted ground plane: rgb, depth, confidence, camera, pose."""
    rng = np.random.default_rng(3)
    cam = PinholeCamera.from_fov(W, H, 70.0)
    out = []
    for i in range(n):
        v, u = np.mgrid[0:H, 0:W]
        depth = (30.0 + 0.05 * u + 0.1 * v + i).astype(np.float32)
        depth[:5] = np.inf  # sky
        depth[20:24, 30:50] = np.nan  # unknown
        conf = np.where(u < 10, 0.1, 0.9).astype(np.float32)
        out.append({
            'stamp': T0 + i * 500_000_000,
            'rgb': rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
            'depth': depth,
            'conf': conf,
            'cam': cam,
            'pose': look_at([20.0 * np.cos(i), 20.0 * np.sin(i), 25.0], [0.0, 0.0, 0.0]),
        })  # fmt: skip
    return out


def test_scene_viz_publishes_the_model_and_a_late_viewer_gets_all_of_it():
    from ibr_ros.nodes.scene_viz import SceneViz

    kfs = _keyframes()
    cfg = SCENE_VIZ.config({})
    model, req = model_qos(), reliable_qos()
    with in_process(SceneViz, feeder='viz_feeder', diagnostics_period_s=0.1) as h:
        node = h.node
        diag = h.collect(DiagnosticArray, '/diagnostics', reliable_qos(100))
        pubs = h.publishers({
            'pose': (PoseStamped, 'keyframes/pose', model),
            'info': (CameraInfo, 'keyframes/camera_info', model),
            'image': (Image, 'keyframes/image', model),
            'depth': (Image, 'keyframes/depth', model),
            'conf': (Image, 'keyframes/depth/confidence', model),
            'query': (PoseStamped, 'novel_view/query', req),
            'view_info': (CameraInfo, 'novel_view/camera_info', req),
            'camera_pose': (PoseStamped, 'camera/pose', req),
        })  # fmt: skip
        for k in kfs:
            header = msg_utils.make_header(k['stamp'], 'camera_optical')
            h.send(pubs['pose'], msg_utils.matrix_to_pose_stamped(k['pose'], stamp_ns=k['stamp']))
            h.send(pubs['info'], msg_utils.pinhole_to_camera_info(k['cam'], header))
            h.send(pubs['image'], msg_utils.numpy_to_image(k['rgb'], 'rgb8', header))
            h.send(pubs['conf'], msg_utils.confidence_to_image(k['conf'], header))
            h.send(pubs['depth'], msg_utils.depth_m_to_image(k['depth'], header))
        assert node.clouds == 3
        h.send(
            pubs['depth'],
            msg_utils.depth_m_to_image(kfs[0]['depth'], header=msg_utils.make_header(kfs[0]['stamp'])),
        )
        assert node.clouds == 3  # a mirror's copy of a depth the model has: nothing new
        bad_header = msg_utils.make_header(kfs[1]['stamp'])
        h.send(pubs['depth'], msg_utils.depth_m_to_image(np.ones((10, 10), np.float32), bad_header))
        assert node.bad.counts['size'] == 1  # counted and logged, the node goes on
        h.send(pubs['depth'], msg_utils.depth_m_to_image(kfs[1]['depth'], bad_header))  # the good one again
        assert node.clouds == 4
        # A novel view: its query, then the view_renderer's camera_info with the query's stamp.
        q_stamp, q_pose = T0 + 700_000_000, look_at([5.0, 5.0, 20.0], [0.0, 0.0, 0.0])
        view_cam = PinholeCamera.from_fov(64, 36, 60.0)
        h.send(pubs['query'], msg_utils.matrix_to_pose_stamped(q_pose, stamp_ns=q_stamp))
        h.send(pubs['view_info'], msg_utils.pinhole_to_camera_info(view_cam, msg_utils.make_header(q_stamp)))
        h.send(pubs['camera_pose'], msg_utils.matrix_to_pose_stamped(kfs[2]['pose'], stamp_ns=q_stamp))
        assert dict(node.bad.counts) == {'size': 1}
        # A viewer joining now gets the whole reconstruction.
        clouds = h.collect(PointCloud2, 'keyframes/points', model_qos())
        poses = h.collect(PoseArray, 'keyframes/poses', latched_qos())
        frustums = h.collect(MarkerArray, 'keyframes/frustums', latched_qos())
        assert h.wait(lambda: len(clouds) == 4 and poses and frustums, 30), (len(clouds), poses, frustums)
        want = {'depth.count': '6', 'image.count': '3', 'query.count': '1', 'view_info.count': '1'}

        def report() -> dict | None:  # the newest report that counted every message sent above
            for msg in reversed(list(diag)):
                areas = msg_utils.diagnostics_to_areas(msg, 'scene_viz')
                fed = areas and want.items() <= dict(areas['inputs'].values).items()
                if fed and dict(areas['outputs'].values).get('points.count') == '4':
                    return areas
            return None

        assert h.wait(lambda: report() is not None, 30), diag[-1:]
        areas = report()
        tf_publishers = (node.pub_tf, node.pub_tf_static)
        if msg_utils.tf_available():  # a ROS 2 install, or tf2_msgs built by `make install`
            from tf2_msgs.msg import TFMessage

            static = h.collect(TFMessage, '/tf_static', latched_qos())
            assert h.wait(lambda: static, 30)
            dynamic = h.collect(TFMessage, '/tf', reliable_qos(100))
            h.send(
                pubs['camera_pose'], msg_utils.matrix_to_pose_stamped(kfs[1]['pose'], stamp_ns=q_stamp + 1)
            )
            assert h.wait(lambda: dynamic, 30)
    if msg_utils.tf_available():
        (st,) = static  # latched: the latest, every keyframe
        tree = {
            t.child_frame_id: (t.header.frame_id, msg_utils.transform_stamped_to_matrix(t))
            for t in st.transforms
        }
        for k in kfs:
            parent, t = tree[f'keyframe_{k["stamp"]}_optical_frame']
            assert parent == 'map'
            np.testing.assert_allclose(t, k['pose'], atol=1e-9)
        (dy,) = dynamic
        chain = {
            t.child_frame_id: (t.header.frame_id, msg_utils.transform_stamped_to_matrix(t))
            for t in dy.transforms
        }
        assert chain['camera_optical_frame'][0] == 'camera_link'
        assert chain['camera_link'][0] == 'map'
        np.testing.assert_allclose(
            chain['camera_link'][1] @ chain['camera_optical_frame'][1], kfs[1]['pose'], atol=1e-9
        )
    else:  # PyPI without the built tf2_msgs: the node says so at start-up and publishes the rest
        assert tf_publishers == (None, None)
    assert dict(areas['rejected'].values) == {'total': '1', 'size': '1'}
    model = dict(areas['model'].values)
    assert (model['keyframes'], model['posed'], model['clouds']) == ('3', '3', '4')
    assert model['tf'] == ('on' if msg_utils.tf_available() else 'off')
    assert dict(areas['outputs'].values)['latency.count'] == '4'
    by_stamp = {msg_utils.stamp_to_ns(c.header.stamp): c for c in clouds}  # the latest per keyframe
    assert sorted(by_stamp) == [k['stamp'] for k in kfs]
    for k in kfs:
        xyz, rgb = msg_utils.cloud_to_points(by_stamp[k['stamp']])
        want = keyframe_points(k['depth'], k['rgb'], k['cam'], k['pose'], k['conf'], cfg.viz.cloud)
        np.testing.assert_array_equal(xyz, want[0])
        np.testing.assert_array_equal(rgb, want[1])
        u, v, z = k['cam'].pixels_of(xyz, k['pose'])
        np.testing.assert_allclose(z, k['depth'][v, u], rtol=1e-4)
        assert (u >= 10).all()  # the low-confidence columns are left out
    (pa,) = poses
    assert pa.header.frame_id == 'map'
    for p, k in zip(pa.poses, kfs):
        np.testing.assert_allclose(msg_utils.pose_to_matrix(p), k['pose'], atol=1e-9)
    (ma,) = frustums
    assert [(m.ns, m.id) for m in ma.markers] == [
        ('keyframes', 0),
        ('keyframes', 1),
        ('keyframes', 2),
        ('novel_view', 0),
    ]
    novel = ma.markers[-1]
    np.testing.assert_allclose([novel.points[0].x, novel.points[0].y, novel.points[0].z], q_pose[:3, 3])
