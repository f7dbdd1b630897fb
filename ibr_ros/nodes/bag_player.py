"""``bag_player``: replays a bag with its original message types and publishes ``/clock``.

Reads whatever :func:`ibr_ros.bag.open_bag` reads (rosbag2 directory, ``.mcap``, ``.db3``, ROS 1
``.bag``; ROS 1 messages arrive converted to ROS 2 CDR) and publishes every message's serialised
bytes unchanged on the bag's topic (after ``remap``). Topics whose type has no Python message class
installed, or whose data is not Jazzy CDR, are skipped with a warning.

QoS per topic (logged at start): reliable (which reaches best effort and reliable subscribers alike)
and volatile with ``qos_depth``, unless the bag records the QoS its publishers offered (rosbag2's
``offered_qos_profiles``, which ``ibr process`` and ``ros2 bag record`` write; ``use_recorded_qos``):
then transient local where they offered it, with a history of the recorded depth or the topic's
message count if larger, at most ``max_durable_depth``, so that a subscriber that asks for transient
local (e.g. a ``view_renderer`` for ``keyframes/*``) matches and, joining late, still gets the topic's
history. Recorded best effort is played reliable all the same; publishers that offered different
reliability or durability fall back to the default, as in ``ros2 bag play``. ``topic_qos`` overrides
per bag topic: ``'TOPIC:=POLICY[,POLICY...]'`` with ``reliable``, ``best_effort``, ``volatile``,
``transient_local``, ``depth=N``. Transient-local history lives as long as the player: ``linger_s``
keeps it after the bag is done.

Every message is checked before it goes out: a payload that does not decode as its topic's type
(empty, no CDR header, truncated, lengths past its end, ...) is never published (a 0-byte payload
would never be acknowledged and stall the topic); it is counted by reason (``empty``,
``encapsulation``, ``corrupt``), logged (throttled, with topic, bag time and the decode error) and
summed up when the bag is done. Types ROS 2 Jazzy knows are decoded with the rosbags CDR reader (no
copy of array data: ~0.04 ms for a 640x360 rgb8 Image), others with rclpy. The rosbags reader is
stricter than Fast CDR on three points, also skipped: strings without terminator or not UTF-8, and
more than 3 bytes after the message.

Messages are paced on the wall clock: bag time since ``start_offset``, divided by ``rate`` (0 = as
fast as possible). ``/clock`` (``rosgraph_msgs/Clock``) carries the playback's bag time at
``clock_rate_hz``, never ahead of the next message, so nodes can run with ``use_sim_time``. With
``wait_for_subscribers`` > 0 playback starts once every topic of ``wait_topics`` (published names;
empty = every played topic) has that many matched subscriptions (``wait_timeout_s`` 0: however long
that takes). Publishers of image topics are created last, so a subscriber that discovers this
player's image publisher already knows its other topics (DDS announces endpoints in order). DDS
repairs what a reliable subscriber missed (within a heartbeat period, 3 s with Fast DDS) as long as
the publisher still holds it: at rate > 0 ``qos_depth`` should cover a few seconds of each topic; at
rate 0 the player lets at most ``flow_window`` messages per topic go unacknowledged, so reliable
subscribers receive everything and the topics stay within that window of each other. The process
exits 0 when the bag is done (unless ``loop``), after reliable subscribers acknowledged everything
or ``ack_timeout_s``; a bag or parameter that cannot be used is one error line and exit code 2.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Literal

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

import msg_utils
from ibr_ros.bag import TYPESTORE, BagMessage, BagReader, TopicInfo, open_bag
from ibr_ros.errors import UserError
from ibr_ros.nodes.common import EXIT_BAD_CONFIG, BadInput, declare, reliable_qos, run_node
from msg_utils.flavor import message_class

EXIT_BAD_INPUT = EXIT_BAD_CONFIG  # a bag that cannot be played exits like a rejected parameter

#: Encapsulation headers of plain CDR (big, little endian): what ROS 2 Jazzy publishes and records.
CDR_HEADERS = (b'\x00\x00', b'\x00\x01')


@dataclass(frozen=True)
class PlayQos:
    """The QoS a topic is played with, and where it comes from (``default``, ``recorded``, ``override``)."""

    reliability: Literal['reliable', 'best_effort'] = 'reliable'
    durability: Literal['volatile', 'transient_local'] = 'volatile'
    depth: int = 100
    source: str = 'default'

    def profile(self) -> QoSProfile:
        return QoSProfile(
            history=QoSHistoryPolicy.KEEP_LAST,
            depth=self.depth,
            reliability=QoSReliabilityPolicy.RELIABLE
            if self.reliability == 'reliable'
            else QoSReliabilityPolicy.BEST_EFFORT,
            durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
            if self.durability == 'transient_local'
            else QoSDurabilityPolicy.VOLATILE,
        )

    def __str__(self) -> str:
        return f'{self.reliability} {self.durability} depth {self.depth} ({self.source})'


_POLICY_WORDS = {'reliable', 'best_effort', 'volatile', 'transient_local'}


def parse_topic_qos(entries: list[str]) -> dict[str, dict[str, str | int]]:
    """``['TOPIC:=transient_local,depth=50', ...]`` -> ``{TOPIC: {'durability': ..., 'depth': 50}}``.

    Raises:
        ValueError: An entry that is not ``TOPIC:=POLICY[,POLICY...]`` with known policies.

    """
    out: dict[str, dict[str, str | int]] = {}
    for entry in entries:
        topic, sep, spec = entry.partition(':=')
        policies: dict[str, str | int] = {}
        for word in (w.strip().lower() for w in spec.split(',')):
            if word in _POLICY_WORDS:
                policies['reliability' if word in {'reliable', 'best_effort'} else 'durability'] = word
            elif word.startswith('depth=') and word[6:].isdigit() and int(word[6:]) > 0:
                policies['depth'] = int(word[6:])
            else:
                policies = {}
                break
        if not sep or not topic.strip() or not policies:
            raise ValueError(
                f"parameter topic_qos: {entry!r} is not of the form 'TOPIC:=POLICY[,POLICY...]' "
                'with reliable, best_effort, volatile, transient_local, depth=N'
            )
        out[topic.strip()] = policies
    return out


def play_qos(
    info: TopicInfo,
    *,
    depth: int,
    max_durable_depth: int,
    use_recorded: bool = True,
    override: dict[str, str | int] | None = None,
) -> tuple[PlayQos, str]:
    """The QoS to play ``info``'s topic with (see module docstring) and a note for the log ('' if none)."""
    qos, notes = PlayQos(depth=depth), []
    offered = info.offered_qos if use_recorded else ()
    if len({(q.reliability, q.durability) for q in offered}) > 1:
        notes.append(f'its publishers offered different QoS ({"; ".join(map(str, offered))}): default')
    elif offered:
        durable = offered[0].durability == 'transient_local'
        qos = replace(qos, durability='transient_local' if durable else 'volatile', source='recorded')
        if offered[0].reliability == 'best_effort':
            notes.append('recorded best_effort, played reliable (which reaches best-effort subscribers too)')
    if override:
        qos = replace(qos, **{k: v for k, v in override.items() if k != 'depth'}, source='override')  # type: ignore[arg-type]
    if qos.durability == 'transient_local':
        wanted = max([info.count, *(q.depth for q in offered)])
        qos = replace(qos, depth=max(1, min(wanted, max_durable_depth)))
        if wanted > max_durable_depth:
            notes.append(f'history of {wanted} capped at max_durable_depth')
    if override and 'depth' in override:
        qos = replace(qos, depth=int(override['depth']))
    return qos, '; '.join(notes)


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


