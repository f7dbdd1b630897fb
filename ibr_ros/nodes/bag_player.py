# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``bag_player``: replays a bag with its original message types and publishes ``/clock``.

Topics, parameters and behaviour: ``doc/nodes.md`` (generated from
:data:`ibr_ros.node_config.BAG_PLAYER`); what is played and with which QoS:
:class:`ibr_ros.bag.playback.PlaybackPolicy`. This node does the ROS side: publishers with those
QoS, pacing on the wall clock, ``/clock``, waiting for subscribers and acknowledgements.

Publishers of image topics are created last, so a subscriber that discovers this player's image
publisher already knows its other topics (DDS announces endpoints in order). At rate 0 at most
``flow_window`` messages per topic go unacknowledged, so reliable subscribers receive everything and
the topics stay within that window of each other. Types ROS 2 Jazzy knows are decoded (checked before
publishing) with the rosbags CDR reader (no copy of array data), others with rclpy; the rosbags reader
is stricter than Fast CDR on three points, also skipped: strings without terminator or not UTF-8, and
more than 3 bytes after the message.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

import msg_utils
from ibr_ros.bag import TYPESTORE, BagMessage, BagReader, open_bag
from ibr_ros.bag.playback import PlayQos, play_window, undecodable
from ibr_ros.errors import UserError
from ibr_ros.node_config.bag_player import BAG_PLAYER
from ibr_ros.nodes.common import (
    EXIT_BAD_CONFIG,
    BadInput,
    declare_table,
    reliable_qos,
    run_node,
    start_diagnostics,
)
from msg_utils.flavor import message_class

EXIT_BAD_INPUT = EXIT_BAD_CONFIG  # a bag that cannot be played exits like a rejected parameter


def qos_profile(qos: PlayQos) -> QoSProfile:
    """The rclpy profile of ``qos`` (keep last)."""
    return QoSProfile(
        history=QoSHistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=QoSReliabilityPolicy.RELIABLE
        if qos.reliability == 'reliable'
        else QoSReliabilityPolicy.BEST_EFFORT,
        durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == 'transient_local'
        else QoSDurabilityPolicy.VOLATILE,
    )


def decoder(msgtype: str, cls: type) -> Callable[[bytes], object]:
    """Deserialiser of ``msgtype`` CDR: rosbags' Jazzy typestore (fast, no array copies), else rclpy."""
    if msgtype in TYPESTORE.types:
        return partial(TYPESTORE.deserialize_cdr, typename=msgtype)
    return partial(deserialize_message, message_type=cls)


@dataclass
class _Out:
    """A replayed topic: where it goes and how far it got."""

    name: str
    publisher: Publisher
    decode: Callable[[bytes], object]  # raises on a payload that is not a message of the topic's type
    depth: int  # history depth of the publisher
    durable: bool  # transient local
    count: int = 0
    unacked: int = 0  # upper bound of the messages in the publisher's history
    skipped: Counter[str] = field(default_factory=Counter)  # undecodable payloads by reason


