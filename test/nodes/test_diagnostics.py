# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``/diagnostics`` of every node, received over DDS: the values are the truth of what was fed.

frame_subsampler, depth_refiner and view_renderer run in this process (node_harness: each message
is handed over once the previous one was handled); bag_player runs as its own process. Each gets
known inputs including bad ones and the test waits (on the data, with ``diagnostics_period_s`` 0.1)
for a report whose input counts are those sent, then checks the rejections per reason, the output
counts and latency samples against what came out, the queues and the model size; every key reported is
documented in the node's parameter table (``doc/nodes.md``).
"""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from node_harness import (
    image_msg,
    in_process,
    info_msg,
    keyframe_topics,
    pose_msg,
    shipped_frames,
    spin_until,
)
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

import msg_utils
from ibr_ros.bag import BagWriter
from ibr_ros.core.diagnostics import AREAS, AreaStatus
from ibr_ros.node_config import TABLES
from ibr_ros.nodes.common import latched_qos, model_qos, reliable_qos

pytestmark = pytest.mark.dds

LATCHED = model_qos()
DIAG_QOS = QoSProfile(depth=100, reliability=QoSReliabilityPolicy.RELIABLE)
PERIOD = {'diagnostics_period_s': 0.1}


def _areas(
    box: list, node: str, cond: Callable[[dict[str, AreaStatus]], bool]
) -> dict[str, AreaStatus] | None:
    """The newest report of ``node`` in ``box`` (DiagnosticArray messages) for which ``cond`` holds."""
    for msg in reversed(list(box)):
        areas = msg_utils.diagnostics_to_areas(msg, node)
        if areas and cond(areas):
            return areas
    return None


def _counts(areas: dict[str, AreaStatus], area: str) -> dict[str, str]:
    return dict(areas[area].values)


def _documented(node: str, areas: dict[str, AreaStatus]) -> None:
    """Every area is there and every key reported is one the node's table documents."""
    assert sorted(areas) == sorted(AREAS)
    keys = TABLES[node].diagnostics.keys()
    for area, status in areas.items():
        for key, _ in status.values:
            documented = key in keys[area] or any(
                k.startswith('<') and key.endswith(k.split('>', 1)[1]) for k in keys[area]
            )
            prefixed = any(
                k.endswith('.<reason>') and key.startswith(k[: -len('<reason>')]) for k in keys[area]
            )
            assert documented or prefixed, f'{node}: {area} key {key!r} is not documented'


def _assert_named(box: list, node: str) -> None:
    msg = box[-1]
    mine = [s for s in msg.status if s.name.startswith(f'{node}: ')]
    assert [s.name for s in mine] == [f'{node}: {a}' for a in AREAS]
    assert {s.hardware_id for s in mine} == {socket.gethostname()}