def decoder(msgtype: str, cls: type) -> Callable[[bytes], object]:
    """Deserialiser of ``msgtype`` CDR: rosbags' Jazzy typestore (fast, no array copies), else rclpy."""
    if msgtype in TYPESTORE.types:
        return partial(TYPESTORE.deserialize_cdr, typename=msgtype)
    return partial(deserialize_message, message_type=cls)


def undecodable(raw: bytes, decode: Callable[[bytes], object]) -> tuple[str, str] | None:
    """``(reason, error)`` when ``raw`` is not a CDR message that ``decode`` accepts; None when it is."""
    if not raw:
        return 'empty', 'payload of 0 bytes'
    if len(raw) < 4:
        return 'encapsulation', f'{len(raw)} bytes, shorter than the 4-byte CDR encapsulation header'
    if (head := bytes(raw[:2])) not in CDR_HEADERS:
        return 'encapsulation', f'{len(raw)} bytes: encapsulation {head.hex(" ")} is not CDR (00 00 or 00 01)'
    try:
        decode(raw)
    except Exception as exc:  # rosbags SerdeError, rclpy RMWError, ...
        return 'corrupt', f'{len(raw)} bytes: {exc or type(exc).__name__}'
    return None


def parse_remaps(pairs: list[str]) -> dict[str, str]:
    """``['from:=to', ...]`` -> ``{from: to}``; raises ValueError on a malformed pair."""
    remaps: dict[str, str] = {}
    for pair in pairs:
        src, sep, dst = pair.partition(':=')
        if not sep or not src.strip() or not dst.strip():
            raise ValueError(f"parameter remap: {pair!r} is not of the form 'from:=to'")
        remaps[src.strip()] = dst.strip()
    return remaps