class BagPlayer(Node):
    """Bag replay node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        cfg = BAG_PLAYER.build(declare_table(self, BAG_PLAYER))
        if not cfg.bag:
            raise UserError('parameter bag is required (-p bag:=PATH)')
        self.cfg = cfg
        self.bag_path = cfg.bag
        self.rate, self.loop, self.window = cfg.playback.rate, cfg.loop, cfg.playback.flow_window
        self.linger, self.ack_timeout, self.progress_s = cfg.linger_s, cfg.ack_timeout_s, cfg.progress_s
        self.wait_for, self.wait_timeout = cfg.wait_for_subscribers, cfg.wait_timeout_s
        self.clock_period = cfg.clock_period_s
        self.bag: BagReader = open_bag(self.bag_path)  # BagError names the path
        plan = cfg.playback.plan(self.bag)
        for warning in plan.warnings:
            self.get_logger().warning(warning)
        self.bad = BadInput(self)
        self.outs: dict[str, _Out] = {}
        for t in plan.topics:  # images last
            cls = message_class(t.msgtype)
            publisher = self.create_publisher(cls, t.name, qos_profile(t.qos))
            durable = t.qos.durability == 'transient_local'
            self.outs[t.topic] = _Out(t.name, publisher, decoder(t.msgtype, cls), t.qos.depth, durable)
        self.outs = {t: self.outs[t] for t in plan.bag_order}
        self.wait_outs = [self.outs[t] for t in plan.waited(cfg.wait_topics, self.resolve_topic_name)]
        self.clock_pub = (
            self.create_publisher(Clock, '/clock', reliable_qos(10)) if cfg.publish_clock else None
        )
        self.first_ns, self.stop_ns = play_window(self.bag, cfg.start_offset_s, cfg.duration_s)
        self._last_clock_wall = -1.0
        self._clock_ns = -1
        self.passes = 0
        self._bag_ns = self.bag.start_ns  # of the last message published
        self.diag = start_diagnostics(
            self, BAG_PLAYER.diagnostics, self._diagnostics, [o.name for o in self.outs.values()]
        )
        self.stopping = threading.Event()
        self.finished: Future = Future()
        self._thread = threading.Thread(target=self._run, name='bag_player', daemon=True)
        self.get_logger().info(
            f'playing {self.bag_path} ({self.bag.storage}, {self.bag.duration_s:.1f} s): '
            + ', '.join(f'{t} -> {o.name}' if t != o.name else t for t, o in self.outs.items())
            + f' at rate {self.rate:g}'
            + (' (as fast as possible)' if self.rate == 0 else '')
        )
        by_topic = {t.topic: str(t) for t in plan.topics}
        self.get_logger().info('QoS: ' + ', '.join(by_topic[t] for t in self.outs))

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        model = {
            'passes': self.passes,
            'bag_time_s': f'{(self._bag_ns - self.bag.start_ns) / 1e9:.3f}',
            'duration_s': f'{self.bag.duration_s:.3f}',
        }
        return {'rejected': self.bad.counts, 'model': model}

    # -- playback thread ---------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self.stopping.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)

    def _run(self) -> None:
        try:
            self._wait_for_subscribers()
            passes = 0
            while not self.stopping.is_set():
                published = self._play_once(passes)
                passes += 1
                if not self.loop:
                    break
                if not published and not self.stopping.is_set():  # looping would spin on nothing
                    raise UserError(f'{self.bag_path}: pass {passes} published no message; not looping')
            if not self.stopping.is_set():
                self._wait_acked()
            self._linger()
        except Exception as exc:  # a shutdown while publishing raises; anything else is logged
            if not self.stopping.is_set() and self.context.ok():
                self.get_logger().error(f'playback failed: {exc}')
                self.finished.set_result(EXIT_BAD_INPUT if isinstance(exc, UserError) else 1)
                return
        self.finished.set_result(0)

    def _linger(self) -> None:
        """Keep the publishers (and their transient-local history) for ``linger_s`` after the end."""
        if self.linger == 0 or self.stopping.is_set():
            return
        durable = [o.name for o in self.outs.values() if o.durable]
        how_long = 'until shut down' if self.linger < 0 else f'for {self.linger:g} s'
        self.get_logger().info(
            f'lingering {how_long}; history for late subscribers on {", ".join(durable) or "no topic"}'
        )
        self.stopping.wait(self.linger if self.linger > 0 else None)

    def _wait_for_subscribers(self) -> None:
        if self.wait_for <= 0:
            return
        self.get_logger().info(f'waiting for {self.wait_for} subscription(s) on every topic')
        deadline = time.monotonic() + self.wait_timeout if self.wait_timeout > 0 else float('inf')
        next_note = time.monotonic() + 10.0
        while not self.stopping.is_set():
            short = [o.name for o in self.wait_outs if o.publisher.get_subscription_count() < self.wait_for]
            if not short:
                return
            if time.monotonic() >= next_note:  # a wait without end says what it waits for
                next_note += 10.0
                self.get_logger().info(
                    f'still waiting for {self.wait_for} subscription(s) on {", ".join(short)}'
                )
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f'starting after {self.wait_timeout:g} s; too few subscriptions on {", ".join(short)}'
                )
                return
            self._publish_clock(self.first_ns, force=True)
            self.stopping.wait(0.02)

    def _messages(self) -> Iterator[BagMessage]:
        return self.bag.messages(list(self.outs), start_ns=self.first_ns, end_ns=self.stop_ns)

    def _play_once(self, passes: int) -> int:
        """Play the bag (from ``start_offset`` for ``duration``) once; the number of messages published."""
        start_wall = time.monotonic()
        last_progress = start_wall
        span_ns = max(1, min(self.stop_ns - 1, self.bag.end_ns) - self.first_ns)
        count = last_ns = 0
        n_skipped = 0
        skipped_before = {t: o.skipped.copy() for t, o in self.outs.items()}
        self._clock_ns = -1  # a new pass may go back in time
        self._publish_clock(self.first_ns, force=True)
        self.passes = passes + 1
        for msg in self._messages():
            out = self.outs[msg.topic]
            self.diag.received('bag')
            if problem := undecodable(msg.rawdata, out.decode):
                self._skip(out, msg, *problem)
                n_skipped += 1
                continue
            if self.rate > 0:
                due = start_wall + (msg.timestamp_ns - self.first_ns) / 1e9 / self.rate
                if not self._sleep_until(due, start_wall, msg.timestamp_ns):
                    return count
            elif self.stopping.is_set():
                return count
            self._publish_clock(msg.timestamp_ns)
            if self.rate == 0:
                self._flow_control(out)
            out.publisher.publish(msg.rawdata)
            self.diag.published(out.name)
            if self.rate > 0:
                self.diag.measured(max(0.0, time.monotonic() - due))
            self._bag_ns = msg.timestamp_ns
            out.count += 1
            out.unacked += 1
            count += 1
            last_ns = msg.timestamp_ns
            now = time.monotonic()
            if self.progress_s > 0 and now - last_progress >= self.progress_s:
                last_progress = now
                self.get_logger().info(
                    f'{count} messages, bag time {(msg.timestamp_ns - self.bag.start_ns) / 1e9:.2f} s '
                    f'({100.0 * (msg.timestamp_ns - self.first_ns) / span_ns:.0f}%)'
                    + (f', {n_skipped} undecodable skipped' if n_skipped else '')
                )
        if self.stopping.is_set():
            return count
        if count:
            self._publish_clock(last_ns, force=True)  # the last message's time, whatever the ticks
        wall = time.monotonic() - start_wall
        what = f'pass {passes + 1} done' if self.loop else 'done'
        self.get_logger().info(
            f'{what}: {count} messages in {wall:.2f} s ({count / max(wall, 1e-9):.0f} msg/s), '
            + ', '.join(f'{o.name} {o.count}' for o in self.outs.values())
        )
        if n_skipped:
            per_topic = {o.name: o.skipped - skipped_before[t] for t, o in self.outs.items()}
            self.get_logger().warning(
                f'{what}: {n_skipped} undecodable messages skipped: '
                + ', '.join(
                    f'{name} {c.total()} ({", ".join(f"{r} {n}" for r, n in sorted(c.items()))})'
                    for name, c in per_topic.items()
                    if c
                )
            )
        return count

    def _skip(self, out: _Out, msg: BagMessage, reason: str, error: str) -> None:
        """Count and log (throttled per reason) an undecodable message instead of publishing it."""
        out.skipped[reason] += 1
        bag_s = (msg.timestamp_ns - self.bag.start_ns) / 1e9
        self.bad(
            reason,
            f'{msg.topic} at bag time {msg.timestamp_ns} ns (+{bag_s:.3f} s): not a {msg.msgtype}, '
            f'skipped: {error}',
        )

    def _flow_control(self, out: _Out) -> None:
        """At rate 0: at most ``flow_window`` (and never more than the history depth) messages of a
        topic unacknowledged, so a reliable subscriber loses nothing and its topics stay within a
        window of each other (a subscriber matching them by stamp holds only that many pending).
        """
        limit = min(out.depth, self.window)
        if out.unacked >= max(1, limit // 2) and out.publisher.wait_for_all_acked(Duration()):
            out.unacked = 0  # all acknowledged: cheap check, no wait
        if out.unacked < limit:
            return
        if not self._acked(out, self.ack_timeout) and not self.stopping.is_set():
            self.get_logger().warning(
                f'{out.name}: subscribers did not acknowledge within {self.ack_timeout:g} s; going on',
                throttle_duration_sec=10.0,
            )
        out.unacked = 0

    def _sleep_until(self, due: float, start_wall: float, next_ns: int) -> bool:
        """Sleep until wall time ``due``, publishing /clock meanwhile; False if stopping."""
        while True:
            now = time.monotonic()
            if self.stopping.is_set():
                return False
            if now >= due:
                return True
            bag_ns = self.first_ns + round((now - start_wall) * self.rate * 1e9)
            self._publish_clock(min(bag_ns, next_ns))
            wake = due if self.clock_pub is None else min(due, self._last_clock_wall + self.clock_period)
            self.stopping.wait(max(0.0, wake - now))

    def _publish_clock(self, bag_ns: int, *, force: bool = False) -> None:
        """Publish ``bag_ns`` on /clock if a tick is due (or ``force``); the clock never goes back."""
        if self.clock_pub is None:
            return
        now = time.monotonic()
        if not force and now - self._last_clock_wall < self.clock_period:
            return
        self._last_clock_wall = now
        self._clock_ns = max(self._clock_ns, bag_ns)
        self.clock_pub.publish(Clock(clock=msg_utils.ns_to_stamp(self._clock_ns)))

    def _acked(self, out: _Out, timeout: float) -> bool:
        """Wait up to ``timeout`` s for all of ``out``'s messages to be acknowledged; False if not."""
        deadline = time.monotonic() + timeout
        while not self.stopping.is_set():
            left = deadline - time.monotonic()
            if out.publisher.wait_for_all_acked(Duration(seconds=min(0.1, max(0.0, left)))):
                return True
            if left <= 0:
                break
        return False

    def _wait_acked(self) -> None:
        """Give reliable subscribers up to ``ack_timeout_s`` to acknowledge (or get repaired) everything."""
        deadline = time.monotonic() + self.ack_timeout
        late = [o.name for o in self.outs.values() if not self._acked(o, deadline - time.monotonic())]
        if late and not self.stopping.is_set():
            self.get_logger().warning(f'not acknowledged within {self.ack_timeout:g} s on {", ".join(late)}')

    def destroy_node(self) -> None:
        self.stop()
        self.bag.close()
        super().destroy_node()


def play(node: BagPlayer) -> int:
    """Spin ``node`` until its bag is played (the ``spin`` of :func:`run_node`); its exit code."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    node.start()
    executor.spin_until_future_complete(node.finished)
    return node.finished.result() if node.finished.done() else 0


def main(args: list[str] | None = None) -> int:
    """Play the bag; 0 when done (or interrupted), 2 when the bag or a parameter is bad."""
    return run_node(BagPlayer, args if args is not None else sys.argv, spin=play)


if __name__ == '__main__':
    sys.exit(main())
