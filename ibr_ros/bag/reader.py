# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Read ROS 2 bags (mcap or sqlite3 storage), bare ``.mcap`` files and ROS 1 ``.bag`` files.

Messages come out as :class:`BagMessage` with CDR ``rawdata`` and a lazily deserialised rosbags
message object ``.msg``. ROS 1 messages are converted to their ROS 2 Jazzy form (``header.seq``
dropped, ``CameraInfo.D`` as ``d``, ...) as far as Jazzy knows the type. Where a ROS 2 bag's
embedded definition equals Jazzy's, ``.msg`` is an instance of ``TYPESTORE.types[msgtype]``;
otherwise it is built from the bag's own definition.

Every problem with the bag (missing, empty, corrupt, truncated, unknown storage or type) is a
:class:`ibr_ros.errors.BagError`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Literal, cast

from ibr_ros.bag.typestore import TYPESTORE
from ibr_ros.errors import BagError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator
    from types import TracebackType

    from rosbags.typesys.store import Typestore

    from ibr_ros.bag._sources import Source
    from ibr_ros.bag.qos import OfferedQos

__all__ = [
    'TYPESTORE',
    'BagMessage',
    'BagReader',
    'Storage',
    'TopicInfo',
    'find_bags',
    'open_bag',
    'same_definition',
]

log = logging.getLogger(__name__)

Storage = Literal['mcap', 'sqlite3', 'ros1']

