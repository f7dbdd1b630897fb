# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""bag_player in its own process, received over DDS by a subscriber node in the test process.

Checks: the shipped bag's first 3 s arrive complete, byte-identical and in order with /clock at the
bag's time; a small bag of raw Image (rgb8), CompressedImage, CameraInfo and PoseStamped is paced at
rate 1, honours a remap and drives a ``use_sim_time`` node's clock; ``loop`` republishes; a missing
bag is one error line and exit code 2; undecodable payloads are classified by reason, and a looping
player over nothing but undecodable messages stops (exit 2) instead of spinning; topics recorded with
transient-local QoS are played so, and a ``model_qos`` subscriber that joins after playback still gets
them all.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections import defaultdict
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.bag import BagWriter, OfferedQos, open_bag
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.nodes.common import model_qos

pytestmark = pytest.mark.dds

SUB_QOS = QoSProfile(depth=1000, reliability=QoSReliabilityPolicy.RELIABLE)
SMALL_START_NS = 1_700_000_000_000_000_000
SMALL_TYPES = {
    '/camera/image_raw': Image,
    '/camera/image_raw/compressed': CompressedImage,
    '/camera/camera_info': CameraInfo,
    '/camera/pose': PoseStamped,
}


def _frame(i: int) -> np.ndarray:
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory) -> Path:
    """2 s at 10 Hz (21 frames) of the four camera topics, written with BagWriter."""
    path = tmp_path_factory.mktemp('bags') / 'small'
    cam = PinholeCamera(64, 48, np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]))
    with BagWriter(path) as bag:
        for i in range(21):
            stamp = SMALL_START_NS + i * 100_000_000
            header = msg_utils.make_header(stamp, 'camera_optical', flavor='rosbags')
            rgb = _frame(i)
            bag.write(
                '/camera/image_raw', msg_utils.numpy_to_image(rgb, 'rgb8', header, flavor='rosbags'), stamp
            )
            jpeg = msg_utils.numpy_to_compressed_image(
                rgb, 'jpeg', encoding='rgb8', header=header, flavor='rosbags'
            )
            bag.write('/camera/image_raw/compressed', jpeg, stamp)
            bag.write(
                '/camera/camera_info', msg_utils.pinhole_to_camera_info(cam, header, flavor='rosbags'), stamp
            )
            pose = np.eye(4)
            pose[:3, 3] = [i, 2.0 * i, 50.0]
            bag.write(
                '/camera/pose',
                msg_utils.matrix_to_pose_stamped(pose, stamp_ns=stamp, flavor='rosbags'),
                stamp,
            )
    return path


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def _player(ros_env, log: Path, *params: str) -> subprocess.Popen:
    args = [sys.executable, '-m', 'ibr_ros.nodes.bag_player', '--ros-args']
    for p in params:
        args += ['-p', p]
    return subprocess.Popen(args, env=ros_env, stdout=log.open('w'), stderr=subprocess.STDOUT, text=True)