def test_frame_subsampler_diagnostics(repo):
    from ibr_ros.nodes.frame_subsampler import FrameSubsampler

    frames = shipped_frames(repo, range(0, 40, 4), (320, 180))
    n = len(frames)
    qos = reliable_qos(100)
    with in_process(
        FrameSubsampler, repo / 'config' / 'frame_subsampler.yaml', scene_depth_m=20.0, **PERIOD
    ) as h:
        diag = h.collect(DiagnosticArray, '/diagnostics', DIAG_QOS)
        got = h.collect(Image, 'keyframes/image', LATCHED)
        flight = h.collect(DiagnosticStatus, 'keyframes/status', latched_qos())
        pubs = h.publishers({
            'image': (Image, 'camera/image_raw', qos),
            'info': (CameraInfo, 'camera/camera_info', qos),
            'pose': (PoseStamped, 'camera/pose', qos),
        })  # fmt: skip
        for k, f in enumerate(frames):
            if k == 3:  # a NaN pose of its own stamp: rejected, reason pose
                bad = pose_msg(f['pose'], f['stamp'] + 1)
                bad.pose.position.x = float('nan')
                h.send(pubs['pose'], bad)
            h.send(pubs['info'], info_msg(f['camera'], f['stamp']))
            h.send(pubs['pose'], pose_msg(f['pose'], f['stamp']))
            h.send(pubs['image'], image_msg(f['rgb'], f['stamp']))
        want = {'image.count': str(n), 'camera_info.count': str(n), 'pose.count': str(n + 1)}

        def fed(a: dict[str, AreaStatus]) -> bool:
            return want.items() <= _counts(a, 'inputs').items()

        assert h.wait(lambda: _areas(diag, 'frame_subsampler', fed) is not None, 60)
        areas = _areas(diag, 'frame_subsampler', fed)
        keyframes = int(areas['model'].value('keyframes'))
        assert h.wait(lambda: len(got) >= keyframes, 30)
        assert h.wait(lambda: flight and dict(msg_utils.status_to_pairs(flight[-1]))['frames'] == str(n), 30)
        _assert_named(diag, 'frame_subsampler')
    assert keyframes == len(got) >= 2
    assert dict(msg_utils.status_to_pairs(flight[-1]))['keyframes'] == str(keyframes)
    assert _counts(areas, 'rejected') == {'total': '1', 'pose': '1'}
    assert areas['rejected'].level in ('ok', 'warn')
    out = _counts(areas, 'outputs')
    assert out['keyframes.count'] == out['latency.count'] == str(keyframes)  # every keyframe's latency
    assert float(out['latency_ms.max']) >= float(out['latency_ms.median']) >= 0
    assert float(_counts(areas, 'inputs')['image.rate_hz']) > 0
    shipped = TABLES['frame_subsampler'].defaults()
    assert _counts(areas, 'queues') == {
        'pending_frames': '0', 'pending_frames.bound': str(shipped['max_pending']),
        'pending_bytes': '0', 'pending_bytes.bound': str(round(shipped['max_pending_mb'] * 2**20)),
    }  # fmt: skip
    assert _counts(areas, 'model') == {
        'frames': str(n), 'keyframes': str(keyframes), 'pose_source': 'pose', 'camera': 'streaming',
    }  # fmt: skip
    _documented('frame_subsampler', areas)


def test_depth_refiner_diagnostics(repo):
    """Keyframes (one with a camera_info of another size) and no refinement (min_neighbours 16): the
    keyframes held, their bytes, the unrefined queue and the rejection."""
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    frames = shipped_frames(repo, (0, 24, 48, 72), (320, 180))
    params = {'min_neighbours': 16, 'max_neighbours': 16, 'warmup': False, **PERIOD}
    with in_process(DepthRefinerNode, repo / 'config' / 'depth_refiner.yaml', **params) as h:
        diag = h.collect(DiagnosticArray, '/diagnostics', DIAG_QOS)
        pubs = h.publishers(keyframe_topics(LATCHED))
        for k, f in enumerate(frames):
            cam = f['camera'].scaled(0.5, 0.5) if k == 2 else f['camera']  # 160x90 for a 320x180 image
            h.send(pubs['info'], info_msg(cam, f['stamp']))
            h.send(pubs['pose'], pose_msg(f['pose'], f['stamp']))
            h.send(pubs['image'], image_msg(f['rgb'], f['stamp']))
        want = {f'{s}.count': str(len(frames)) for s in ('image', 'camera_info', 'pose')}

        def fed(a: dict[str, AreaStatus]) -> bool:
            return want.items() <= _counts(a, 'inputs').items()

        assert h.wait(lambda: _areas(diag, 'depth_refiner', fed) is not None, 60)
        areas = _areas(diag, 'depth_refiner', fed)
        _assert_named(diag, 'depth_refiner')
    assert _counts(areas, 'rejected') == {'total': '1', 'camera_info': '1'}
    kept = len(frames) - 1
    model = _counts(areas, 'model')
    assert model['keyframes'] == str(kept)
    assert model['refined'] == '0'
    assert model['published'] == '0'
    assert model['bytes'] == str(kept * 320 * 180 * 3)
    queues = _counts(areas, 'queues')
    assert queues['unrefined'] == str(kept)
    assert queues['pending_keyframes'] == '0'
    out = _counts(areas, 'outputs')
    assert out['depth.count'] == out['latency.count'] == '0'
    _documented('depth_refiner', areas)


