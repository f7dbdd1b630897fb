# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Storage back ends of :mod:`ibr_ros.bag.reader`: rosbags ``AnyReader`` and the ``mcap`` library.

A source yields ``(topic, msgtype, timestamp_ns, data)`` in timestamp order, ``data`` as stored
(CDR for ROS 2, ROS 1 serialisation for ROS 1 bags), and knows the bag's own type definitions and
each topic's recorded offered QoS profiles (a malformed ``offered_qos_profiles`` is ignored with a
warning: the bag stays readable).
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Iterable
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

from ibr_ros.bag.qos import OfferedQos, parse_offered_qos
from ibr_ros.bag.typestore import TYPESTORE
from ibr_ros.errors import BagError

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator
    from pathlib import Path

    from rosbags.typesys.store import Typestore

RawMessage = tuple[str, str, int, bytes]
"""``(topic, msgtype, timestamp_ns, data)``."""

_IDL_SEPARATOR = '=' * 80 + '\n'

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SourceTopic:
    """A topic as the storage reports it."""

    msgtype: str
    count: int
    offered_qos: tuple[OfferedQos, ...] = ()


class Source(Protocol):
    """What :class:`ibr_ros.bag.reader.BagReader` needs from a storage back end."""

    is_ros1: bool
    typestore: Typestore
    topics: dict[str, SourceTopic]
    start_ns: int
    end_ns: int
    message_count: int

    def messages(self, topics: list[str] | None, start: int | None, stop: int | None) -> Iterator[RawMessage]:
        """Messages of ``topics`` (all if None) with ``start <= timestamp < stop``, in time order."""
        ...

    def close(self) -> None:
        """Release files."""
        ...


class RosbagsSource:
    """rosbag2 directories, bare ``.mcap``/``.db3`` files and ROS 1 bags through rosbags' AnyReader."""

    def __init__(self, path: Path) -> None:
        self._reader = AnyReader([path], default_typestore=TYPESTORE)
        with _unparsed_qos():
            self._reader.open()
        try:
            self.is_ros1 = not self._reader.is2
            self.typestore = self._reader.typestore
            self.topics = {}
            for name, info in self._reader.topics.items():
                if info.msgtype is None:
                    types = sorted({c.msgtype for c in info.connections})
                    raise BagError(path, f'topic {name} has several message types: {", ".join(types)}')
                recorded = [getattr(c.ext, 'offered_qos_profiles', None) for c in info.connections]
                self.topics[name] = SourceTopic(
                    info.msgtype, info.msgcount, _offered_qos(path, name, recorded)
                )
            self.message_count = self._reader.message_count
            self.start_ns = self._reader.start_time
            self.end_ns = self._reader.end_time - 1  # rosbags' end_time is one past the last message
        except BaseException:
            self._reader.close()
            raise

    def messages(self, topics: list[str] | None, start: int | None, stop: int | None) -> Iterator[RawMessage]:
        connections = self._reader.connections
        if topics is not None:
            wanted = set(topics)
            connections = [c for c in connections if c.topic in wanted]
            if not connections:
                return
        for conn, timestamp, data in self._reader.messages(connections, start=start, stop=stop):
            yield conn.topic, conn.msgtype, timestamp, data

    def close(self) -> None:
        self._reader.close()