def _spin_until(node, cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    return cond()


def _receive(
    node, topics: dict[str, type], qos: QoSProfile = SUB_QOS
) -> dict[str, list[tuple[float, bytes]]]:
    """Subscribe (raw bytes, ``qos``) to ``topics``; arrivals as (monotonic time, data)."""
    got: dict[str, list[tuple[float, bytes]]] = defaultdict(list)
    for name, cls in topics.items():
        cb = lambda data, name=name: got[name].append((time.monotonic(), data))  # noqa: E731
        node.create_subscription(cls, name, cb, qos, raw=True)
    return got


def _clock(node) -> list[int]:
    clock: list[int] = []
    node.create_subscription(Clock, '/clock', lambda m: clock.append(msg_utils.stamp_to_ns(m.clock)), SUB_QOS)
    return clock


def _payloads(arrivals: list[tuple[float, bytes]], raws: list[bytes]) -> list[bytes]:
    """Received serialised messages, cut to the bag's lengths where DDS only appended zero padding.

    RTPS pads serialised payloads to a multiple of 4 bytes; the CDR content is untouched.
    """
    out = []
    for (_, data), raw in zip(arrivals, raws):
        pad = data[len(raw) :]
        out.append(data[: len(raw)] if len(pad) < 4 and not any(pad) and len(data) % 4 == 0 else data)
    return out + [data for _, data in arrivals[len(raws) :]]


def _finish(proc: subprocess.Popen, log: Path, timeout: float = 20.0) -> str:
    try:
        proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return log.read_text()


def test_shipped_bag_arrives_complete_byte_identical_in_order(repo, ros_env, ros, tmp_path):
    bag_path = repo / 'bags' / 'synth_orbit_s0'
    with open_bag(bag_path) as bag:
        types = {t: i.msgtype for t, i in bag.topics.items()}
        end_ns = bag.start_ns + 3_000_000_000
        expected: dict[str, list[bytes]] = defaultdict(list)
        stamps = []
        for m in bag.messages(end_ns=end_ns):
            expected[m.topic].append(m.rawdata)
            stamps.append(m.timestamp_ns)
    node = rclpy.create_node('bag_player_test')
    got = _receive(node, {t: msg_utils.flavor.message_class(types[t]) for t in expected})
    clock = _clock(node)
    log = tmp_path / 'player.log'
    proc = _player(ros_env, log, f'bag:={bag_path}', 'rate:=0.0', 'duration:=3.0', 'wait_for_subscribers:=1')
    try:
        total = sum(len(v) for v in expected.values())
        complete = _spin_until(node, lambda: sum(len(v) for v in got.values()) >= total, 30)
        assert complete, f'messages missing: { ({t: len(v) for t, v in got.items()}) }\n{log.read_text()}'
        assert _spin_until(node, lambda: proc.poll() is not None and clock[-1:] == [max(stamps)], 20)
    finally:
        out = _finish(proc, log)
    assert proc.returncode == 0, out
    assert f'done: {total} messages' in out, out
    assert set(got) == set(expected)
    for topic, raws in expected.items():
        assert _payloads(got[topic], raws) == raws, f'{topic}: bytes or order differ'
    assert clock == sorted(clock), '/clock went backwards'
    assert clock[0] == min(stamps)
    assert clock[-1] == max(stamps)


def test_rate_1_paces_raw_images_remaps_and_drives_sim_time(small_bag, ros_env, ros, tmp_path):
    with open_bag(small_bag) as bag:
        expected = {t: [m.rawdata for m in bag.messages([t])] for t in SMALL_TYPES}
    node = rclpy.create_node('sim_time_test', parameter_overrides=[Parameter('use_sim_time', value=True)])
    topics = {('pose_remapped' if t == '/camera/pose' else t): cls for t, cls in SMALL_TYPES.items()}
    got = _receive(node, topics)
    sim_now: list[tuple[int, int]] = []  # (pose stamp, node clock when it arrived)
    node.create_subscription(
        PoseStamped,
        'pose_remapped',
        lambda m: sim_now.append((msg_utils.stamp_to_ns(m.header.stamp), node.get_clock().now().nanoseconds)),
        SUB_QOS,
    )
    log = tmp_path / 'player.log'
    proc = _player(
        ros_env, log, f'bag:={small_bag}', 'rate:=1.0', 'wait_for_subscribers:=1', 'progress_s:=0.5',
        "remap:=['/camera/pose:=pose_remapped']",
    )  # fmt: skip
    try:
        done = lambda: sum(len(v) for v in got.values()) >= 4 * 21 and len(sim_now) >= 21  # noqa: E731
        assert _spin_until(node, done, 30), f'messages missing\n{log.read_text()}'
    finally:
        out = _finish(proc, log)
    assert proc.returncode == 0, out
    got['/camera/pose'] = got.pop('pose_remapped')
    for topic, raws in expected.items():
        assert _payloads(got[topic], raws) == raws, f'{topic}: bytes or order differ'
    images = [deserialize_message(data, Image) for _, data in got['/camera/image_raw']]
    assert images[0].encoding == 'rgb8'
    np.testing.assert_array_equal(msg_utils.image_to_numpy(images[20]), _frame(20))
    wall = float(re.search(r'done: 84 messages in ([0-9.]+) s', out).group(1))
    assert 1.8 <= wall <= 3.0, f'a 2 s bag at rate 1 took {wall} s'
    # The node's sim time is the bag time (not wall time): within 0.1 s of each pose as it arrives.
    lag = [(stamp - now) / 1e9 for stamp, now in sim_now]
    assert np.median(np.abs(lag)) < 0.1, lag
    assert '%)' in out  # progress lines


def test_loop_republishes_until_stopped(small_bag, ros_env, ros, tmp_path):
    node = rclpy.create_node('loop_test')
    got = _receive(node, SMALL_TYPES)
    log = tmp_path / 'player.log'
    proc = _player(ros_env, log, f'bag:={small_bag}', 'rate:=0.0', 'loop:=true', 'wait_for_subscribers:=1')
    try:
        assert _spin_until(node, lambda: len(got['/camera/pose']) > 3 * 21, 30), 'no second pass'
        assert proc.poll() is None, 'a looping player must not exit'
        proc.terminate()
        proc.wait(timeout=10)
    finally:
        out = _finish(proc, log)
    assert 'pass 3 done' in out, out
    poses = [deserialize_message(data, PoseStamped) for _, data in got['/camera/pose']]
    stamps = [msg_utils.stamp_to_ns(p.header.stamp) for p in poses[:42]]
    assert stamps[21] == stamps[0] == SMALL_START_NS  # the second pass starts over


def test_ros1_bag_plays_as_ros2_and_skips_unknown_types(ros_env, ros, tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    noetic = get_typestore(Stores.ROS1_NOETIC)
    noetic.register(get_types_from_msg('int32 value', 'my_pkg/msg/Custom'))
    N = noetic.types
    path = tmp_path / 'old.bag'
    with Writer(path) as writer:
        conn = writer.add_connection('/pose', 'geometry_msgs/msg/PoseStamped', typestore=noetic)
        custom = writer.add_connection('/custom', 'my_pkg/msg/Custom', typestore=noetic)
        for i in range(5):
            stamp = N['builtin_interfaces/msg/Time'](sec=100 + i, nanosec=0)
            pose = N['geometry_msgs/msg/PoseStamped'](
                header=N['std_msgs/msg/Header'](seq=i, stamp=stamp, frame_id='map'),
                pose=N['geometry_msgs/msg/Pose'](
                    position=N['geometry_msgs/msg/Point'](x=float(i), y=0.0, z=1.0),
                    orientation=N['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            )
            ns = (100 + i) * 1_000_000_000
            writer.write(conn, ns, noetic.serialize_ros1(pose, 'geometry_msgs/msg/PoseStamped'))
            writer.write(
                custom, ns, noetic.serialize_ros1(N['my_pkg/msg/Custom'](value=i), 'my_pkg/msg/Custom')
            )
    node = rclpy.create_node('ros1_test')
    got: list[PoseStamped] = []
    node.create_subscription(PoseStamped, '/pose', got.append, SUB_QOS)
    log = tmp_path / 'player.log'
    proc = _player(ros_env, log, f'bag:={path}', 'rate:=0.0', 'wait_for_subscribers:=1')
    try:
        assert _spin_until(node, lambda: len(got) >= 5, 30), log.read_text()
    finally:
        out = _finish(proc, log)
    assert proc.returncode == 0, out
    assert [(m.header.stamp.sec, m.header.frame_id, m.pose.position.x) for m in got] == [
        (100 + i, 'map', float(i)) for i in range(5)
    ]
    assert 'skipping /custom (my_pkg/msg/Custom)' in out


def test_missing_bag_is_one_error_line_and_exit_2(ros_env, tmp_path):
    missing = tmp_path / 'no_such_bag'
    res = subprocess.run(
        [sys.executable, '-m', 'ibr_ros.nodes.bag_player', '--ros-args', '-p', f'bag:={missing}'],
        env=ros_env, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert res.returncode == 2
    lines = (res.stdout + res.stderr).strip().splitlines()
    assert len(lines) == 1, lines
    assert 'ERROR' in lines[0]
    assert str(missing) in lines[0]


def test_undecodable_payloads_are_classified_and_valid_ones_pass():
    from ibr_ros.bag.playback import undecodable
    from ibr_ros.nodes.bag_player import decoder

    header = msg_utils.make_header(SMALL_START_NS, 'camera_optical')
    img = msg_utils.numpy_to_image(_frame(0), 'rgb8', header)
    jpeg = msg_utils.numpy_to_compressed_image(_frame(0), 'jpeg', encoding='rgb8', header=header)
    for msg in (img, jpeg):
        cls, raw = type(msg), serialize_message(msg)
        msgtype = msg_utils.flavor.message_typename(msg)
        for decode in (decoder(msgtype, cls), partial(deserialize_message, message_type=cls)):
            assert undecodable(raw, decode) is None
            assert undecodable(b'', decode) == ('empty', 'payload of 0 bytes')
            assert undecodable(raw[:3], decode)[0] == 'encapsulation'
            reason, error = undecodable(b'\x10\x01' + raw[2:], decode)
            assert (reason, '10 01' in error) == ('encapsulation', True)
            assert undecodable(raw[: len(raw) - 8], decode)[0] == 'corrupt'
            huge = raw[:12] + (2**31).to_bytes(4, 'little') + raw[16:]  # header.frame_id length
            assert undecodable(huge, decode)[0] == 'corrupt'


def test_loop_over_undecodable_messages_only_stops_with_exit_2(ros_env, tmp_path):
    path = tmp_path / 'garbage'
    with BagWriter(path) as bag:
        for i in range(3):
            bag.write_raw(
                '/camera/pose', 'geometry_msgs/msg/PoseStamped', b'\x00\x01\x00\x00', SMALL_START_NS + i
            )
    log = tmp_path / 'player.log'
    proc = _player(ros_env, log, f'bag:={path}', 'rate:=0.0', 'loop:=true', 'publish_clock:=false')
    out = _finish(proc, log)
    assert proc.returncode == 2, out
    assert 'pass 1 done: 3 undecodable messages skipped: /camera/pose 3 (corrupt 3)' in out, out
    assert 'published no message; not looping' in out, out


def test_transient_local_topics_reach_a_late_subscriber(ros_env, ros, tmp_path):
    """A bag with keyframe-like topics recorded reliable + transient local (one as if latched, depth 1)
    and a volatile query topic: a ``model_qos`` subscriber created after playback gets every message."""
    path = tmp_path / 'model'
    recorded = {
        '/keyframes/image': (Image, OfferedQos.from_profile(model_qos())),
        '/keyframes/pose': (PoseStamped, OfferedQos('reliable', 'transient_local', depth=1)),
        '/novel_view/query': (PoseStamped, OfferedQos('reliable', 'volatile', depth=10)),
    }
    with BagWriter(path) as bag:
        for topic, (cls, qos) in recorded.items():
            bag.add_topic(topic, msg_utils.flavor.message_typename(cls()), qos)
        for i in range(5):
            stamp = SMALL_START_NS + i * 100_000_000
            header = msg_utils.make_header(stamp, 'camera_optical', flavor='rosbags')
            bag.write(
                '/keyframes/image',
                msg_utils.numpy_to_image(_frame(i), 'rgb8', header, flavor='rosbags'),
                stamp,
            )
            pose = msg_utils.matrix_to_pose_stamped(np.eye(4), stamp_ns=stamp, flavor='rosbags')
            bag.write('/keyframes/pose', pose, stamp)
            bag.write('/novel_view/query', pose, stamp)
    with open_bag(path) as reader:
        expected = {t: [m.rawdata for m in reader.messages([t])] for t in recorded}
    types = {t: cls for t, (cls, _) in recorded.items()}
    durable = ['/keyframes/image', '/keyframes/pose']
    early = rclpy.create_node('early_subscriber')
    got_early = _receive(early, types)
    log = tmp_path / 'player.log'
    proc = _player(
        ros_env, log, f'bag:={path}', 'rate:=0.0', 'wait_for_subscribers:=1', 'linger_s:=-1.0',
        'publish_clock:=false',
    )  # fmt: skip
    try:
        assert _spin_until(early, lambda: all(len(got_early[t]) >= 5 for t in types), 30), log.read_text()
        # Playback has published everything: a model_qos subscriber joins only now.
        late = rclpy.create_node('late_subscriber')
        got_late = _receive(late, {t: types[t] for t in durable}, model_qos())
        assert _spin_until(late, lambda: all(len(got_late[t]) >= 5 for t in durable), 30), log.read_text()
        assert proc.poll() is None, 'the player must linger'
        proc.send_signal(signal.SIGINT)
    finally:
        out = _finish(proc, log)
    assert proc.returncode == 0, out
    for topic in durable:
        assert _payloads(got_late[topic], expected[topic]) == expected[topic], (
            f'{topic}: bytes or order differ'
        )
    assert (
        'QoS: /keyframes/image: reliable transient_local depth 1000 (recorded), '
        '/keyframes/pose: reliable transient_local depth 5 (recorded), '
        '/novel_view/query: reliable volatile depth 8 (recorded, flow_window at rate 0)'
    ) in out, out