def test_depth_refiner_diagnostics_of_its_refinements(repo):
    """3 keyframes refined: the depth count and latency samples are the depth messages that came out."""
    from ibr_ros.core.flight.status import FlightStatus
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    frames = shipped_frames(repo, (0, 24, 48), (320, 180))
    params = {'max_neighbours': 2, 'warmup': False, **PERIOD}
    with in_process(DepthRefinerNode, repo / 'config' / 'depth_refiner.yaml', **params) as h:
        diag = h.collect(DiagnosticArray, '/diagnostics', DIAG_QOS)
        depths = h.collect(Image, 'keyframes/depth', LATCHED)
        pubs = h.publishers(keyframe_topics(LATCHED))
        status = h.publishers({'status': (DiagnosticStatus, 'keyframes/status', latched_qos())})['status']
        for f in frames:
            h.send(pubs['info'], info_msg(f['camera'], f['stamp']))
            h.send(pubs['pose'], pose_msg(f['pose'], f['stamp']))
            h.send(pubs['image'], image_msg(f['rgb'], f['stamp']))
        ended = FlightStatus(pose_source='pose', camera='ended', frames=3, keyframes=3)
        h.send(status, msg_utils.pairs_to_status('/frame_subsampler', ended.to_pairs()))

        def refined(a: dict[str, AreaStatus]) -> bool:  # the worker marks a job done after its depth went
            n = str(len(frames))
            return _counts(a, 'outputs')['depth.count'] == n and _counts(a, 'model')['refined'] == n

        assert h.wait(lambda: _areas(diag, 'depth_refiner', refined) is not None, 300), h.node.bad.counts
        areas = _areas(diag, 'depth_refiner', refined)
        assert h.wait(lambda: len(depths) >= len(frames), 30)
    assert len(depths) == len(frames)
    out = _counts(areas, 'outputs')
    assert out['latency.count'] == str(len(frames))
    assert float(out['latency_ms.max']) >= float(out['latency_ms.median']) > 0
    assert (out['mirrored.count'], out['sfm_pose.count']) == ('0', '0')
    model = _counts(areas, 'model')
    assert (model['keyframes'], model['refined'], model['published']) == ('3', '3', '3')
    assert _counts(areas, 'queues')['unrefined'] == '0'
    assert _counts(areas, 'rejected') == {'total': '0'}
    assert areas['rejected'].level == 'ok'
    _documented('depth_refiner', areas)


