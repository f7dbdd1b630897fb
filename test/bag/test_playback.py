# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The bag_player's playback policy (ibr_ros.bag.playback): QoS, remaps, playable topics, time window."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ibr_ros.bag import (
    TYPESTORE,
    OfferedQos,
    PlaybackPolicy,
    PlayQos,
    TopicInfo,
    parse_remaps,
    parse_topic_qos,
    play_qos,
    play_window,
    same_definition,
    unplayable,
)
from ibr_ros.errors import UserError
from ibr_ros.nodes.common import model_qos

MODEL = OfferedQos.from_profile(model_qos())


def test_play_qos_follows_the_recording_and_overrides():
    def qos(count: int, *offered: OfferedQos, **kw) -> tuple[PlayQos, str]:
        info = TopicInfo('/t', 'std_msgs/msg/String', count, 'cdr', offered)
        return play_qos(info, depth=100, max_durable_depth=1000, **kw)

    latched = OfferedQos('reliable', 'transient_local', depth=1)
    assert qos(7) == (PlayQos('reliable', 'volatile', 100, 'default'), '')
    assert qos(25, latched) == (PlayQos('reliable', 'transient_local', 25, 'recorded'), '')  # all 25 kept
    assert qos(25, OfferedQos.from_profile(model_qos()))[0].depth == 1000
    assert qos(4, OfferedQos('reliable', 'transient_local', 'unknown', 0))[0].depth == 4  # as discovered
    assert qos(25, latched, latched)[0].durability == 'transient_local'  # two publishers, same QoS
    durable, note = qos(5000, latched)
    assert (durable.depth, note) == (1000, 'history of 5000 capped at max_durable_depth')
    sensor, note = qos(7, OfferedQos('best_effort', 'volatile', depth=5))
    assert (sensor, 'played reliable' in note) == (PlayQos('reliable', 'volatile', 100, 'recorded'), True)
    mixed, note = qos(7, latched, OfferedQos())
    assert (mixed.durability, mixed.source, 'offered different QoS' in note) == ('volatile', 'default', True)
    assert qos(7, latched, use_recorded=False)[0] == PlayQos()
    overrides = parse_topic_qos(['/t:=transient_local', '/u:= Best_Effort, depth=5'])
    assert overrides == {
        '/t': {'durability': 'transient_local'},
        '/u': {'reliability': 'best_effort', 'depth': 5},
    }
    assert qos(7, override=overrides['/t'])[0] == PlayQos('reliable', 'transient_local', 7, 'override')
    assert qos(7, latched, override=overrides['/u'])[0] == PlayQos(
        'best_effort', 'transient_local', 5, 'override'
    )
    for bad in ('/t', '/t:=', ':=reliable', '/t:=latched', '/t:=depth=0', '/t:=reliable,depth=x'):
        with pytest.raises(ValueError, match='parameter topic_qos'):
            parse_topic_qos([bad])


def test_remaps_are_from_to_pairs():
    assert parse_remaps([' /a := b ', '/c:=/d']) == {'/a': 'b', '/c': '/d'}
    for bad in ('/a', '/a:=', ':=b', '/a:= '):
        with pytest.raises(ValueError, match=r"parameter remap: .* is not of the form 'from:=to'"):
            parse_remaps([bad])


def _store(definitions: dict[str, str]):
    store = get_typestore(Stores.EMPTY)
    for name, text in definitions.items():
        store.register(get_types_from_msg(text, name))
    return store


def test_the_bag_players_definition_check_is_the_readers():
    """A bag that defines a Jazzy type differently is not played; one whose definition cannot be
    hashed (incomplete) is trusted by the type's name; ROS 1 data is CDR once converted."""
    string = TopicInfo('/s', 'std_msgs/msg/String', 1, 'cdr')
    same = _store({'std_msgs/msg/String': 'string data'})
    other = _store({'std_msgs/msg/String': 'int32 data'})
    incomplete = _store({'std_msgs/msg/String': 'my_pkg/msg/Missing data'})
    assert (same_definition(same, string.msgtype), same_definition(other, string.msgtype)) == (True, False)
    assert same_definition(incomplete, string.msgtype) is None
    assert unplayable(string, 'mcap', same) == unplayable(string, 'mcap', incomplete) == ''
    assert unplayable(string, 'mcap', other) == 'the bag defines the type differently from ROS 2 Jazzy'
    assert unplayable(string, 'ros1', other) == ''  # the reader converted it to Jazzy's definition
    assert unplayable(string, 'mcap', TYPESTORE, installed=lambda t: False) == (
        'no Python message class installed'
    )
    ros1 = TopicInfo('/c', 'my_pkg/msg/Custom', 1, 'ros1')
    assert unplayable(ros1, 'ros1', TYPESTORE) == 'ros1 data of a type ROS 2 Jazzy does not know'