MCAP_MAGIC = b'\x89MCAP0\r\n'
STORAGE_SUFFIXES: dict[str, Storage] = {'.mcap': 'mcap', '.db3': 'sqlite3', '.bag': 'ros1'}


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag. ``serialization_format`` is that of :attr:`BagMessage.rawdata`.

    ``offered_qos``: the QoS profiles its recorded publishers offered (rosbag2 ``offered_qos_profiles``;
    empty where the bag records none, for ROS 1 bags, and where the record is malformed).
    """

    name: str
    msgtype: str
    count: int
    serialization_format: str
    offered_qos: tuple[OfferedQos, ...] = ()


class BagMessage:
    """One message: ``topic``, ``msgtype``, ``timestamp_ns`` (receive/log time), ``rawdata``.

    ``rawdata`` is CDR (``serialization_format == 'cdr'``), except for ROS 1 types that ROS 2 Jazzy
    does not know, which stay in ROS 1 serialisation (``'ros1'``).
    """

    __slots__ = ('_decode', '_msg', 'msgtype', 'rawdata', 'serialization_format', 'timestamp_ns', 'topic')

    def __init__(
        self,
        topic: str,
        msgtype: str,
        timestamp_ns: int,
        rawdata: bytes,
        serialization_format: str = 'cdr',
        decode: Callable[[BagMessage], object] | None = None,
    ) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.timestamp_ns = timestamp_ns
        self.rawdata = rawdata
        self.serialization_format = serialization_format
        self._decode = decode
        self._msg: object = None

    @property
    def msg(self) -> object:
        """The rosbags message object, deserialised on first access.

        Raises:
            BagError: Unknown message type or undecodable data.

        """
        if self._msg is None:
            if self._decode is None:
                self._msg = TYPESTORE.deserialize_cdr(self.rawdata, self.msgtype)
            else:
                self._msg = self._decode(self)
        return self._msg

    @property
    def header_stamp_ns(self) -> int | None:
        """``header.stamp`` in nanoseconds, None if the message has no header."""
        stamp = getattr(getattr(self.msg, 'header', None), 'stamp', None)
        if stamp is None:
            return None
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)

    def __repr__(self) -> str:
        return (
            f'BagMessage(topic={self.topic!r}, msgtype={self.msgtype!r}, '
            f'timestamp_ns={self.timestamp_ns}, {len(self.rawdata)} bytes)'
        )


@dataclass(frozen=True)
class _Codec:
    """How to expose and deserialise the stored data of one message type."""

    serialization_format: str
    convert: Callable[[bytes], bytes] | None
    deserialize: Callable[[bytes], object] | None  # None: unknown type


class BagReader:
    """An open bag; use :func:`open_bag` (or ``with BagReader(path) as reader``)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self._source: Source | None = None
        self._storage: Storage = 'mcap'
        self._codecs: dict[str, _Codec] = {}
        self._topics: dict[str, TopicInfo] = {}

    def open(self) -> BagReader:
        """Open the bag (idempotent).

        Raises:
            BagError: The bag cannot be read or holds no messages.

        """
        if self._source is not None:
            return self
        self._storage, source = _open_source(self.path)
        try:
            if source.message_count == 0:
                raise BagError(self.path, 'bag contains no messages')
            self._source = source
            self._topics = {
                name: TopicInfo(
                    name, t.msgtype, t.count, self._codec(t.msgtype).serialization_format, t.offered_qos
                )
                for name, t in sorted(source.topics.items())
            }
        except BaseException:
            self._source = None
            source.close()
            raise
        return self

    def close(self) -> None:
        """Close the bag (idempotent)."""
        source, self._source = self._source, None
        self._codecs.clear()
        if source is not None:
            source.close()

    def __enter__(self) -> BagReader:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    @property
    def _src(self) -> Source:
        if self._source is None:
            raise BagError(self.path, 'bag is not open')
        return self._source

    @property
    def storage(self) -> Storage:
        """``'mcap'``, ``'sqlite3'`` or ``'ros1'``."""
        return self._storage

    @property
    def typestore(self) -> Typestore:
        """The bag's own type definitions (messages of types Jazzy knows use :data:`TYPESTORE`)."""
        return self._src.typestore

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topics by name, sorted by name."""
        _ = self._src  # raises when closed
        return dict(self._topics)

    @property
    def message_count(self) -> int:
        return self._src.message_count

    @property
    def start_ns(self) -> int:
        """Timestamp of the first message."""
        return self._src.start_ns

    @property
    def end_ns(self) -> int:
        """Timestamp of the last message."""
        return self._src.end_ns

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last message."""
        return (self.end_ns - self.start_ns) / 1e9

    def messages(
        self,
        topics: Iterable[str] | None = None,
        *,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[BagMessage]:
        """Messages of ``topics`` (all if None) with ``start_ns <= timestamp_ns < end_ns``, in time order.

        Raises:
            BagError: A topic is not in the bag, or the data cannot be read.

        """
        source = self._src
        wanted: list[str] | None = None
        if topics is not None:
            wanted = list(dict.fromkeys([topics] if isinstance(topics, str) else topics))
            if missing := [t for t in wanted if t not in self._topics]:
                raise BagError(
                    self.path,
                    f'no topic {", ".join(missing)} in the bag; it has {", ".join(self._topics) or "none"}',
                )
        return self._messages(source, wanted, start_ns, end_ns)

    def _messages(
        self, source: Source, topics: list[str] | None, start: int | None, stop: int | None
    ) -> Iterator[BagMessage]:
        try:
            for topic, msgtype, timestamp, data in source.messages(topics, start, stop):
                codec = self._codec(msgtype)
                raw = codec.convert(data) if codec.convert is not None else bytes(data)
                decode = partial(self._decode, codec.deserialize)
                yield BagMessage(topic, msgtype, timestamp, raw, codec.serialization_format, decode)
        except BagError:
            raise
        except Exception as exc:  # the storage libraries raise many kinds on corrupt data
            raise BagError(self.path, f'cannot read messages: {_describe(exc)}') from exc

    def _decode(self, deserialize: Callable[[bytes], object] | None, message: BagMessage) -> object:
        """Deserialise ``message`` (also after the reader is closed)."""
        if deserialize is None:
            raise BagError(
                self.path,
                f'unknown message type {message.msgtype} on {message.topic}: '
                'the bag has no definition of it and ROS 2 Jazzy does not know it',
            )
        try:
            return deserialize(message.rawdata)
        except Exception as exc:
            raise BagError(
                self.path,
                f'cannot decode {message.msgtype} message on {message.topic} '
                f'at {message.timestamp_ns}: {_describe(exc)}',
            ) from exc

    def _codec(self, msgtype: str) -> _Codec:
        if (codec := self._codecs.get(msgtype)) is None:
            codec = self._codecs[msgtype] = _make_codec(self._src, msgtype)
        return codec


def _make_codec(source: Source, msgtype: str) -> _Codec:
    own = source.typestore
    known, has_own = msgtype in TYPESTORE.types, msgtype in own.types
    if not source.is_ros1:
        if known and (not has_own or same_definition(own, msgtype)):  # None (cannot tell): the bag's
            return _Codec('cdr', None, partial(TYPESTORE.deserialize_cdr, typename=msgtype))
        return _Codec('cdr', None, partial(own.deserialize_cdr, typename=msgtype) if has_own else None)
    if known and has_own:
        return _Codec(
            'cdr', _ros1_to_jazzy(own, msgtype), partial(TYPESTORE.deserialize_cdr, typename=msgtype)
        )
    return _Codec('ros1', None, partial(own.deserialize_ros1, typename=msgtype) if has_own else None)


def same_definition(own: Typestore, msgtype: str) -> bool | None:
    """Whether a bag's typestore ``own`` defines ``msgtype`` as ROS 2 Jazzy does (same RIHS01 hash);
    None when that cannot be told (a definition that cannot be hashed, e.g. incomplete)."""
    try:
        return own.hash_rihs01(msgtype) == TYPESTORE.hash_rihs01(msgtype)
    except Exception:  # incomplete definitions cannot be hashed
        return None


def _ros1_to_jazzy(own: Typestore, msgtype: str) -> Callable[[bytes], bytes]:
    """Convert ROS 1 serialised ``msgtype`` (as the bag defines it) to Jazzy CDR."""
    from rosbags.convert.converter import is_same_wireformat, migrate_bytes

    if is_same_wireformat(own, TYPESTORE, msgtype, msgtype):
        return lambda data: bytes(TYPESTORE.ros1_to_cdr(data, msgtype))
    cache: dict[str, object] = {}
    return lambda data: bytes(
        migrate_bytes(own, TYPESTORE, msgtype, msgtype, cache, data, src_is2=False, dst_is2=True)
    )


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().rstrip('.')
    if isinstance(exc, KeyError) and exc.args:
        text = f'missing {exc.args[0]!r}'
    return text or type(exc).__name__


def _diagnose_mcap(path: Path) -> str | None:
    """A plain-words problem of an MCAP file's framing, None if its start and end look right."""
    try:
        size = path.stat().st_size
        with path.open('rb') as f:
            head = f.read(8)
            f.seek(max(0, size - 8))
            tail = f.read(8)
    except OSError as exc:
        return f'cannot read file: {exc.strerror or exc}'
    if size == 0:
        return 'empty file (0 bytes); the recording may have been interrupted'
    if head != MCAP_MAGIC:
        return 'not an MCAP file (bad magic bytes)'
    if size < 2 * len(MCAP_MAGIC) + 29 or tail != MCAP_MAGIC:
        return 'truncated MCAP file (no footer); the recording may have been interrupted'
    return None


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in STORAGE_SUFFIXES and p.is_file())