def test_view_renderer_diagnostics(repo):
    """4 keyframes, a depth without a known value, a query answered and one with a NaN position."""
    from ibr_ros.nodes.view_renderer import ViewRenderer

    frames = shipped_frames(repo, (0, 24, 48, 72), (320, 180))
    params = {'warmup': False, 'n_segments': 400, **PERIOD}
    with in_process(ViewRenderer, repo / 'config' / 'view_renderer.yaml', **params) as h:
        diag = h.collect(DiagnosticArray, '/diagnostics', DIAG_QOS)
        replies = h.collect(Image, 'novel_view/image', reliable_qos(100))
        pubs = h.publishers({**keyframe_topics(LATCHED), 'depth': (Image, 'keyframes/depth', LATCHED)})
        for f in frames:
            header = msg_utils.make_header(f['stamp'], 'c')
            h.send(pubs['image'], image_msg(f['rgb'], f['stamp']))
            h.send(pubs['info'], info_msg(f['camera'], f['stamp']))
            h.send(pubs['pose'], pose_msg(f['pose'], f['stamp']))
            h.send(pubs['depth'], msg_utils.depth_m_to_image(f['gt'], header))
        nan = np.full_like(frames[1]['gt'], np.nan)
        h.send(pubs['depth'], msg_utils.depth_m_to_image(nan, msg_utils.make_header(frames[1]['stamp'], 'c')))
        query = h.publishers({'q': (PoseStamped, 'novel_view/query', reliable_qos(100))})['q']
        h.send(query, pose_msg(frames[1]['pose'], 10**9))
        bad = pose_msg(frames[1]['pose'], 10**9 + 1)
        bad.pose.position.y = float('nan')
        h.send(query, bad)
        want = {'depth.count': '5', 'image.count': '4', 'query.count': '2'}

        def fed(a: dict[str, AreaStatus]) -> bool:  # inputs are counted before the render ends
            out = _counts(a, 'outputs')
            settled = out.get('status.count') == '2' and _counts(a, 'rejected').get('total') == '2'
            return want.items() <= _counts(a, 'inputs').items() and settled

        assert h.wait(lambda: _areas(diag, 'view_renderer', fed) is not None, 60)
        areas = _areas(diag, 'view_renderer', fed)
        assert h.wait(lambda: len(replies) >= 1, 30)
        _assert_named(diag, 'view_renderer')
    assert _counts(areas, 'rejected') == {'total': '2', 'depth_unknown': '1', 'query.invalid_query': '1'}
    out = _counts(areas, 'outputs')
    assert (out['image.count'], out['status.count'], out['latency.count']) == ('1', '2', '1')
    assert len(replies) == 1
    model = _counts(areas, 'model')
    assert (model['keyframes'], model['max_keyframes'], model['usable']) == ('4', '1000', '4')
    assert model['bytes'] == str(4 * 320 * 180 * (3 + 4))  # rgb8 and float32 depth
    _documented('view_renderer', areas)


def test_bag_player_diagnostics(ros_env, tmp_path):
    """5 poses and 2 corrupt payloads: 7 read, 5 published, 2 rejected as corrupt, one pass."""
    path = tmp_path / 'bag'
    start = 1_700_000_000_000_000_000
    with BagWriter(path) as bag:
        for i in range(5):
            stamp = start + i * 100_000_000
            pose = np.eye(4)
            pose[:3, 3] = [i, 0.0, 50.0]
            bag.write(
                '/camera/pose',
                msg_utils.matrix_to_pose_stamped(pose, stamp_ns=stamp, flavor='rosbags'),
                stamp,
            )
            if i in (1, 3):
                bag.write_raw('/camera/pose', 'geometry_msgs/msg/PoseStamped', b'\x00\x01\x00\x00', stamp + 1)
    argv = [sys.executable, '-m', 'ibr_ros.nodes.bag_player', '--ros-args', '-p', f'bag:={path}',
            '-p', 'rate:=0.0', '-p', 'publish_clock:=false', '-p', 'linger_s:=-1.0',
            '-p', 'diagnostics_period_s:=0.1']  # fmt: skip
    log = tmp_path / 'player.log'
    rclpy.init()
    proc = subprocess.Popen(argv, env=ros_env, stdout=log.open('w'), stderr=subprocess.STDOUT)
    try:
        node = rclpy.create_node('diagnostics_listener')
        box: list = []
        node.create_subscription(DiagnosticArray, '/diagnostics', box.append, DIAG_QOS)

        def done(a: dict[str, AreaStatus]) -> bool:  # the player's thread counts, then publishes
            last = _counts(a, 'outputs').get('/camera/pose.count') == '5'
            return (
                _counts(a, 'inputs').get('bag.count') == '7'
                and last
                and a['model'].value('bag_time_s') == '0.400'
            )

        assert spin_until(node, lambda: _areas(box, 'bag_player', done) is not None, 60), log.read_text()
        areas = _areas(box, 'bag_player', done)
        _assert_named(box, 'bag_player')
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        rclpy.try_shutdown()
    assert proc.returncode == 0, log.read_text()
    assert _counts(areas, 'rejected') == {'total': '2', 'corrupt': '2'}
    assert _counts(areas, 'outputs')['latency.count'] == '0'  # rate 0: nothing is due
    assert _counts(areas, 'model') == {'passes': '1', 'bag_time_s': '0.400', 'duration_s': '0.400'}
    assert _counts(areas, 'queues') == {}
    _documented('bag_player', areas)
