# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Write ROS 2 bag directories: MCAP storage with chunk compression, plus ``metadata.yaml``.

The ``.mcap`` is written with the ``mcap`` library (rosbags' writer compresses chunks with zstd
only, at a fixed chunk size): profile ``ros2``, ``ros2msg`` schemas generated from the typestore,
CDR messages, and the ``rosbag2`` metadata record. ``metadata.yaml`` is rosbag2 version 8, as
ROS 2 Jazzy writes it. A topic may carry the QoS profile its publisher offered
(:class:`~ibr_ros.bag.qos.OfferedQos`), stored as ``offered_qos_profiles`` in the channel and in the
metadata, so that ``ros2 bag play`` and the ``bag_player`` offer it again on replay. The bag is
written next to its target as ``.<name>.tmp-<pid>`` and renamed into place when the writer closes
without an exception.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Literal

import yaml

from ibr_ros import __version__
from ibr_ros.bag.qos import OfferedQos, dump_offered_qos
from ibr_ros.bag.typestore import TYPESTORE, ros2msg_definition, serialize
from ibr_ros.errors import BagError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import TracebackType

    from mcap.writer import Writer as McapWriter
    from rosbags.typesys.store import Typestore

__all__ = ['METADATA_VERSION', 'BagWriter', 'Compression']

Compression = Literal['zstd', 'lz4', 'none']

#: rosbag2 metadata version of ROS 2 Jazzy.
METADATA_VERSION = 8
ROS_DISTRO = 'jazzy'
DEFAULT_CHUNK_SIZE = 4 * 1024 * 1024


@dataclass
class _Topic:
    channel_id: int
    msgtype: str
    qos: tuple[OfferedQos, ...] = field(default_factory=tuple)
    count: int = 0


