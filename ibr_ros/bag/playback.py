# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""What the bag_player plays and how, as pure policy (no rclpy): which bag topics can be replayed, the
QoS each is offered with, topic remaps, the played time window and whether a payload decodes.

QoS per topic (:func:`play_qos`): reliable (which reaches best effort and reliable subscribers alike)
and volatile with ``qos_depth``, unless the bag records the QoS its publishers offered (rosbag2's
``offered_qos_profiles``; ``use_recorded_qos``): then transient local where they offered it, with a
history of the recorded depth or the topic's message count if larger, at most ``max_durable_depth``,
so that a late transient-local subscriber still gets the topic's history. Recorded best effort is
played reliable all the same; publishers that offered different reliability or durability fall back
to the default, as in ``ros2 bag play``. ``topic_qos`` entries (:func:`parse_topic_qos`) override
per bag topic. At rate 0 a volatile history is capped at ``flow_window`` (a full history makes Fast
DDS ask for acknowledgements with every message).

QoS are plain values (:class:`PlayQos`); the node turns them into rclpy profiles.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

from ibr_ros.bag.reader import BagReader, Storage, TopicInfo, same_definition
from ibr_ros.errors import UserError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    'CDR_HEADERS',
    'PlayQos',
    'PlaybackPlan',
    'PlaybackPolicy',
    'PlayedTopic',
    'is_image',
    'parse_remaps',
    'parse_topic_qos',
    'play_qos',
    'play_window',
    'undecodable',
    'unplayable',
]

#: Encapsulation headers of plain CDR (big, little endian): what ROS 2 Jazzy publishes and records.
CDR_HEADERS = (b'\x00\x00', b'\x00\x01')

_POLICY_WORDS = {'reliable', 'best_effort', 'volatile', 'transient_local'}

#: Per bag topic QoS overrides: ``{'reliability': ..., 'durability': ..., 'depth': N}`` (any of them).
Overrides = Mapping[str, Mapping[str, str | int]]


@dataclass(frozen=True)
class PlayQos:
    """The QoS a topic is played with, and where it comes from (``default``, ``recorded``, ``override``)."""

    reliability: Literal['reliable', 'best_effort'] = 'reliable'
    durability: Literal['volatile', 'transient_local'] = 'volatile'
    depth: int = 100
    source: str = 'default'

    def __str__(self) -> str:
        return f'{self.reliability} {self.durability} depth {self.depth} ({self.source})'


def parse_topic_qos(entries: Sequence[str]) -> dict[str, dict[str, str | int]]:
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


def parse_remaps(pairs: Sequence[str]) -> dict[str, str]:
    """``['from:=to', ...]`` -> ``{from: to}``; raises ValueError on a malformed pair."""
    remaps: dict[str, str] = {}
    for pair in pairs:
        src, sep, dst = pair.partition(':=')
        if not sep or not src.strip() or not dst.strip():
            raise ValueError(f"parameter remap: {pair!r} is not of the form 'from:=to'")
        remaps[src.strip()] = dst.strip()
    return remaps


def play_qos(
    info: TopicInfo,
    *,
    depth: int,
    max_durable_depth: int,
    use_recorded: bool = True,
    override: Mapping[str, str | int] | None = None,
) -> tuple[PlayQos, str]:
    """The QoS to play ``info``'s topic with (see the module docstring) and a note for the log ('' if
    none). ``depth``: history of a volatile topic; ``override``: one entry of :func:`parse_topic_qos`."""
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
        qos = replace(qos, **{k: v for k, v in override.items() if k != 'depth'}, source='override')  # type: ignore[arg-type]  # policy names checked by parse_topic_qos
    if qos.durability == 'transient_local':
        wanted = max([info.count, *(q.depth for q in offered)])
        qos = replace(qos, depth=max(1, min(wanted, max_durable_depth)))
        if wanted > max_durable_depth:
            notes.append(f'history of {wanted} capped at max_durable_depth')
    if override and 'depth' in override:
        qos = replace(qos, depth=int(override['depth']))
    return qos, '; '.join(notes)


def _installed(msgtype: str) -> bool:
    from msg_utils import MessageError  # imported here: msg_utils loads OpenCV
    from msg_utils.flavor import message_class

    try:
        message_class(msgtype)
    except MessageError:
        return False
    return True


def unplayable(
    info: TopicInfo, storage: Storage, own: Typestore, installed: Callable[[str], bool] = _installed
) -> str:
    """Why a bag topic cannot be replayed as it is ('' when it can): data that is not CDR, no Python
    message class ``installed`` for its type, or a bag (``own`` its typestore) that defines the type
    differently from ROS 2 Jazzy (:func:`~ibr_ros.bag.reader.same_definition`; a definition that
    cannot be hashed is trusted by its name). ROS 1 data the reader converted to Jazzy is CDR."""
    if info.serialization_format != 'cdr':
        return f'{info.serialization_format} data of a type ROS 2 Jazzy does not know'
    if not installed(info.msgtype):
        return 'no Python message class installed'
    if storage != 'ros1' and info.msgtype in own.types and same_definition(own, info.msgtype) is False:
        return 'the bag defines the type differently from ROS 2 Jazzy'
    return ''


def undecodable(raw: bytes, decode: Callable[[bytes], object]) -> tuple[str, str] | None:
    """``(reason, error)`` when ``raw`` is not a CDR message that ``decode`` accepts; None when it is.

    Reasons: ``empty``, ``encapsulation`` (shorter than the 4-byte header, or not plain CDR),
    ``corrupt`` (``decode`` raised).
    """
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


