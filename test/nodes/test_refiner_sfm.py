# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""depth_refiner in SfM mode, in this process over DDS: keyframes without poses.

Eight keyframes of the shipped synthetic orbit (every 24th frame, 320x180, all with stored ground
truth) are published without poses, five first and then three more. With the default
``sfm_mode:=auto`` the refiner must notice that no pose comes, register them (two SfM updates),
publish one pose per keyframe on ``keyframes/pose`` (frame ``sfm``), refine every keyframe once,
and its depth must match the ground truth up to the SfM scale (found from the published poses).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from node_harness import (
    assert_refuses_to_start,
    in_process,
    keyframe_topics,
    publish_frame,
    shipped_frames,
)
from sensor_msgs.msg import Image

import msg_utils
from ibr_ros.core.flight.status import FlightStatus
from ibr_ros.core.registration.sfm import umeyama
from ibr_ros.nodes.common import latched_qos, model_qos

pytestmark = pytest.mark.dds

FRAMES = tuple(range(0, 192, 24))
SIZE = (320, 180)


@pytest.fixture(scope='module')
def keyframes(repo) -> list[dict]:
    """stamp, rgb, camera, GT pose and GT depth of FRAMES, resized to SIZE."""
    return shipped_frames(repo, FRAMES, SIZE)


@pytest.mark.parametrize(
    ('params', 'error'),
    [
        (['num_workers:=2', 'sfm_mode:=always'],
         "parameter sfm_mode 'always' needs num_workers 1 (one SfM registration per graph), got num_wo"),
        (['sfm_mode:=sometimes'], "parameter sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'"),
        (['sfm_scale:=altitude'], "parameter sfm_scale_m must be > 0 with sfm_scale 'altitude', got 0.0"),
    ],
)  # fmt: skip
def test_bad_sfm_parameters_stop_the_node_with_one_line(params, error, capfd):
    from ibr_ros.nodes.depth_refiner import main

    assert_refuses_to_start(main, 'depth_refiner', params, error, capfd)