class BagWriter:
    """Write a ROS 2 bag directory (MCAP storage); a context manager.

    Args:
        path: The bag directory to create.
        compression: MCAP chunk compression.
        chunk_size: Uncompressed bytes per chunk.
        overwrite: Replace an existing ``path`` (only once the new bag is complete).
        typestore: Message definitions and serialisation of rosbags messages.

    """

    def __init__(
        self,
        path: Path | str,
        *,
        compression: Compression = 'zstd',
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        overwrite: bool = False,
        typestore: Typestore = TYPESTORE,
    ) -> None:
        if compression not in {'zstd', 'lz4', 'none'}:
            raise ValueError(f'compression must be zstd, lz4 or none, not {compression!r}')
        if chunk_size < 1:
            raise ValueError(f'chunk_size must be positive, not {chunk_size}')
        self.path = Path(path)
        self.compression: Compression = compression
        self.chunk_size = chunk_size
        self.overwrite = overwrite
        self.typestore = typestore
        self.tmp_path = self.path.parent / f'.{self.path.name}.tmp-{os.getpid()}'
        self.storage_name = f'{self.path.name}_0.mcap'
        self._file: IO[bytes] | None = None
        self._mcap: McapWriter | None = None
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._start_ns = 2**63 - 1
        self._end_ns = 0

    # -- life cycle --------------------------------------------------------------------------

    def open(self) -> BagWriter:
        """Start writing into the temporary directory.

        Raises:
            BagError: The target exists and ``overwrite`` is off, or cannot be created.

        """
        from mcap.writer import CompressionType
        from mcap.writer import Writer as McapWriter

        if self._mcap is not None:
            return self
        if self.path.exists() and not self.overwrite:
            raise BagError(self.path, 'exists already (pass overwrite=True to replace it)')
        try:
            if self.tmp_path.exists():
                shutil.rmtree(self.tmp_path)
            self.tmp_path.mkdir(parents=True)
            self._file = (self.tmp_path / self.storage_name).open('xb')
        except OSError as exc:
            self._remove_tmp()
            raise BagError(self.path, f'cannot create bag: {exc.strerror or exc}') from exc
        self._mcap = McapWriter(
            self._file,
            chunk_size=self.chunk_size,
            compression={
                'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE,
            }[self.compression],
        )
        self._mcap.start(profile='ros2', library=f'ibr_ros-{__version__}')
        return self

    def close(self) -> None:
        """Finish the files and move the bag to its path."""
        if self._mcap is None:
            return
        try:
            mcap, self._mcap = self._mcap, None
            metadata = self._metadata()
            mcap.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(metadata, sort_keys=False)})
            mcap.finish()
            self._close_file()
            text = yaml.safe_dump({'rosbag2_bagfile_information': metadata}, sort_keys=False)
            (self.tmp_path / 'metadata.yaml').write_text(text, encoding='utf-8')
            if self.path.exists() or self.path.is_symlink():
                if not self.overwrite:
                    raise BagError(self.path, 'exists already (created while writing)')
                if self.path.is_dir() and not self.path.is_symlink():
                    shutil.rmtree(self.path)
                else:
                    self.path.unlink()
            self.tmp_path.rename(self.path)
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Drop everything written; the target is left as it was."""
        self._mcap = None
        self._close_file()
        self._remove_tmp()

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- writing -----------------------------------------------------------------------------

    def add_topic(
        self, topic: str, msgtype: str, qos: OfferedQos | Sequence[OfferedQos] | None = None
    ) -> None:
        """Declare ``topic`` with ``msgtype`` (``pkg/msg/Name``) and the QoS profile(s) it was offered with.

        Without ``qos`` the topic records no profile (players use their default). Declaring it again
        with the same type (and the same ``qos`` or None) is a no-op; :meth:`write` declares topics
        without QoS, so declare a topic with its QoS before writing to it.

        Raises:
            BagError: The topic has another type or QoS, or the type is unknown to the typestore.

        """
        mcap = self._writer()
        profiles = (qos,) if isinstance(qos, OfferedQos) else tuple(qos or ())
        if not all(isinstance(q, OfferedQos) for q in profiles):
            raise TypeError(f'topic {topic}: qos must be OfferedQos profiles, not {qos!r}')
        if (have := self._topics.get(topic)) is not None:
            if have.msgtype != msgtype:
                raise BagError(self.path, f'topic {topic} is {have.msgtype}, cannot add it as {msgtype}')
            if qos is not None and profiles != have.qos:
                offered = ', '.join(map(str, have.qos)) or 'no QoS'
                raise BagError(self.path, f'topic {topic} is declared with {offered} already')
            return
        if msgtype not in self.typestore.types:
            raise BagError(self.path, f'topic {topic}: unknown message type {msgtype!r}')
        if (schema_id := self._schemas.get(msgtype)) is None:
            schema_id = self._schemas[msgtype] = mcap.register_schema(
                name=msgtype,
                encoding='ros2msg',
                data=ros2msg_definition(msgtype, self.typestore).encode(),
            )
        channel_id = mcap.register_channel(
            topic=topic,
            message_encoding='cdr',
            schema_id=schema_id,
            metadata={'offered_qos_profiles': dump_offered_qos(profiles)},
        )
        self._topics[topic] = _Topic(channel_id, msgtype, profiles)

    def write(self, topic: str, msg: object, stamp_ns: int) -> None:
        """Write a rosbags or rclpy message object, logged at ``stamp_ns``."""
        try:
            msgtype, cdr = serialize(msg, self.typestore)
        except (TypeError, KeyError) as exc:
            raise BagError(self.path, f'topic {topic}: cannot serialise message: {exc}') from exc
        self.write_raw(topic, msgtype, cdr, stamp_ns)

    def write_raw(self, topic: str, msgtype: str, cdr: bytes, stamp_ns: int) -> None:
        """Write an already CDR-serialised message, logged at ``stamp_ns``."""
        mcap = self._writer()
        if not 0 <= stamp_ns < 2**63:
            raise BagError(self.path, f'topic {topic}: timestamp {stamp_ns} out of range')
        self.add_topic(topic, msgtype)
        entry = self._topics[topic]
        mcap.add_message(entry.channel_id, log_time=stamp_ns, data=bytes(cdr), publish_time=stamp_ns)
        entry.count += 1
        self._start_ns = min(self._start_ns, stamp_ns)
        self._end_ns = max(self._end_ns, stamp_ns)

    # -- helpers -----------------------------------------------------------------------------

    def _writer(self) -> McapWriter:
        if self._mcap is None:
            raise BagError(self.path, 'writer is not open')
        return self._mcap

    def _metadata(self) -> dict[str, object]:
        """``rosbag2_bagfile_information`` as rosbag2 (Jazzy) writes it."""
        count = sum(t.count for t in self._topics.values())
        start = self._start_ns if count else 0
        duration = self._end_ns - start if count else 0
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': name,
                        'type': t.msgtype,
                        'serialization_format': 'cdr',
                        'offered_qos_profiles': dump_offered_qos(t.qos),
                        'type_description_hash': self.typestore.hash_rihs01(t.msgtype),
                    },
                    'message_count': t.count,
                }
                for name, t in self._topics.items()
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.storage_name],
            'files': [
                {
                    'path': self.storage_name,
                    'starting_time': {'nanoseconds_since_epoch': start},
                    'duration': {'nanoseconds': duration},
                    'message_count': count,
                }
            ],
            'custom_data': None,
            'ros_distro': ROS_DISTRO,
        }

    def _close_file(self) -> None:
        file, self._file = self._file, None
        if file is not None:
            file.close()

    def _remove_tmp(self) -> None:
        shutil.rmtree(self.tmp_path, ignore_errors=True)