def _open_source(path: Path) -> tuple[Storage, Source]:
    """Pick the back end for ``path`` and open it."""
    from ibr_ros.bag._sources import McapSource, RosbagsSource

    if not path.exists():
        raise BagError(path, 'no such file or directory')
    if path.is_dir():
        meta = path / 'metadata.yaml'
        if not meta.is_file():
            files = _storage_files(path)
            if len(files) == 1:
                return _open_source(files[0])
            if not files:
                raise BagError(path, 'not a bag: no metadata.yaml and no .mcap, .db3 or .bag file')
            raise BagError(
                path, f'no metadata.yaml and {len(files)} storage files; run `ros2 bag reindex` on it'
            )
        storage = _storage_identifier(meta)
        files = sorted(path.glob('*.mcap')) if storage == 'mcap' else []
    elif path.suffix in STORAGE_SUFFIXES:
        storage = STORAGE_SUFFIXES[path.suffix]
        files = [path] if storage == 'mcap' else []
    else:
        raise BagError(
            path,
            f'unknown storage {path.suffix or "(no suffix)"!r}: '
            'expected a rosbag2 directory, a .mcap, .db3 or ROS 1 .bag file',
        )

    try:
        return storage, RosbagsSource(path)
    except BagError:
        raise
    except Exception as exc:
        error = exc
    for file in files:
        if problem := _diagnose_mcap(file):
            raise BagError(file, problem) from error
    if path.suffix == '.mcap':
        try:
            source = McapSource(path)
        except BagError:
            raise
        except Exception:
            log.debug('mcap library cannot read %s either', path, exc_info=True)
        else:
            log.debug('%s: read with the mcap library (rosbags: %s)', path, _describe(error))
            return storage, source
    raise BagError(path, _problem(storage, error)) from error


def _problem(storage: Storage, exc: Exception) -> str:
    text = _describe(exc)
    if 'not indexed' in text:
        return 'ROS 1 bag is not indexed (the recording may have been interrupted); run `rosbag reindex`'
    if isinstance(exc, PermissionError):
        return 'permission denied'
    kind = {'mcap': 'MCAP', 'sqlite3': 'SQLite', 'ros1': 'ROS 1'}[storage]
    return f'corrupt or unreadable {kind} bag: {text}'


def _storage_identifier(meta: Path) -> Storage:
    import yaml

    try:
        info = yaml.safe_load(meta.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
        storage = info['storage_identifier']
    except (OSError, UnicodeError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(meta, f'not a rosbag2 metadata file: {_describe(exc)}') from exc
    if storage not in {'mcap', 'sqlite3'}:
        raise BagError(meta, f'unknown storage {storage!r} (supported: mcap, sqlite3)')
    return cast('Storage', storage)


def open_bag(path: Path | str) -> BagReader:
    """Open a rosbag2 directory, a ``.mcap``/``.db3`` file or a ROS 1 ``.bag``; use it as a context manager.

    Raises:
        BagError: Missing, empty, corrupt, truncated or of unknown storage.

    """
    return BagReader(path).open()


def find_bags(folder: Path | str) -> list[Path]:
    """Bags under ``folder``, sorted: rosbag2 directories (not entered), ``.mcap``, ``.db3``, ``.bag`` files.

    Hidden entries (names starting with ``.``, e.g. unfinished writes) are skipped.

    Raises:
        BagError: ``folder`` does not exist.

    """
    folder = Path(folder)
    if not folder.exists():
        raise BagError(folder, 'no such file or directory')
    if folder.is_file() or (folder / 'metadata.yaml').is_file():
        return [folder]
    found: list[Path] = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith('.'):
            continue
        if entry.is_dir():
            found.extend(find_bags(entry))
        elif entry.suffix in STORAGE_SUFFIXES:
            found.append(entry)
    return sorted(found)