def test_refiner_registers_and_refines_keyframes_without_poses(repo, keyframes):
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    config = repo / 'config' / 'depth_refiner.yaml'
    params = {'sfm_min_keyframes': 5, 'sfm_every': 3, 'flush_after_s': 2.0, 'max_neighbours': 2}
    with in_process(DepthRefinerNode, config, 'sfm_refiner_feeder', **params) as h:
        node = h.node
        assert (node.sfm_mode, node.sfm_active) == ('auto', False)
        depths = h.collect(Image, 'keyframes/depth', model_qos())
        poses = h.collect(PoseStamped, 'keyframes/pose', model_qos())
        spec = keyframe_topics(model_qos())
        pubs = h.publishers({k: spec[k] for k in ('image', 'info')})
        # The refiner's pose publisher and the feeder's pose subscription must be matched.
        assert h.wait(lambda: node.pub_pose.get_subscription_count() >= 1, 30)
        # The frame_subsampler's latched status: this flight has no poses.
        status = h.publishers({'s': (DiagnosticStatus, 'keyframes/status', latched_qos())})['s']
        status.publish(msg_utils.pairs_to_status('t', FlightStatus(pose_source='none').to_pairs()))
        assert h.wait(lambda: node.sfm_active, 30)

        def send(frames: list[dict]) -> None:
            for f in frames:
                publish_frame(pubs, f, pose=False)

        t0 = time.monotonic()
        send(keyframes[:5])
        assert h.wait(lambda: len(poses) == 5, 60), node.bad.counts
        t_first = time.monotonic() - t0
        assert node.sfm_active
        send(keyframes[5:])
        assert h.wait(lambda: len(poses) == 8 and len(depths) == 8, 180), (len(poses), len(depths))
        t_all = time.monotonic() - t0
        # Idle: nothing waits for registration or refinement, so no further depth can come.
        assert h.wait(lambda: not node._sfm_queue and not node.schedule.unrefined(), 10)
        refine_times = list(node.refine_times)
        sfm_times = list(node.sfm_times)
        bad = dict(node.bad.counts)
    assert bad == {}
    stamps = [f['stamp'] for f in keyframes]
    assert sorted(msg_utils.stamp_to_ns(m.header.stamp) for m in poses) == stamps  # one pose each
    assert {m.header.frame_id for m in poses} == {'sfm'}
    assert sorted(msg_utils.stamp_to_ns(m.header.stamp) for m in depths) == stamps  # refined once each
    assert len(refine_times) == 8
    print(f'SfM updates {[round(t, 2) for t in sfm_times]} s; first poses after {t_first:.1f} s, '
          f'all depth after {t_all:.1f} s; refinement {np.median(refine_times):.2f} s median')  # fmt: skip

    # Poses against the ground truth up to a similarity; its scale converts SfM units to metres.
    by_stamp = {msg_utils.stamp_to_ns(m.header.stamp): msg_utils.pose_stamped_to_matrix(m) for m in poses}
    est = np.array([by_stamp[f['stamp']][:3, 3] for f in keyframes])
    ref = np.array([f['pose'][:3, 3] for f in keyframes])
    m = umeyama(est, ref)
    scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
    rms = float(np.sqrt(np.mean(np.sum((est @ m[:3, :3].T + m[:3, 3] - ref) ** 2, axis=1))))
    baseline = float(np.linalg.norm(ref[1] - ref[0]))
    print(f'pose centre RMS {rms:.3f} m (baseline {baseline:.1f} m), scale {scale:.2f} m per unit')
    assert rms < 0.02 * baseline
    assert abs(scale / baseline - 1.0) < 0.02  # the unit is the first baseline

    rels = []
    for msg in sorted(depths, key=lambda d: d.header.stamp.sec * 10**9 + d.header.stamp.nanosec):
        f = keyframes[stamps.index(msg_utils.stamp_to_ns(msg.header.stamp))]
        d = msg_utils.image_to_numpy(msg) * scale
        assert d.shape == (SIZE[1], SIZE[0])
        gt = f['gt']
        ok = np.isfinite(gt) & (gt > 0) & np.isfinite(d) & (d > 0)
        assert ok.mean() > 0.5
        rels.append(float(np.median(np.abs(d[ok] - gt[ok]) / gt[ok])))
    print('median relative depth error per keyframe (after scale)', [round(r, 4) for r in rels])
    assert max(rels) < 0.1, rels


def test_auto_sfm_starts_only_when_the_status_says_no_poses(monkeypatch):
    """'auto' never starts SfM on its own, however long keyframes wait for their poses: only when
    keyframes/status says the flight has no poses (then the waiting ones are registered first)."""
    import rclpy

    import msg_utils
    from ibr_ros.core.flight.status import FlightStatus
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    rclpy.init(args=['--ros-args', '-p', 'sfm_min_keyframes:=4'])
    node = None
    try:
        node = DepthRefinerNode()
        partial = {'image': np.zeros((2, 2, 3), np.uint8), 'camera_info': ('cam', None)}
        monkeypatch.setattr(node.frames, 'partial', lambda stamp: partial)
        monkeypatch.setattr(node.frames, 'discard', lambda stamp: None)
        added: list[int] = []
        monkeypatch.setattr(node, '_add_poseless', lambda stamp, *rest: added.append(stamp))
        node._poseless = {1, 2, 3, 4}
        status = lambda **v: msg_utils.pairs_to_status('t', FlightStatus(**v).to_pairs())  # noqa: E731
        node._on_status(status(pose_source='pose'))
        assert not node.sfm_active
        node._on_status(status(pose_source='unknown', camera='ended'))
        assert not node.sfm_active
        assert node._ended
        node._on_status(status(pose_source='none'))
        assert node.sfm_active
        assert added == [1, 2, 3, 4]
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
