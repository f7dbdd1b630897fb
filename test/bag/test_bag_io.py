# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Bag reading, writing and topic detection (ibr_ros.bag)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap_helpers import corrupt_chunk
from rosbags.typesys import Stores, get_typestore

from ibr_ros.bag import TYPESTORE, BagWriter, OfferedQos, detect_topics, find_bags, open_bag, serialize
from ibr_ros.bag.info import image_dimensions
from ibr_ros.errors import BagError

T = TYPESTORE.types
SEC = 1_000_000_000
PNG_4X3 = b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x04\x00\x00\x00\x03\x08\x02\x00\x00\x00'
JPEG_5X7 = b'\xff\xd8\xff\xe0\x00\x04JF\xff\xc0\x00\x11\x08\x00\x07\x00\x05\x03' + bytes(12) + b'\xff\xd9'


def stamp(ns: int) -> object:
    return T['builtin_interfaces/msg/Time'](sec=ns // SEC, nanosec=ns % SEC)


def header(ns: int, frame: str = 'cam') -> object:
    return T['std_msgs/msg/Header'](stamp=stamp(ns), frame_id=frame)


def image(ns: int, value: int = 0) -> object:
    return T['sensor_msgs/msg/Image'](
        header=header(ns),
        height=2,
        width=3,
        encoding='rgb8',
        is_bigendian=0,
        step=9,
        data=np.full(18, value, dtype=np.uint8),
    )


def compressed(ns: int) -> object:
    return T['sensor_msgs/msg/CompressedImage'](
        header=header(ns), format='png', data=np.frombuffer(PNG_4X3, dtype=np.uint8)
    )


def camera_info(ns: int) -> object:
    roi = T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return T['sensor_msgs/msg/CameraInfo'](
        header=header(ns),
        height=2,
        width=3,
        distortion_model='plumb_bob',
        d=np.array([0.1, 0.0, 0.0, 0.0, 0.0]),
        k=np.array([100.0, 0, 1.5, 0, 100.0, 1.0, 0, 0, 1]),
        r=np.eye(3).ravel(),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def pose(ns: int, x: float) -> object:
    pos = T['geometry_msgs/msg/Point'](x=x, y=2.0, z=3.0)
    quat = T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)
    return T['geometry_msgs/msg/PoseStamped'](
        header=header(ns, 'map'), pose=T['geometry_msgs/msg/Pose'](position=pos, orientation=quat)
    )


def navsat(ns: int) -> object:
    status = T['sensor_msgs/msg/NavSatStatus'](status=0, service=1)
    return T['sensor_msgs/msg/NavSatFix'](
        header=header(ns, 'gps'),
        status=status,
        latitude=48.1,
        longitude=11.5,
        altitude=520.0,
        position_covariance=np.zeros(9),
        position_covariance_type=0,
    )


def tf(ns: int) -> object:
    transform = T['geometry_msgs/msg/Transform'](
        translation=T['geometry_msgs/msg/Vector3'](x=1.0, y=0.0, z=0.0),
        rotation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    stamped = T['geometry_msgs/msg/TransformStamped'](
        header=header(ns, 'map'), child_frame_id='base', transform=transform
    )
    return T['tf2_msgs/msg/TFMessage'](transforms=[stamped])


def rclpy_pose(ns: int) -> object:
    from geometry_msgs.msg import PoseStamped

    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // SEC, ns % SEC
    msg.header.frame_id = 'odom'
    msg.pose.position.x = 7.5
    msg.pose.orientation.w = 1.0
    return msg


def sample_messages() -> list[tuple[str, object, int]]:
    """``(topic, message, log time)``, deliberately not in time order."""
    return [
        ('/cam/image_raw', image(3 * SEC, 3), 3 * SEC),
        ('/cam/image_raw', image(1 * SEC, 1), 1 * SEC),
        ('/cam/image_raw', image(2 * SEC, 2), 2 * SEC + 10),
        ('/cam/image_raw/compressed', compressed(SEC), SEC + 1),
        ('/cam/image_raw/compressed', compressed(2 * SEC), 2 * SEC + 1),
        ('/cam/camera_info', camera_info(SEC), SEC + 2),
        ('/cam/depth/image_raw', image(SEC), SEC + 3),
        ('/pose', pose(SEC, 1.0), SEC + 4),
        ('/pose', pose(2 * SEC, 2.0), 2 * SEC + 4),
        ('/fix', navsat(SEC), SEC + 5),
        ('/tf', tf(SEC), SEC + 6),
        ('/odom_pose', rclpy_pose(SEC + 7), SEC + 7),
    ]


def expected(messages: list[tuple[str, object, int]]) -> list[tuple[str, int, bytes]]:
    from rclpy.serialization import deserialize_message

    rows = []
    for topic, msg, ns in messages:
        if hasattr(msg, '__msgtype__'):
            cdr = bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
        else:  # rclpy: same content (its padding bytes are not deterministic)
            cdr = serialize(msg)[1]
            assert deserialize_message(cdr, type(msg)) == msg
        rows.append((topic, ns, cdr))
    return sorted(rows, key=lambda row: row[1])


def write_sample(path: Path, **kwargs: object) -> Path:
    with BagWriter(path, **kwargs) as writer:
        for topic, msg, ns in sample_messages():
            writer.write(topic, msg, ns)
    return path


@pytest.fixture(scope='module')
def sample_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_sample(tmp_path_factory.mktemp('bags') / 'sample', chunk_size=600)


# -- writing, and reading back with every reader --------------------------------------------------


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_written_bag_reads_back_identically(tmp_path: Path, compression: str) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader

    path = write_sample(tmp_path / 'bag', compression=compression, chunk_size=600)
    want = expected(sample_messages())
    assert sorted(p.name for p in path.iterdir()) == ['bag_0.mcap', 'metadata.yaml']

    with open_bag(path) as reader:
        got = [(m.topic, m.timestamp_ns, m.rawdata) for m in reader.messages()]
    assert got == want

    with AnyReader([path]) as anyreader:
        got = [(c.topic, t, bytes(d)) for c, t, d in anyreader.messages()]
    assert got == want

    with Reader(path) as rosbag2:
        assert rosbag2.message_count == len(want)
        assert not rosbag2.compression_mode
        got = [(c.topic, t, bytes(d)) for c, t, d in rosbag2.messages()]
        assert {c.msgtype for c in rosbag2.connections} >= {'sensor_msgs/msg/Image', 'tf2_msgs/msg/TFMessage'}
    assert got == want

    with (path / 'bag_0.mcap').open('rb') as f:
        mcap = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = mcap.get_summary()
        assert summary is not None
        assert {c.compression for c in summary.chunk_indexes} == {
            '' if compression == 'none' else compression
        }
        assert len(summary.chunk_indexes) > 1
        decoded = list(mcap.iter_decoded_messages(log_time_order=True))
    assert [(c.topic, m.log_time, m.data) for _, c, m, _ in decoded] == want
    by_topic = {}
    for _, channel, _, msg in decoded:
        by_topic.setdefault(channel.topic, []).append(msg)
    assert [bytes(m.data)[0] for m in by_topic['/cam/image_raw']] == [1, 2, 3]
    assert by_topic['/cam/camera_info'][0].k[0] == 100.0
    assert by_topic['/fix'][0].latitude == 48.1
    assert by_topic['/tf'][0].transforms[0].child_frame_id == 'base'
    assert by_topic['/odom_pose'][0].pose.position.x == 7.5


def test_reader_api(sample_bag: Path) -> None:
    with open_bag(sample_bag) as reader:
        assert reader.storage == 'mcap'
        assert reader.topics['/cam/image_raw'].msgtype == 'sensor_msgs/msg/Image'
        assert reader.topics['/cam/image_raw'].count == 3
        assert reader.topics['/odom_pose'].msgtype == 'geometry_msgs/msg/PoseStamped'
        assert (reader.start_ns, reader.end_ns) == (SEC, 3 * SEC)
        assert reader.duration_s == 2.0
        images = list(reader.messages(['/cam/image_raw'], start_ns=2 * SEC))
        assert [m.timestamp_ns for m in images] == [2 * SEC + 10, 3 * SEC]
        msg = images[0].msg
        assert type(msg) is T['sensor_msgs/msg/Image']
        assert msg.data.dtype == np.uint8
        assert images[0].header_stamp_ns == 2 * SEC
        assert next(iter(reader.messages('/odom_pose'))).msg.pose.position.x == 7.5
        assert next(iter(reader.messages('/tf'))).header_stamp_ns is None
        assert list(reader.messages(end_ns=SEC + 1)) != []
        with pytest.raises(BagError, match='no topic /nope in the bag; it has /cam/camera_info'):
            reader.messages(['/nope'])


def test_bare_mcap_and_metadata_less_directory(sample_bag: Path, tmp_path: Path) -> None:
    bare = tmp_path / 'bare.mcap'
    shutil.copy(sample_bag / 'sample_0.mcap', bare)
    folder = tmp_path / 'nometa'
    folder.mkdir()
    shutil.copy(sample_bag / 'sample_0.mcap', folder / 'x.mcap')
    want = expected(sample_messages())
    for path in (bare, folder):
        with open_bag(path) as reader:
            assert reader.storage == 'mcap'
            assert [(m.topic, m.timestamp_ns, m.rawdata) for m in reader.messages()] == want


def test_mcap_that_rosbags_rejects_is_read_with_mcap_library(tmp_path: Path) -> None:
    from mcap.writer import Writer

    from ibr_ros.bag.typestore import ros2msg_definition

    path = tmp_path / 'other_profile.mcap'
    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='', library='test')
        schema = writer.register_schema(
            'sensor_msgs/msg/Image', 'ros2msg', ros2msg_definition('sensor_msgs/msg/Image').encode()
        )
        channel = writer.register_channel('/camera/image', 'cdr', schema)
        for ns in (2 * SEC, SEC):
            cdr = bytes(TYPESTORE.serialize_cdr(image(ns, ns // SEC), 'sensor_msgs/msg/Image'))
            writer.add_message(channel, log_time=ns, data=cdr, publish_time=ns)
        writer.finish()
    with open_bag(path) as reader:
        assert reader.topics['/camera/image'].count == 2
        assert (reader.start_ns, reader.end_ns) == (SEC, 2 * SEC)
        messages = list(reader.messages())
    assert [m.timestamp_ns for m in messages] == [SEC, 2 * SEC]
    assert type(messages[0].msg) is T['sensor_msgs/msg/Image']
    assert messages[1].msg.data[0] == 2


def test_custom_and_unknown_types(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / 'custom.mcap'
    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='test')
        known = writer.register_schema('my_msgs/msg/Thing', 'ros2msg', b'int32 a\nstring b\n')
        unknown = writer.register_schema('my_msgs/msg/Mystery', '', b'')
        thing = writer.register_channel('/thing', 'cdr', known)
        mystery = writer.register_channel('/mystery', 'cdr', unknown)
        writer.add_message(
            thing, log_time=1, data=b'\x00\x01\x00\x00\x07\x00\x00\x00\x02\x00\x00\x00x\x00', publish_time=1
        )
        writer.add_message(mystery, log_time=2, data=b'\x00\x01\x00\x00', publish_time=2)
        writer.finish()
    with open_bag(path) as reader:
        assert reader.topics['/mystery'].msgtype == 'my_msgs/msg/Mystery'
        first, second = reader.messages()
    assert (first.msg.a, first.msg.b) == (7, 'x')
    with pytest.raises(BagError, match='unknown message type my_msgs/msg/Mystery on /mystery'):
        _ = second.msg


def test_sqlite3_bag(tmp_path: Path) -> None:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = tmp_path / 'db3bag'
    forever = QosTime(9223372036, 854775807)
    qos = Qos(
        QosHistory.KEEP_LAST, 7, QosReliability.BEST_EFFORT, QosDurability.TRANSIENT_LOCAL,
        forever, forever, QosLiveliness.AUTOMATIC, forever, False,
    )  # fmt: skip
    with Writer(path, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection(
            '/cam/image_raw', 'sensor_msgs/msg/Image', typestore=TYPESTORE, offered_qos_profiles=[qos]
        )
        for ns in (SEC, 2 * SEC):
            writer.write(conn, ns, TYPESTORE.serialize_cdr(image(ns, 5), 'sensor_msgs/msg/Image'))
    for bag in (path, path / 'db3bag.db3'):
        with open_bag(bag) as reader:
            assert reader.storage == 'sqlite3'
            assert reader.topics['/cam/image_raw'].offered_qos == (
                OfferedQos('best_effort', 'transient_local', depth=7),
            )
            messages = list(reader.messages())
        assert [m.timestamp_ns for m in messages] == [SEC, 2 * SEC]
        assert messages[0].msg.data[0] == 5


# -- offered QoS profiles -------------------------------------------------------------------------

DURABLE = OfferedQos('reliable', 'transient_local', depth=1000)
SENSOR = OfferedQos('best_effort', 'volatile', depth=5)
#: ``offered_qos_profiles`` as ``ros2 bag record`` (Jazzy, metadata version 8) writes it: a YAML string,
#: history unknown (discovery does not tell it), depth 0.
JAZZY_RECORDED = (
    '- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 9223372036\n'
    '    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n'
    '  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n'
    '  avoid_ros_namespace_conventions: false'
)
RECORDED = OfferedQos('reliable', 'volatile', 'unknown', 0)


def write_qos_bag(path: Path) -> Path:
    """A keyframe-like transient-local topic, a best-effort one, one with two profiles, one without."""
    with BagWriter(path) as writer:
        writer.add_topic('/keyframes/pose', 'geometry_msgs/msg/PoseStamped', DURABLE)
        writer.add_topic('/camera/image_raw', 'sensor_msgs/msg/Image', [SENSOR])
        writer.add_topic('/two', 'std_msgs/msg/String', [DURABLE, OfferedQos(history='keep_all', depth=0)])
        for i in range(3):
            writer.write('/keyframes/pose', pose(i * SEC, float(i)), i * SEC)
            writer.write('/camera/image_raw', image(i * SEC), i * SEC)
            writer.write('/two', T['std_msgs/msg/String'](data='x'), i * SEC)
            writer.write('/plain', T['std_msgs/msg/String'](data='y'), i * SEC)
    return path


QOS_WANT = {
    '/camera/image_raw': (SENSOR,),
    '/keyframes/pose': (DURABLE,),
    '/plain': (),
    '/two': (DURABLE, OfferedQos('reliable', 'volatile', 'keep_all', 0)),
}


def test_offered_qos_round_trips_through_metadata(tmp_path: Path) -> None:
    import rosbags.rosbag2.metadata
    import rosbags.rosbag2.reader
    import yaml
    from mcap.reader import make_reader
    from rosbags.interfaces import QosDurability, QosHistory, QosReliability
    from rosbags.rosbag2 import Reader

    from ibr_ros.bag._sources import McapSource
    from ibr_ros.bag.qos import parse_offered_qos

    path = write_qos_bag(tmp_path / 'bag')
    for bag in (path, path / 'bag_0.mcap'):
        with open_bag(bag) as reader:
            assert {t: i.offered_qos for t, i in reader.topics.items()} == QOS_WANT
    assert {t: i.offered_qos for t, i in McapSource(path / 'bag_0.mcap').topics.items()} == QOS_WANT
    assert rosbags.rosbag2.reader.parse_qos is rosbags.rosbag2.metadata.parse_qos  # unpatched after open

    # rosbag2's format: metadata.yaml and each MCAP channel hold the same version 8 string (rmw enums).
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    stored = {
        t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
        for t in meta['topics_with_message_count']
    }
    with (path / 'bag_0.mcap').open('rb') as f:
        summary = make_reader(f).get_summary()
    assert {c.topic: c.metadata['offered_qos_profiles'] for c in summary.channels.values()} == stored
    assert stored['/plain'] == ''
    (durable,) = yaml.safe_load(stored['/keyframes/pose'])
    assert durable['history'] == durable['reliability'] == durable['durability'] == durable['liveliness'] == 1
    assert durable['depth'] == 1000
    assert durable['deadline'] == {'sec': 9223372036, 'nsec': 854775807}
    assert {t: parse_offered_qos(v) for t, v in stored.items()} == QOS_WANT

    # rosbags' own reader (which parses it as rosbag2 does) agrees.
    with Reader(path) as rosbag2:
        qos = {c.topic: c.ext.offered_qos_profiles for c in rosbag2.connections}
    (kf,) = qos['/keyframes/pose']
    assert (kf.history, kf.depth) == (QosHistory.KEEP_LAST, 1000)
    assert (kf.reliability, kf.durability) == (QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
    assert qos['/camera/image_raw'][0].reliability == QosReliability.BEST_EFFORT
    assert [q.history for q in qos['/two']] == [QosHistory.KEEP_LAST, QosHistory.KEEP_ALL]
    assert qos['/plain'] == []


def test_writer_qos_declarations(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/a', 'std_msgs/msg/String', DURABLE)
        writer.add_topic('/a', 'std_msgs/msg/String', [DURABLE])  # the same: no-op
        writer.add_topic('/a', 'std_msgs/msg/String')  # no QoS given: no-op
        with pytest.raises(
            BagError, match='topic /a is declared with reliable transient_local keep_last 1000'
        ):
            writer.add_topic('/a', 'std_msgs/msg/String', SENSOR)
        writer.write('/b', T['std_msgs/msg/String'](data='x'), 1)
        with pytest.raises(BagError, match='topic /b is declared with no QoS already'):
            writer.add_topic('/b', 'std_msgs/msg/String', DURABLE)
        with pytest.raises(TypeError, match='qos must be OfferedQos'):
            writer.add_topic('/c', 'std_msgs/msg/String', {'durability': 'transient_local'})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="durability 'latched' is not one of"):
        OfferedQos(durability='latched')  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='depth -1'):
        OfferedQos(depth=-1)


def test_rosbag2_qos_formats_and_malformed_ones(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import yaml

    path = write_qos_bag(tmp_path / 'bag')
    version9 = {
        'history': 'keep_last', 'depth': 3, 'reliability': 'reliable', 'durability': 'transient_local',
        'deadline': {'sec': 0, 'nsec': 0}, 'lifespan': {'sec': 0, 'nsec': 0}, 'liveliness': 'automatic',
        'liveliness_lease_duration': {'sec': 0, 'nsec': 0}, 'avoid_ros_namespace_conventions': False,
    }  # fmt: skip
    values = {
        '/keyframes/pose': JAZZY_RECORDED,
        '/camera/image_raw': [version9],  # version 9: a list, policies by name
        '/two': '- history: [unclosed',  # not YAML
        '/plain': '{history: 1, depth: 1, reliability: 1, durability: 1}',  # a mapping, not a list
    }
    meta_path = path / 'metadata.yaml'
    meta = yaml.safe_load(meta_path.read_text())
    for topic in meta['rosbag2_bagfile_information']['topics_with_message_count']:
        topic['topic_metadata']['offered_qos_profiles'] = values[topic['topic_metadata']['name']]
    meta_path.write_text(yaml.safe_dump(meta))
    with caplog.at_level(logging.WARNING), open_bag(path) as reader:
        got = {t: i.offered_qos for t, i in reader.topics.items()}
        assert len(list(reader.messages())) == 12
    assert got == {
        '/keyframes/pose': (RECORDED,),
        '/camera/image_raw': (OfferedQos('reliable', 'transient_local', depth=3),),
        '/two': (),
        '/plain': (),
    }
    warned = '\n'.join(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    assert 'topic /two: ignoring its malformed offered_qos_profiles: not YAML' in warned
    assert 'topic /plain: ignoring its malformed offered_qos_profiles: a list of profiles expected' in warned

    # In MCAP channel metadata (a bare file): missing and unknown policies.
    from mcap.writer import Writer

    from ibr_ros.bag.typestore import ros2msg_definition

    bare = tmp_path / 'bad_qos.mcap'
    with bare.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema(
            'std_msgs/msg/String', 'ros2msg', ros2msg_definition('std_msgs/msg/String').encode()
        )
        no_durability = '- {history: 1, depth: 1, reliability: 1}'
        unknown_reliability = '- {history: 1, depth: 1, reliability: 9, durability: 1}'
        for i, qos in enumerate([no_durability, unknown_reliability, JAZZY_RECORDED]):
            channel = writer.register_channel(f'/t{i}', 'cdr', schema, {'offered_qos_profiles': qos})
            cdr = bytes(TYPESTORE.serialize_cdr(T['std_msgs/msg/String'](data='x'), 'std_msgs/msg/String'))
            writer.add_message(channel, log_time=SEC + i, data=cdr, publish_time=SEC + i)
        writer.finish()
    caplog.clear()
    with caplog.at_level(logging.WARNING), open_bag(bare) as reader:
        assert {t: i.offered_qos for t, i in reader.topics.items()} == {
            '/t0': (), '/t1': (), '/t2': (RECORDED,)
        }  # fmt: skip
    warned = '\n'.join(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    assert 'topic /t0: ignoring its malformed offered_qos_profiles: profile 0: no durability' in warned
    assert 'topic /t1: ignoring its malformed offered_qos_profiles: profile 0: reliability 9' in warned


def test_ros1_bag_comes_out_as_ros2(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer

    noetic = get_typestore(Stores.ROS1_NOETIC)
    N = noetic.types
    hdr = N['std_msgs/msg/Header'](
        seq=4, stamp=N['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='cam'
    )
    img = N['sensor_msgs/msg/Image'](
        header=hdr, height=2, width=3, encoding='rgb8', is_bigendian=0, step=9, data=np.full(18, 1, np.uint8)
    )
    roi = N['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    info = N['sensor_msgs/msg/CameraInfo'](
        header=hdr,
        height=2,
        width=3,
        distortion_model='plumb_bob',
        D=np.array([0.1, 0.0, 0.0, 0.0, 0.0]),
        K=np.array([100.0, 0, 1.5, 0, 100.0, 1.0, 0, 0, 1]),
        R=np.eye(3).ravel(),
        P=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
    path = tmp_path / 'old.bag'
    with Writer(path) as writer:
        conn = writer.add_connection('/cam/image_raw', 'sensor_msgs/msg/Image', typestore=noetic)
        conn_info = writer.add_connection('/cam/camera_info', 'sensor_msgs/msg/CameraInfo', typestore=noetic)
        writer.write(conn, SEC, noetic.serialize_ros1(img, 'sensor_msgs/msg/Image'))
        writer.write(conn_info, SEC + 1, noetic.serialize_ros1(info, 'sensor_msgs/msg/CameraInfo'))
    with open_bag(path) as reader:
        assert reader.storage == 'ros1'
        assert reader.topics['/cam/camera_info'].serialization_format == 'cdr'
        got = [(m.topic, m.timestamp_ns, m.rawdata) for m in reader.messages()]
        ros2_info = next(iter(reader.messages(['/cam/camera_info']))).msg
    assert got == expected(
        [('/cam/image_raw', image(SEC, 1), SEC), ('/cam/camera_info', camera_info(SEC), SEC + 1)]
    )
    assert type(ros2_info) is T['sensor_msgs/msg/CameraInfo']
    assert ros2_info.k[0] == 100.0


# -- atomic writing -----------------------------------------------------------------------------


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    seen: list[bool] = []

    def fail() -> None:
        with BagWriter(tmp_path / 'bag') as writer:
            writer.write('/pose', pose(SEC, 1.0), SEC)
            seen.append(writer.tmp_path.is_dir())
            raise RuntimeError('boom')

    with pytest.raises(RuntimeError, match='boom'):
        fail()
    assert seen == [True]
    assert list(tmp_path.iterdir()) == []


def test_existing_target(tmp_path: Path) -> None:
    target = tmp_path / 'bag'
    target.mkdir()
    with pytest.raises(BagError, match='exists already'):
        BagWriter(target).open()
    with BagWriter(target, overwrite=True) as writer:
        writer.write_raw(
            '/pose',
            'geometry_msgs/msg/PoseStamped',
            TYPESTORE.serialize_cdr(pose(5, 1.0), 'geometry_msgs/msg/PoseStamped'),
            5,
        )
    assert [p.name for p in tmp_path.iterdir()] == ['bag']
    with open_bag(target) as reader:
        assert reader.message_count == 1


def test_writer_rejects_bad_topics(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/a', 'std_msgs/msg/String')
        writer.add_topic('/a', 'std_msgs/msg/String')
        with pytest.raises(BagError, match='topic /a is std_msgs/msg/String'):
            writer.add_topic('/a', 'sensor_msgs/msg/Image')
        with pytest.raises(BagError, match="unknown message type 'my_msgs/msg/Thing'"):
            writer.add_topic('/b', 'my_msgs/msg/Thing')
        with pytest.raises(BagError, match='cannot serialise'):
            writer.write('/c', object(), 1)


# -- errors ------------------------------------------------------------------------------------


def broken_bags(good: Path, folder: Path) -> dict[str, tuple[Path, str]]:
    """Name -> (path, expected problem), made from the good bag ``good``."""
    data = (good / f'{good.name}_0.mcap').read_bytes()
    truncated = folder / 'truncated.mcap'
    truncated.write_bytes(data[: len(data) // 2])
    corrupt = folder / 'corrupt.mcap'
    corrupt.write_bytes(corrupt_chunk(data))
    garbage = folder / 'garbage.db3'
    garbage.write_bytes(b'not a database at all' * 10)
    empty = folder / 'empty'
    with BagWriter(empty) as writer:
        writer.add_topic('/a', 'std_msgs/msg/String')
    return {
        'missing': (folder / 'missing.mcap', 'no such file or directory'),
        'truncated': (truncated, 'truncated MCAP file (no footer); the recording may have been interrupted'),
        'corrupt': (corrupt, 'cannot read messages'),
        'garbage': (garbage, 'corrupt or unreadable SQLite bag'),
        'empty': (empty, 'bag contains no messages'),
        'unknown': (folder / 'notes.txt', "unknown storage '.txt'"),
    }


def test_errors_are_bag_errors(sample_bag: Path, tmp_path: Path) -> None:
    from ibr_ros.bag.info import bag_info

    (tmp_path / 'notes.txt').write_text('x')
    for name, (path, problem) in broken_bags(sample_bag, tmp_path).items():
        with pytest.raises(BagError) as info:
            bag_info(path)
        assert problem in info.value.problem, name
        assert str(info.value).startswith(f'{path}: ')


# -- detection ---------------------------------------------------------------------------------


def test_detect_topics(sample_bag: Path, caplog: pytest.LogCaptureFixture) -> None:
    with open_bag(sample_bag) as reader, caplog.at_level(logging.INFO):
        auto = detect_topics(reader)
        assert auto.image == '/cam/image_raw'
        assert not auto.image_compressed
        assert auto.camera_info == '/cam/camera_info'
        assert auto.pose == '/odom_pose'  # PoseStamped before /tf; two of them: alphabetical
        assert auto.pose_type == 'geometry_msgs/msg/PoseStamped'
        assert auto.navsat == '/fix'
        assert auto.depth == '/cam/depth/image_raw'
        assert auto.sky_mask is None
        assert 'several image topics' in caplog.text
        assert 'using /cam/image_raw' in caplog.text

        chosen = detect_topics(reader, image='/cam/image_raw/compressed', pose='/tf')
        assert chosen.image == '/cam/image_raw/compressed'
        assert chosen.image_compressed
        assert (chosen.pose, chosen.pose_type) == ('/tf', 'tf2_msgs/msg/TFMessage')
        with pytest.raises(BagError, match=r'pose topic /gps is not in the bag; topics: /cam/camera_info \('):
            detect_topics(reader, pose='/gps')
        with pytest.raises(BagError, match='image topic /fix is sensor_msgs/msg/NavSatFix, expected'):
            detect_topics(reader, image='/fix')


def test_find_bags(sample_bag: Path, tmp_path: Path) -> None:
    root = tmp_path / 'root'
    (root / 'sub').mkdir(parents=True)
    shutil.copytree(sample_bag, root / 'sub' / 'dirbag')
    (root / 'sub' / 'dirbag' / 'inner.mcap').write_bytes(b'')
    (root / 'a.mcap').write_bytes(b'')
    (root / 'b.bag').write_bytes(b'')
    (root / 'readme.txt').write_text('')
    (root / '.hidden.tmp-1').mkdir()
    (root / '.hidden.tmp-1' / 'x.mcap').write_bytes(b'')
    assert find_bags(root) == [root / 'a.mcap', root / 'b.bag', root / 'sub' / 'dirbag']
    assert find_bags(root / 'sub' / 'dirbag') == [root / 'sub' / 'dirbag']
    with pytest.raises(BagError, match='no such file or directory'):
        find_bags(tmp_path / 'nope')


def test_image_dimensions() -> None:
    assert image_dimensions(PNG_4X3) == (4, 3)
    assert image_dimensions(JPEG_5X7) == (5, 7)
    assert image_dimensions(b'GIF89a') is None
