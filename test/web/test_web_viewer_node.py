# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The web_viewer node's ROS side over DDS: keyframe poses in, queries out, /diagnostics true."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from node_harness import in_process
from sensor_msgs.msg import Image

import msg_utils
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.navigation import Query
from ibr_ros.core.render import ReplyStatus
from ibr_ros.nodes.common import model_qos, reliable_qos

pytestmark = pytest.mark.dds

T0 = 1_767_225_600_000_000_000


def test_web_viewer_queries_and_reports_its_diagnostics():
    """Two keyframe poses and a NaN one; one query published and its view and status received."""
    from ibr_ros.nodes.web_viewer import WebViewer

    with in_process(WebViewer, feeder='web_feeder', port=0, diagnostics_period_s=0.1) as h:
        node = h.node
        diag = h.collect(DiagnosticArray, '/diagnostics', reliable_qos(100))
        queries = h.collect(PoseStamped, 'novel_view/query', reliable_qos(100))
        pubs = h.publishers({
            'pose': (PoseStamped, 'keyframes/pose', model_qos()),
            'image': (Image, 'novel_view/image', reliable_qos()),
            'status': (DiagnosticArray, 'novel_view/status', reliable_qos(100)),
        })  # fmt: skip
        for i in range(2):
            pose = look_at([10.0 * i, 0.0, 30.0], [10.0 * i, 5.0, 0.0])
            h.send(pubs['pose'], msg_utils.matrix_to_pose_stamped(pose, stamp_ns=T0 + i, frame_id='map'))
        bad = msg_utils.matrix_to_pose_stamped(np.eye(4), stamp_ns=T0 + 2, frame_id='map')
        bad.pose.position.x = float('nan')
        h.send(pubs['pose'], bad)
        stamp = T0 + 10**9
        node._publish(Query(stamp, look_at([5.0, 0.0, 30.0], [5.0, 5.0, 0.0]), 1))  # as a page would
        assert h.wait(lambda: len(queries) == 1, 30)
        (q,) = queries
        assert msg_utils.stamp_to_ns(q.header.stamp) == stamp
        assert q.header.frame_id == 'map'
        header = msg_utils.make_header(stamp, 'novel_view_optical')
        h.send(pubs['image'], msg_utils.numpy_to_image(np.zeros((36, 64, 3), np.uint8), 'rgb8', header))
        status = ReplyStatus('answered', '', 1.0, 0.7, 'ok', ('1',), 12.5)
        h.send(pubs['status'], msg_utils.reply_to_diagnostics(status, header, name='view_renderer'))

        def settled() -> dict | None:
            for msg in reversed(list(diag)):
                areas = msg_utils.diagnostics_to_areas(msg, 'web_viewer')
                ins = dict(areas['inputs'].values) if areas else {}
                fed = ins.get('pose.count') == '3' and ins.get('status.count') == '1'
                if fed and dict(areas['outputs'].values).get('view.count') == '1':
                    return areas
            return None

        assert h.wait(lambda: settled() is not None, 30), diag[-1:]
        areas = settled()
    assert dict(areas['inputs'].values)['image.count'] == '1'
    out = dict(areas['outputs'].values)
    assert (out['query.count'], out['view.count'], out['latency.count']) == ('1', '1', '1')
    assert dict(areas['rejected'].values) == {'total': '1', 'pose': '1'}
    model = dict(areas['model'].values)
    assert (model['keyframes'], model['pages'], model['lost']) == ('2', '0', '0')