def is_image(msgtype: str) -> bool:
    """Whether ``msgtype`` is a camera image (``Image`` or ``CompressedImage``)."""
    return msgtype.endswith(('/Image', '/CompressedImage'))


def play_window(bag: BagReader, start_offset_s: float, duration_s: float) -> tuple[int, int]:
    """``(first_ns, stop_ns)``: the bag time played, ``start_offset_s`` after the bag's start for
    ``duration_s`` (0 = to the end); ``stop_ns`` is exclusive.

    Raises:
        UserError: ``start_offset_s`` is past the end of the bag.

    """
    first_ns = bag.start_ns + round(start_offset_s * 1e9)
    stop_ns = first_ns + round(duration_s * 1e9) if duration_s > 0 else bag.end_ns + 1
    if first_ns > bag.end_ns:
        raise UserError(f'{bag.path}: start_offset {start_offset_s} s is past the end of the bag')
    return first_ns, stop_ns


@dataclass(frozen=True)
class PlayedTopic:
    """A bag ``topic`` of ``msgtype`` played as ``name`` (after remap) with ``qos``; ``note`` for the log."""

    topic: str
    msgtype: str
    name: str
    qos: PlayQos
    note: str = ''

    def __str__(self) -> str:
        return f'{self.topic}: {self.qos}' + (f'; {self.note}' if self.note else '')


@dataclass(frozen=True)
class PlaybackPlan:
    """What :meth:`PlaybackPolicy.plan` decided for a bag.

    ``topics`` in the order their publishers are to be created: images last (a subscriber that
    discovers the image publisher then already knows the other topics; DDS announces endpoints in
    order), bag order otherwise. ``bag_order``: the played bag topics in the bag's order.
    ``warnings``: lines for the log (remaps or overrides of topics not played, skipped topics).
    """

    topics: tuple[PlayedTopic, ...]
    bag_order: tuple[str, ...]
    warnings: tuple[str, ...] = ()

    def waited(self, wait_topics: Sequence[str], resolve: Callable[[str], str]) -> tuple[str, ...]:
        """The bag topics whose published names are ``wait_topics`` (names compared after ``resolve``,
        the node's name resolution); empty ``wait_topics``: every played topic.

        Raises:
            UserError: A name in ``wait_topics`` that is not played.

        """
        if not wait_topics:
            return self.bag_order
        by_name = {t.name: t.topic for t in sorted(self.topics, key=lambda t: self.bag_order.index(t.topic))}
        known = {resolve(n): topic for n, topic in by_name.items()}
        resolved = {resolve(t): t for t in wait_topics}
        if missing := [t for r, t in resolved.items() if r not in known]:
            raise UserError(
                f'parameter wait_topics: {", ".join(missing)} not played (played: {", ".join(by_name)})'
            )
        return tuple(known[r] for r in resolved)


@dataclass(frozen=True)
class PlaybackPolicy:
    """The bag_player's choice of topics and their QoS (its parameters of the same names).

    ``topics``: bag topics to play (empty = all); ``remap``: bag topic -> published name;
    ``topic_qos``: per bag topic overrides (:func:`parse_topic_qos`); ``qos_depth``: history of the
    volatile publishers; ``rate`` 0 caps it at ``flow_window``.
    """

    topics: tuple[str, ...] = ()
    remap: Mapping[str, str] = field(default_factory=dict)
    topic_qos: Overrides = field(default_factory=dict)
    qos_depth: int = 100
    max_durable_depth: int = 1000
    use_recorded_qos: bool = True
    rate: float = 1.0
    flow_window: int = 8

    def plan(self, bag: BagReader) -> PlaybackPlan:
        """What to play of ``bag`` (its ``topics``, ``storage``, ``typestore`` and ``path`` are read).

        Raises:
            UserError: A topic of ``topics`` that the bag lacks, or no topic that can be played.

        """
        available = bag.topics
        wanted = list(self.topics) or list(available)
        if missing := [t for t in wanted if t not in available]:
            raise UserError(f'{bag.path}: no topic {", ".join(missing)} in the bag')
        warnings = []
        if unknown := [t for t in self.remap if t not in wanted]:
            warnings.append(f'remap of topics that are not played: {", ".join(unknown)}')
        if unknown := [t for t in self.topic_qos if t not in wanted]:
            warnings.append(f'topic_qos of topics that are not played: {", ".join(unknown)}')
        played = []
        for topic in sorted(wanted, key=lambda t: is_image(available[t].msgtype)):  # stable: images last
            info = available[topic]
            if problem := unplayable(info, bag.storage, bag.typestore):
                warnings.append(f'skipping {topic} ({info.msgtype}): {problem}')
                continue
            qos, note = play_qos(
                info,
                depth=self.qos_depth,
                max_durable_depth=self.max_durable_depth,
                use_recorded=self.use_recorded_qos,
                override=self.topic_qos.get(topic),
            )
            if self.rate == 0 and qos.durability == 'volatile' and qos.depth > self.flow_window:
                # A full history makes Fast DDS ask for acknowledgements with every message.
                qos = replace(qos, depth=self.flow_window, source=f'{qos.source}, flow_window at rate 0')
            played.append(PlayedTopic(topic, info.msgtype, self.remap.get(topic, topic), qos, note))
        if not played:
            raise UserError(f'{bag.path}: none of the topics can be played')
        names = {t.topic for t in played}
        return PlaybackPlan(tuple(played), tuple(t for t in wanted if t in names), tuple(warnings))