def _bag(*topics: TopicInfo, storage: str = 'mcap', start_ns: int = 10, end_ns: int = 20):
    return SimpleNamespace(
        path='b.mcap',
        topics={t.name: t for t in topics},
        storage=storage,
        typestore=TYPESTORE,
        start_ns=start_ns,
        end_ns=end_ns,
    )


IMAGE = TopicInfo('/camera/image_raw', 'sensor_msgs/msg/Image', 3, 'cdr')
INFO = TopicInfo('/camera/camera_info', 'sensor_msgs/msg/CameraInfo', 3, 'cdr')
POSE = TopicInfo('/camera/pose', 'geometry_msgs/msg/PoseStamped', 3, 'cdr', (MODEL,))
CUSTOM = TopicInfo('/custom', 'my_pkg/msg/Custom', 3, 'ros1')


def test_plan_plays_images_last_remaps_and_skips_with_warnings():
    policy = PlaybackPolicy(
        remap={'/camera/pose': 'camera/pose', '/nope': 'x'}, topic_qos={'/gone': {'depth': 3}}
    )
    plan = policy.plan(_bag(IMAGE, INFO, CUSTOM, POSE))
    assert [t.topic for t in plan.topics] == ['/camera/camera_info', '/camera/pose', '/camera/image_raw']
    assert plan.bag_order == ('/camera/image_raw', '/camera/camera_info', '/camera/pose')
    assert [t.name for t in plan.topics] == ['/camera/camera_info', 'camera/pose', '/camera/image_raw']
    assert plan.warnings == (
        'remap of topics that are not played: /nope',
        'topic_qos of topics that are not played: /gone',
        'skipping /custom (my_pkg/msg/Custom): ros1 data of a type ROS 2 Jazzy does not know',
    )
    assert str(plan.topics[1]) == '/camera/pose: reliable transient_local depth 1000 (recorded)'


def test_plan_at_rate_0_caps_volatile_histories_at_the_flow_window():
    plan = PlaybackPolicy(rate=0.0, flow_window=8).plan(_bag(INFO, POSE))
    assert [str(t) for t in plan.topics] == [
        '/camera/camera_info: reliable volatile depth 8 (default, flow_window at rate 0)',
        '/camera/pose: reliable transient_local depth 1000 (recorded)',  # durable: its whole history
    ]


def test_plan_refuses_missing_or_unplayable_topics_and_unknown_wait_topics():
    with pytest.raises(UserError, match=r'b\.mcap: no topic /x in the bag'):
        PlaybackPolicy(topics=('/x',)).plan(_bag(INFO))
    with pytest.raises(UserError, match='none of the topics can be played'):
        PlaybackPolicy().plan(_bag(CUSTOM))
    plan = PlaybackPolicy(remap={'/camera/pose': 'camera/pose'}).plan(_bag(IMAGE, POSE))
    resolve = lambda name: name if name.startswith('/') else f'/{name}'  # noqa: E731
    assert plan.waited([], resolve) == ('/camera/image_raw', '/camera/pose')
    assert plan.waited(['/camera/pose'], resolve) == ('/camera/pose',)
    with pytest.raises(UserError, match=r'wait_topics: /camera/camera_info not played \(played: '):
        plan.waited(['/camera/camera_info'], resolve)


def test_play_window():
    bag = _bag(INFO, start_ns=1_000_000_000, end_ns=3_000_000_000)
    assert play_window(bag, 0.0, 0.0) == (1_000_000_000, 3_000_000_001)
    assert play_window(bag, 0.5, 1.0) == (1_500_000_000, 2_500_000_000)
    with pytest.raises(UserError, match=r'start_offset 2\.5 s is past the end of the bag'):
        play_window(bag, 2.5, 0.0)
