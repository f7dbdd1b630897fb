# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The bag_player's parameter table and the configuration built from it."""

from __future__ import annotations

from dataclasses import dataclass

from ibr_ros.bag.playback import PlaybackPolicy, parse_remaps, parse_topic_qos
from ibr_ros.errors import UserError
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Topic,
    Values,
)

__all__ = ['BAG_PLAYER', 'BagPlayerConfig']


@dataclass(frozen=True)
class BagPlayerConfig:
    """What the bag_player node runs with (see :data:`BAG_PLAYER` for each parameter).

    ``bag`` is '' when not given (the node refuses to start); ``playback`` holds ``rate``,
    ``flow_window`` and the QoS, remap and topic choices. ``clock_period_s`` = 1 / ``clock_rate_hz``;
    ``linger_s`` -1 = until shut down; ``wait_timeout_s``, ``progress_s`` and ``duration_s`` 0 = off.
    """

    bag: str
    playback: PlaybackPolicy
    loop: bool
    start_offset_s: float
    duration_s: float
    publish_clock: bool
    clock_period_s: float
    wait_for_subscribers: int
    wait_timeout_s: float
    wait_topics: tuple[str, ...]
    linger_s: float
    ack_timeout_s: float
    progress_s: float


def _build(v: Values) -> BagPlayerConfig:
    try:
        remap = parse_remaps(v.texts('remap'))
        overrides = parse_topic_qos(v.texts('topic_qos'))
    except ValueError as exc:  # the text names the parameter and the entry
        raise UserError(str(exc)) from exc
    return BagPlayerConfig(
        bag=v.text('bag'),
        playback=PlaybackPolicy(
            topics=tuple(v.texts('topics')),
            remap=remap,
            topic_qos=overrides,
            qos_depth=v.integer('qos_depth'),
            max_durable_depth=v.integer('max_durable_depth'),
            use_recorded_qos=v.flag('use_recorded_qos'),
            rate=v.number('rate'),
            flow_window=v.integer('flow_window'),
        ),
        loop=v.flag('loop'),
        start_offset_s=v.number('start_offset'),
        duration_s=v.number('duration'),
        publish_clock=v.flag('publish_clock'),
        clock_period_s=1.0 / v.number('clock_rate_hz'),
        wait_for_subscribers=v.integer('wait_for_subscribers'),
        wait_timeout_s=v.number('wait_timeout_s'),
        wait_topics=tuple(v.texts('wait_topics')),
        linger_s=v.number('linger_s'),
        ack_timeout_s=v.number('ack_timeout_s'),
        progress_s=v.number('progress_s'),
    )


_BIG = (0.0, 1e9)

BAG_PLAYER: ParamTable[BagPlayerConfig] = ParamTable(
    node='bag_player',
    summary=(
        'Replays a bag (rosbag2 directory, `.mcap`, `.db3` or ROS 1 `.bag`) with its original message '
        'types, paced by `rate`, and publishes `/clock`. Topics that cannot be replayed as ROS 2 Jazzy CDR '
        'and payloads that do not decode are skipped (counted, logged); QoS follows what the bag recorded '
        '(`use_recorded_qos`) or `topic_qos`. Exits 0 when the bag is done, 2 when the bag or a parameter '
        'cannot be used.'
    ),
    params=(
        Param(
            'bag',
            '',
            'bag to replay: rosbag2 directory, .mcap, .db3 or ROS 1 .bag file; must be given',
            comment='e.g. -p bag:=PATH',
        ),
        Param('rate', 1.0, 'playback speed factor; 0 = as fast as possible', _BIG),
        Param('loop', False, 'start again at the end instead of exiting'),
        Param('start_offset', 0.0, 'skip this many seconds at the start of the bag', _BIG),
        Param('duration', 0.0, 'play this many seconds of the bag; 0 = to the end', _BIG),
        Param(
            'topics',
            [],
            'bag topics to play; empty = all',
            comment="e.g. ['/camera/image_raw/compressed']",
        ),
        Param(
            'remap',
            [],
            "renames of bag topics, 'from:=to'",
            comment="""e.g. ['/camera/pose:=camera/pose'] (quote it: -p "remap:=[...]")""",
        ),
        Param('publish_clock', True, "publish the playback's bag time on /clock (for use_sim_time nodes)"),
        Param('clock_rate_hz', 100.0, '/clock messages per wall-clock second', (0.1, 1e4)),
        Param(
            'wait_for_subscribers',
            0,
            'start once every played topic (or each of wait_topics) has this many subscriptions',
            (0, 1000),
        ),
        Param('wait_timeout_s', 30.0, '... or after this many seconds anyway; 0 = wait forever', _BIG),
        Param('wait_topics', [], 'the topics (published names) to wait for; empty = every played topic'),
        Param(
            'qos_depth',
            100,
            'history depth of the volatile publishers: a few seconds of each topic',
            (1, 1000000),
            comment='DDS repairs what a reliable subscriber missed (within a heartbeat period, 3 s with '
            'Fast DDS) as long as the publisher still holds it.',
        ),
        Param(
            'flow_window',
            8,
            'rate 0: at most this many unacknowledged messages per topic (flow control)',
            (1, 1000000),
        ),
        Param(
            'use_recorded_qos',
            True,
            "offer the QoS the bag records its publishers offered (rosbag2's offered_qos_profiles)",
            comment='Transient local where they offered it, with a history of the recorded depth or the '
            "topic's message count if larger; recorded best effort is played reliable; publishers that "
            'offered different reliability or durability fall back to the default, as in ros2 bag play.',
        ),
        Param('max_durable_depth', 1000, 'largest history of a transient-local topic', (1, 1000000)),
        Param(
            'topic_qos',
            [],
            "QoS of bag topics, 'TOPIC:=POLICY[,POLICY...]'",
            comment='Policies: reliable, best_effort, volatile, transient_local, depth=N; e.g. '
            "['/keyframes/image:=transient_local,depth=50'].",
        ),
        Param(
            'linger_s',
            0.0,
            'keep the publishers (and their transient-local history) this long after the end (s); '
            '-1 = until shut down',
            (-1.0, 1e9),
        ),
        Param(
            'ack_timeout_s',
            10.0,
            'longest wait for reliable subscribers to acknowledge (rate 0, and at the end)',
            _BIG,
        ),
        Param('progress_s', 5.0, 'progress log period in seconds; 0 = off', _BIG),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    publishes=(
        Topic(
            '(the bag topics)',
            '(as recorded)',
            "each bag topic after `remap`, the bag's serialised messages unchanged",
            'reliable; transient local where recorded so',
        ),
        Topic(
            '/clock',
            'rosgraph_msgs/Clock',
            "the playback's bag time at `clock_rate_hz`, never ahead of the next message",
            'reliable',
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=('bag',),
        outputs=('<topic>',),
        latency='at `rate` > 0, how late each message went out after its due time',
        reasons=(
            ('empty', 'an empty payload, skipped'),
            ('encapsulation', 'a payload that is not CDR, skipped'),
            ('corrupt', 'a payload its type cannot decode, skipped'),
        ),
        model=(
            ('passes', 'passes over the bag started'),
            ('bag_time_s', 'bag time of the last message published, from the bag start'),
            ('duration_s', "the bag's duration"),
        ),
    ),
)