class McapSource:
    """Bare MCAP files that rosbags does not read (other profiles, unusual layouts): ``mcap`` library."""

    def __init__(self, path: Path) -> None:
        from mcap.reader import make_reader

        self.path = path
        self.is_ros1 = False
        self._file = path.open('rb')
        try:
            self._reader = make_reader(self._file)
            summary = self._reader.get_summary()
            self._indexed = summary is not None and bool(summary.chunk_indexes)
            if summary is not None and summary.statistics is not None:
                stats = summary.statistics
                schemas, channels = summary.schemas, summary.channels
                counts = dict(stats.channel_message_counts)
                self.message_count = stats.message_count
                self.start_ns, self.end_ns = stats.message_start_time, stats.message_end_time
            else:
                schemas, channels, counts = {}, {}, {}
                self.message_count, self.start_ns, self.end_ns = 0, 2**63 - 1, 0
                for schema, channel, message in self._reader.iter_messages(log_time_order=False):
                    if schema is not None:
                        schemas[schema.id] = schema
                    channels[channel.id] = channel
                    counts[channel.id] = counts.get(channel.id, 0) + 1
                    self.message_count += 1
                    self.start_ns = min(self.start_ns, message.log_time)
                    self.end_ns = max(self.end_ns, message.log_time)
            self._msgtypes: dict[int, str] = {}
            self.topics: dict[str, SourceTopic] = {}
            for cid, channel in sorted(channels.items()):
                if channel.message_encoding != 'cdr':
                    raise BagError(
                        path,
                        f'topic {channel.topic}: unsupported message encoding '
                        f'{channel.message_encoding!r} (only ROS 2 CDR is supported)',
                    )
                schema = schemas.get(channel.schema_id)
                msgtype = schema.name if schema is not None else ''
                if not msgtype:
                    raise BagError(
                        path, f'topic {channel.topic}: channel has no schema (message type unknown)'
                    )
                self._msgtypes[cid] = msgtype
                have = self.topics.get(channel.topic)
                if have is not None and have.msgtype != msgtype:
                    raise BagError(
                        path, f'topic {channel.topic} has several message types: {have.msgtype}, {msgtype}'
                    )
                count = counts.get(cid, 0) + (have.count if have else 0)
                qos = _offered_qos(path, channel.topic, [channel.metadata.get('offered_qos_profiles')])
                self.topics[channel.topic] = SourceTopic(
                    msgtype, count, (have.offered_qos if have else ()) + qos
                )
            self.typestore = _typestore_from_schemas(schemas.values())
        except BaseException:
            self._file.close()
            raise

    def messages(self, topics: list[str] | None, start: int | None, stop: int | None) -> Iterator[RawMessage]:
        previous = -1
        for _, channel, message in self._reader.iter_messages(
            topics=topics, log_time_order=True, starting_at=start, ending_before=stop
        ):
            if not self._indexed:
                if message.log_time < previous:
                    raise BagError(
                        self.path,
                        'unindexed MCAP file with messages out of time order; '
                        'rewrite it with `mcap recover` first',
                    )
                previous = message.log_time
            yield channel.topic, self._msgtypes[channel.id], message.log_time, message.data

    def close(self) -> None:
        self._file.close()


class _RawQos(list):
    """Stands in for rosbags' parsed QoS profiles: no profiles, and the stored value as ``raw``."""

    def __init__(self, raw: object) -> None:
        super().__init__()
        self.raw = raw


_ROSBAGS_QOS_LOCK = threading.Lock()


@contextmanager
def _unparsed_qos() -> Iterator[None]:
    """While rosbags opens a bag, keep ``offered_qos_profiles`` unparsed (:class:`_RawQos`).

    rosbags' ``parse_qos`` fails the whole bag on a malformed value; here it is parsed per topic by
    :func:`~ibr_ros.bag.qos.parse_offered_qos`. Only rosbags' reading modules are patched, only for the
    ``open`` (which reads all connections), under a lock.
    """
    modules: list[Any] = []  # rosbags modules that have a parse_qos to patch
    for name in ('reader', 'storage_mcap', 'storage_sqlite3'):
        try:
            module = importlib.import_module(f'rosbags.rosbag2.{name}')
        except ImportError:
            continue
        if hasattr(module, 'parse_qos'):
            modules.append(module)
    with _ROSBAGS_QOS_LOCK:
        saved = [(module, module.parse_qos) for module in modules]
        try:
            for module in modules:
                module.parse_qos = _RawQos
            yield
        finally:
            for module, parse in saved:
                module.parse_qos = parse


def _offered_qos(path: Path, topic: str, recorded: Iterable[object]) -> tuple[OfferedQos, ...]:
    """The profiles of ``topic`` from its connections' stored values; () with a warning if malformed."""
    profiles: list[OfferedQos] = []
    try:
        for value in recorded:
            if isinstance(value, _RawQos):
                profiles.extend(parse_offered_qos(value.raw))
            elif isinstance(value, list):  # parsed by rosbags after all: its Qos tuples
                profiles.extend(
                    OfferedQos(
                        q.reliability.name.lower(), q.durability.name.lower(), q.history.name.lower(), q.depth
                    )
                    for q in value
                )
            elif value is not None:
                profiles.extend(parse_offered_qos(value))
    except (ValueError, AttributeError) as exc:
        log.warning('%s: topic %s: ignoring its malformed offered_qos_profiles: %s', path, topic, exc)
        return ()
    return tuple(profiles)


def _typestore_from_schemas(schemas: Iterable[Any]) -> Typestore:
    """A typestore with the ``ros2msg``/``ros2idl`` definitions embedded in MCAP schemas."""
    typs: dict = {}
    for schema in schemas:
        text = schema.data.decode()
        if schema.encoding == 'ros2msg':
            typs.update(get_types_from_msg(text, schema.name))
        elif schema.encoding in {'ros2idl', 'omgidl'}:
            if text.startswith(f'{_IDL_SEPARATOR}IDL: '):
                for part in text.split(_IDL_SEPARATOR)[1:]:
                    typs.update(get_types_from_idl(part.split('\n', 1)[1]))
            else:
                typs.update(get_types_from_idl(text))
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(typs)
    return typestore