class BagPlayer(Node):
    """Bag replay node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        big = {'limits': (0.0, 1e9)}
        self.bag_path = str(p('bag', '', 'bag to replay: rosbag2 directory, .mcap, .db3 or ROS 1 .bag'))
        self.rate = float(p('rate', 1.0, 'playback speed factor; 0 = as fast as possible', **big))
        self.loop = bool(p('loop', False, 'start again at the end instead of exiting'))
        self.start_offset = float(p('start_offset', 0.0, 'skip this many seconds of the bag', **big))
        self.duration = float(p('duration', 0.0, 'play this many seconds; 0 = to the end', **big))
        topics = p('topics', Parameter.Type.STRING_ARRAY, 'bag topics to play; empty = all')
        remaps = p('remap', Parameter.Type.STRING_ARRAY, "'from:=to' renames of bag topics")
        self.publish_clock = bool(p('publish_clock', True, 'publish the bag time on /clock'))
        clock_hz = float(p('clock_rate_hz', 100.0, '/clock messages per second', limits=(0.1, 1e4)))
        self.clock_period = 1.0 / clock_hz
        n_subs = p('wait_for_subscribers', 0, 'start at this many subscriptions per topic', limits=(0, 1000))
        self.wait_for = int(n_subs)
        self.wait_timeout = float(p('wait_timeout_s', 30.0, '... or after this long; 0 = never', **big))
        wait_topics = p('wait_topics', Parameter.Type.STRING_ARRAY, 'topics to wait for; empty = all')
        self.depth = int(p('qos_depth', 100, 'history depth of the volatile publishers', limits=(1, 1000000)))
        self.window = int(
            p('flow_window', 8, 'rate 0: unacknowledged messages per topic at most', limits=(1, 1000000))
        )
        use_recorded = bool(p('use_recorded_qos', True, 'offer the QoS recorded in the bag'))
        max_durable = int(p('max_durable_depth', 1000, 'most transient-local history', limits=(1, 1000000)))
        topic_qos = p('topic_qos', Parameter.Type.STRING_ARRAY, "'TOPIC:=POLICY,...' QoS of bag topics")
        linger = p(
            'linger_s', 0.0, 'keep publishers after the end (s); -1 = until shut down', limits=(-1.0, 1e9)
        )
        self.linger = float(linger)
        self.ack_timeout = float(p('ack_timeout_s', 10.0, 'longest wait for acknowledgements', **big))
        self.progress_s = float(p('progress_s', 5.0, 'progress log period (s); 0 = off', **big))
        if not self.bag_path:
            raise UserError('parameter bag is required (-p bag:=PATH)')
        remap = parse_remaps(list(remaps or []))
        overrides = parse_topic_qos(list(topic_qos or []))

        self.bag: BagReader = open_bag(self.bag_path)  # BagError names the path
        available = self.bag.topics
        wanted = list(topics or []) or list(available)
        if missing := [t for t in wanted if t not in available]:
            raise UserError(f'{self.bag_path}: no topic {", ".join(missing)} in the bag')
        if unknown := [t for t in remap if t not in wanted]:
            self.get_logger().warning(f'remap of topics that are not played: {", ".join(unknown)}')
        if unknown := [t for t in overrides if t not in wanted]:
            self.get_logger().warning(f'topic_qos of topics that are not played: {", ".join(unknown)}')
        self.outs: dict[str, _Out] = {}
        self.bad = BadInput(self)
        qos_log: dict[str, str] = {}  # topic -> its QoS line
        is_image = lambda t: available[t].msgtype.endswith(('/Image', '/CompressedImage'))  # noqa: E731
        for topic in sorted(wanted, key=is_image):  # images last (stable: bag order otherwise)
            info = available[topic]
            problem = self._unplayable(info.msgtype, info.serialization_format)
            if problem:
                self.get_logger().warning(f'skipping {topic} ({info.msgtype}): {problem}')
                continue
            qos, note = play_qos(
                info,
                depth=self.depth,
                max_durable_depth=max_durable,
                use_recorded=use_recorded,
                override=overrides.get(topic),
            )
            if self.rate == 0 and qos.durability == 'volatile' and qos.depth > self.window:
                # A full history makes Fast DDS ask for acknowledgements with every message.
                qos = replace(qos, depth=self.window, source=f'{qos.source}, flow_window at rate 0')
            qos_log[topic] = f'{topic}: {qos}' + (f'; {note}' if note else '')
            cls = message_class(info.msgtype)
            name = remap.get(topic, topic)
            publisher = self.create_publisher(cls, name, qos.profile())
            durable = qos.durability == 'transient_local'
            self.outs[topic] = _Out(name, publisher, decoder(info.msgtype, cls), qos.depth, durable)
        self.outs = {t: self.outs[t] for t in wanted if t in self.outs}  # bag order again
        if not self.outs:
            raise UserError(f'{self.bag_path}: none of the topics can be played')
        names = {o.name: o for o in self.outs.values()}
        self.wait_outs = list(self.outs.values())
        if wait_topics:
            resolved = {self.resolve_topic_name(t): t for t in wait_topics}
            known = {self.resolve_topic_name(n): o for n, o in names.items()}
            if missing := [t for r, t in resolved.items() if r not in known]:
                raise UserError(
                    f'parameter wait_topics: {", ".join(missing)} not played (played: {", ".join(names)})'
                )
            self.wait_outs = [known[r] for r in resolved]
        self.clock_pub = (
            self.create_publisher(Clock, '/clock', reliable_qos(10)) if self.publish_clock else None
        )
        self.first_ns = self.bag.start_ns + round(self.start_offset * 1e9)
        self.stop_ns = (
            self.first_ns + round(self.duration * 1e9) if self.duration > 0 else self.bag.end_ns + 1
        )
        if self.first_ns > self.bag.end_ns:
            raise UserError(f'{self.bag_path}: start_offset {self.start_offset} s is past the end of the bag')
        self._last_clock_wall = -1.0
        self._clock_ns = -1
        self.stopping = threading.Event()
        self.finished: Future = Future()
        self._thread = threading.Thread(target=self._run, name='bag_player', daemon=True)
        self.get_logger().info(
            f'playing {self.bag_path} ({self.bag.storage}, {self.bag.duration_s:.1f} s): '
            + ', '.join(f'{t} -> {o.name}' if t != o.name else t for t, o in self.outs.items())
            + f' at rate {self.rate:g}'
            + (' (as fast as possible)' if self.rate == 0 else '')
        )
        self.get_logger().info('QoS: ' + ', '.join(qos_log[t] for t in self.outs))

    def _unplayable(self, msgtype: str, serialization_format: str) -> str:
        """Why a topic of ``msgtype`` cannot be replayed as is; '' when it can."""
        if serialization_format != 'cdr':
            return f'{serialization_format} data of a type ROS 2 Jazzy does not know'
        try:
            message_class(msgtype)
        except msg_utils.MessageError:
            return 'no Python message class installed'
        if self.bag.storage == 'ros1':  # converted to Jazzy's definition by the reader
            return ''
        try:
            own = self.bag.typestore
            if msgtype in own.types and own.hash_rihs01(msgtype) != TYPESTORE.hash_rihs01(msgtype):
                return 'the bag defines the type differently from ROS 2 Jazzy'
        except Exception:  # definitions that cannot be hashed: trust the type name
            pass
        return ''

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
        for msg in self._messages():
            out = self.outs[msg.topic]
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
