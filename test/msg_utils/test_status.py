# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.status: the view_renderer's reply status <-> diagnostic_msgs/DiagnosticArray."""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message, serialize_message

import msg_utils
from ibr_ros.core.render import ReplyPolicy

STATUSES = [
    ReplyPolicy(0.75).judge(0.9012345, ['1767225600000000000', '1767225602400000000'], 41.5),
    ReplyPolicy(0.75).judge(0.31),
    ReplyPolicy(0.75, publish_incomplete=True).judge(0.31, ['7']),
    ReplyPolicy(0.75).refuse('unrenderable', 'farther than 150 m from every view'),
]


@pytest.mark.parametrize('status', STATUSES, ids=lambda s: f'{s.result}-{s.reason}')
@pytest.mark.parametrize('flavor', ['rclpy', 'rosbags'])
def test_reply_status_round_trip(status, flavor):
    header = msg_utils.make_header(1_767_225_601_200_000_000, 'novel_view_optical', flavor=flavor)
    msg = msg_utils.reply_to_diagnostics(status, header, name='/view_renderer', flavor=flavor)
    assert msg_utils.is_rosbags_message(msg) == (flavor == 'rosbags')
    assert msg.header.frame_id == 'novel_view_optical'
    (st,) = msg.status
    assert st.name == '/view_renderer'
    assert st.message == status.message
    level = st.level[0] if flavor == 'rclpy' else st.level
    assert level == msg_utils.status.LEVELS[status.level]
    assert dict(msg_utils.status_to_pairs(st))['valid_fraction'] == repr(status.valid_fraction)
    assert msg_utils.diagnostics_to_reply(msg) == (1_767_225_601_200_000_000, status)
    if flavor == 'rclpy':  # and through CDR
        wire = deserialize_message(serialize_message(msg), DiagnosticArray)
        assert msg_utils.diagnostics_to_reply(wire) == (1_767_225_601_200_000_000, status)


def test_other_diagnostics_are_not_reply_statuses():
    status = STATUSES[0]
    empty = msg_utils.new_message('diagnostic_msgs/msg/DiagnosticArray', 'rclpy')
    with pytest.raises(msg_utils.MessageError, match='one DiagnosticStatus'):
        msg_utils.diagnostics_to_reply(empty)
    with pytest.raises(msg_utils.MessageError, match='one DiagnosticStatus'):
        msg_utils.diagnostics_to_reply(msg_utils.pairs_to_status('x', status.to_pairs()))
    other = msg_utils.reply_to_diagnostics(status, name='x')
    other.status = [msg_utils.pairs_to_status('x', [('frames', '3')])]
    with pytest.raises(msg_utils.MessageError, match='result missing'):
        msg_utils.diagnostics_to_reply(other)
    wrong_level = msg_utils.reply_to_diagnostics(status, name='x')
    wrong_level.status[0].level = b'\x02'  # ERROR for an answered view
    with pytest.raises(msg_utils.MessageError, match='level 2'):
        msg_utils.diagnostics_to_reply(wrong_level)


@pytest.mark.parametrize('flavor', ['rclpy', 'rosbags'])
def test_node_diagnostics_round_trip(flavor):
    from ibr_ros.core.diagnostics import NodeDiagnostics, Queue

    d = NodeDiagnostics(('image',), ('keyframes',), clock=lambda: 0.0)
    d.received('image', 0.5)
    areas = d.report(1.0, rejected={'pose': 2}, queues={'pending': Queue(1, 4)}, model={'keyframes': 0})
    header = msg_utils.make_header(1_767_225_601_000_000_000, flavor=flavor)
    msg = msg_utils.areas_to_diagnostics(
        areas, header, node='frame_subsampler', hardware_id='host', flavor=flavor
    )
    assert [s.name for s in msg.status] == [f'frame_subsampler: {a.area}' for a in areas]
    assert {s.hardware_id for s in msg.status} == {'host'}
    rejected = msg.status[2]
    assert (rejected.level[0] if flavor == 'rclpy' else rejected.level) == msg_utils.status.LEVELS['warn']
    assert msg_utils.diagnostics_to_areas(msg, 'frame_subsampler') == {a.area: a for a in areas}
    assert msg_utils.diagnostics_to_areas(msg, 'depth_refiner') == {}  # another node's statuses
    if flavor == 'rclpy':
        wire = deserialize_message(serialize_message(msg), DiagnosticArray)
        got = msg_utils.diagnostics_to_areas(wire, 'frame_subsampler')
        assert got['inputs'].value('image.count') == '1'
        assert got['rejected'].value('pose') == '2'
        wire.status[0].level = bytes([7])
        with pytest.raises(msg_utils.MessageError, match='frame_subsampler: inputs has level 7'):
            msg_utils.diagnostics_to_areas(wire, 'frame_subsampler')
    with pytest.raises(msg_utils.MessageError, match='not a DiagnosticArray'):
        msg_utils.diagnostics_to_areas(msg.status[0], 'frame_subsampler')
