# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""frame_subsampler in its own process, fed over DDS from the shipped synthetic bag.

The test node publishes every 2nd frame of the bag's first 12 s (CompressedImage + CameraInfo +
PoseStamped) with malformed messages interleaved (zero quaternion, NaN position, garbage JPEG,
mismatched camera_info), then checks the keyframes: three topics with identical stamps, a sensible
count, and a node that is still alive and has logged the rejections. Also: keyframes without poses, and
``target_keyframes`` + ``expected_path_m`` (the live hint) over the whole shipped flight in-process.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from node_harness import image_msg, in_process, info_msg, shipped_frames, spin_until
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.jobs.synth_bag import TOPICS

pytestmark = pytest.mark.dds

LATCHED = QoSProfile(
    depth=1000, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
)
PUB_QOS = QoSProfile(depth=50, reliability=QoSReliabilityPolicy.RELIABLE)


def _frames(repo, seconds: float = 12.0, every: int = 2):
    with open_bag(repo / 'bags' / 'synth_orbit_s0') as bag:
        by_stamp: dict[int, dict] = {}
        for m in bag.messages([TOPICS['image'], TOPICS['camera_info'], TOPICS['pose']]):
            by_stamp.setdefault(m.timestamp_ns, {})[m.topic] = m.rawdata
    stamps = sorted(by_stamp)
    stamps = [s for s in stamps if s - stamps[0] < seconds * 1e9][::every]
    return [(s, by_stamp[s]) for s in stamps]


@pytest.fixture
def subsampler(repo, ros_env):
    proc = subprocess.Popen(
        [sys.executable, '-m', 'ibr_ros.nodes.frame_subsampler', '--ros-args',
         '--params-file', str(repo / 'config' / 'frame_subsampler.yaml'),
         '-p', 'image_transport:=compressed', '-p', 'scene_depth_m:=120.0'],
        env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    yield proc
    proc.terminate()
    proc.wait(timeout=20)


def test_keyframes_from_the_shipped_bag(repo, subsampler):
    from rclpy.serialization import deserialize_message

    frames = _frames(repo)
    rclpy.init()
    try:
        node = rclpy.create_node('subsampler_feeder')
        pub_img = node.create_publisher(CompressedImage, 'camera/image_raw/compressed', PUB_QOS)
        pub_info = node.create_publisher(CameraInfo, 'camera/camera_info', PUB_QOS)
        pub_pose = node.create_publisher(PoseStamped, 'camera/pose', PUB_QOS)
        got: dict[str, list] = {'image': [], 'info': [], 'pose': []}
        node.create_subscription(Image, 'keyframes/image', got['image'].append, LATCHED)
        node.create_subscription(CameraInfo, 'keyframes/camera_info', got['info'].append, LATCHED)
        node.create_subscription(PoseStamped, 'keyframes/pose', got['pose'].append, LATCHED)
        pubs = (pub_img, pub_info, pub_pose)
        assert spin_until(node, lambda: all(p.get_subscription_count() > 0 for p in pubs), 30), (
            'node never subscribed'
        )

        for k, (stamp, raw) in enumerate(frames):
            img = deserialize_message(raw[TOPICS['image']], CompressedImage)
            info = deserialize_message(raw[TOPICS['camera_info']], CameraInfo)
            pose = deserialize_message(raw[TOPICS['pose']], PoseStamped)
            if k % 5 == 2:  # malformed companions of a frame that also has valid ones
                bad_pose = deserialize_message(raw[TOPICS['pose']], PoseStamped)
                bad_pose.pose.orientation.w = bad_pose.pose.orientation.x = 0.0
                bad_pose.pose.orientation.y = bad_pose.pose.orientation.z = 0.0
                bad_pose.header.stamp = msg_utils.ns_to_stamp(stamp + 1)
                pub_pose.publish(bad_pose)
                garbage = CompressedImage(header=img.header, format='jpeg')
                garbage.header.stamp = msg_utils.ns_to_stamp(stamp + 1)
                garbage.data = b'not a jpeg'
                pub_img.publish(garbage)
                nan_pose = deserialize_message(raw[TOPICS['pose']], PoseStamped)
                nan_pose.pose.position.x = float('nan')
                nan_pose.header.stamp = msg_utils.ns_to_stamp(stamp + 2)
                pub_pose.publish(nan_pose)
            pub_info.publish(info)
            pub_pose.publish(pose)
            pub_img.publish(img)
            rclpy.spin_once(node, timeout_sec=0.03)
        assert spin_until(node, lambda: len(got['pose']) >= 3 and len(got['pose']) == len(got['image']), 30)
        spin_until(node, lambda: False, 1.0)  # let the last keyframe's three messages arrive
    finally:
        rclpy.try_shutdown()
    assert subsampler.poll() is None, 'node died'
    stamps = [[msg_utils.stamp_to_ns(m.header.stamp) for m in got[k]] for k in ('image', 'info', 'pose')]
    assert stamps[0] == stamps[1] == stamps[2]
    assert 4 <= len(stamps[0]) <= len(frames) // 2
    assert got['image'][0].encoding == 'rgb8'
    assert (got['image'][0].width, got['image'][0].height) == (640, 360)
    # Keyframes are spaced: consecutive camera centres >= 0.08 x 120 m apart (or turned 15 deg).
    centres = np.array([msg_utils.pose_stamped_to_matrix(m)[:3, 3] for m in got['pose']])
    assert (np.linalg.norm(np.diff(centres, axis=0), axis=1) > 1.0).all()
    subsampler.terminate()
    out, _ = subsampler.communicate(timeout=20)
    assert 'rejected input (pose' in out
    assert 'rejected input (image' in out


def test_keyframes_without_poses(repo):
    """No camera/pose publisher (``pose_source`` auto): the sharpest frame of every 1 s window, no pose
    topic; the last window's keyframe once the camera stream ends."""
    import cv2

    from ibr_ros.nodes.frame_subsampler import FrameSubsampler

    # The bag's first 6 s, every 2nd frame: 30 frames, 0.2 s apart.
    frames = [(f['stamp'], f['rgb'], f['camera']) for f in shipped_frames(repo, range(0, 60, 2), (320, 180))]
    blurred = {frames[k][0] for k in (3, 12, 13, 14)}  # never keyframes
    t0 = frames[0][0]
    params = {'poseless_interval_s': 1.0}
    with in_process(FrameSubsampler, None, 'poseless_feeder', **params) as h:
        node = h.node
        got = {
            'image': h.collect(Image, 'keyframes/image', LATCHED),
            'info': h.collect(CameraInfo, 'keyframes/camera_info', LATCHED),
            'pose': h.collect(PoseStamped, 'keyframes/pose', LATCHED),
        }
        pubs = h.publishers({
            'image': (Image, 'camera/image_raw', PUB_QOS),
            'info': (CameraInfo, 'camera/camera_info', PUB_QOS),
        })  # fmt: skip
        assert h.wait(lambda: node.pub_pose.get_subscription_count() > 0, 30)
        for k, (stamp, rgb, camera) in enumerate(frames):
            if stamp in blurred:
                rgb = cv2.GaussianBlur(rgb, (0, 0), 3.0)
            pubs['info'].publish(info_msg(camera, stamp))
            pubs['image'].publish(image_msg(rgb, stamp))
            # Paced: the next frame goes out once the node has this one (pending or processed).
            assert h.wait(
                lambda s=stamp, n=k + 1: 'image' in node.frames.partial(s) or node.frames_seen >= n, 10
            )
        # Six 1 s windows: five closed by the next window's frames, the last when the camera stops.
        h.feeder.destroy_publisher(pubs['image'])
        assert h.wait(lambda: len(got['image']) == 6 and len(got['info']) == 6, 20), node.interval.rejected
        assert node.pose_source.state == 'none'
        assert node.frames_seen == len(frames)
        bad = dict(node.bad.counts)
    assert bad == {}
    assert got['pose'] == []
    stamps = [msg_utils.stamp_to_ns(m.header.stamp) for m in got['image']]
    assert stamps == [msg_utils.stamp_to_ns(m.header.stamp) for m in got['info']]
    assert [(s - t0) // 1_000_000_000 for s in stamps] == [0, 1, 2, 3, 4, 5]  # one per window
    assert not blurred & set(stamps)
    assert (got['image'][0].width, got['image'][0].height, got['image'][0].encoding) == (320, 180, 'rgb8')
    assert (got['info'][0].width, got['info'][0].height) == (320, 180)


def test_target_keyframes_live_hint(repo):
    """``target_keyframes`` 25 + ``expected_path_m`` (the bag's path length): about 25 keyframes over the
    whole shipped flight, even with a scene depth set (the target's baseline replaces its rule).
    """
    from ibr_ros.nodes.frame_subsampler import FrameSubsampler

    frames = shipped_frames(repo, range(200), (160, 90))
    centres = np.array([f['pose'][:3, 3] for f in frames])
    path_m = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())  # ~159 m
    params = {
        'target_keyframes': 25,
        'expected_path_m': path_m,
        'scene_depth_m': 120.0,
        'pose_source': 'topic',
    }
    with in_process(FrameSubsampler, repo / 'config' / 'frame_subsampler.yaml', **params) as h:
        node = h.node
        assert node.config.min_baseline_m == pytest.approx(path_m / 25)
        assert node.decide_depth is None
        for f in frames:  # straight into the node's frame assembly (no DDS: fast and deterministic)
            info = info_msg(f['camera'], f['stamp'])
            node._put(f['stamp'], 'camera_info', (info, f['camera']))
            node._put(f['stamp'], 'pose', (f['pose'], 'map'))
            node._put(f['stamp'], 'image', f['rgb'])
        assert node.frames_seen == 200
        assert abs(node.keyframes - 25) <= 2, node.keyframes
    with (
        pytest.raises(ValueError, match='needs expected_path_m'),
        in_process(FrameSubsampler, target_keyframes=25),
    ):
        pass
