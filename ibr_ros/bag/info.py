# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Summaries of bags, like ``ros2 bag info`` plus per-topic rates and image sizes."""

from __future__ import annotations

import datetime as dt
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibr_ros.bag.detect import COMPRESSED_IMAGE, IMAGE
from ibr_ros.bag.reader import open_bag

if TYPE_CHECKING:
    from ibr_ros.bag.reader import BagMessage, Storage

__all__ = ['BagInfo', 'ImageDetails', 'TopicSummary', 'bag_info', 'format_bag_info', 'image_dimensions']


@dataclass(frozen=True)
class ImageDetails:
    """First image of a topic: size (None where a compressed format is not understood), encoding or format."""

    width: int | None
    height: int | None
    encoding: str


@dataclass(frozen=True)
class TopicSummary:
    """A topic: ``rate_hz`` is (count - 1) / (last - first timestamp), None below two messages."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None
    serialization_format: str
    image: ImageDetails | None = None


@dataclass(frozen=True)
class BagInfo:
    """A bag's storage, size, time span and topics."""

    path: Path
    storage: Storage
    size_bytes: int
    start_ns: int
    end_ns: int
    duration_s: float
    message_count: int
    topics: tuple[TopicSummary, ...]

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {**asdict(self), 'path': str(self.path), 'topics': [asdict(t) for t in self.topics]}


def bag_info(path: Path | str) -> BagInfo:
    """Summarise the bag at ``path``; reads every message's timestamp (not its content).

    Raises:
        BagError: As :func:`ibr_ros.bag.reader.open_bag`, or corrupt data further in.

    """
    path = Path(path)
    with open_bag(path) as reader:
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        images: dict[str, ImageDetails] = {}
        image_topics = {n for n, t in reader.topics.items() if t.msgtype in {IMAGE, COMPRESSED_IMAGE}}
        for message in reader.messages():
            first.setdefault(message.topic, message.timestamp_ns)
            last[message.topic] = message.timestamp_ns
            if message.topic in image_topics and message.topic not in images:
                images[message.topic] = _image_details(message)
        topics = tuple(
            TopicSummary(
                name=name,
                msgtype=t.msgtype,
                count=t.count,
                rate_hz=_rate(t.count, first.get(name), last.get(name)),
                serialization_format=t.serialization_format,
                image=images.get(name),
            )
            for name, t in reader.topics.items()
        )
        return BagInfo(
            path=path,
            storage=reader.storage,
            size_bytes=_size(path),
            start_ns=reader.start_ns,
            end_ns=reader.end_ns,
            duration_s=reader.duration_s,
            message_count=reader.message_count,
            topics=topics,
        )


def _rate(count: int, first: int | None, last: int | None) -> float | None:
    if count < 2 or first is None or last is None or last <= first:
        return None
    return (count - 1) / ((last - first) / 1e9)


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob('*') if p.is_file())
    return path.stat().st_size


def _image_details(message: BagMessage) -> ImageDetails:
    msg: Any = message.msg  # a decoded Image or CompressedImage
    if message.msgtype == IMAGE:
        return ImageDetails(int(msg.width), int(msg.height), str(msg.encoding))
    data = bytes(msg.data)
    width, height = image_dimensions(data) or (None, None)
    return ImageDetails(width, height, str(msg.format))


_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def image_dimensions(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` read from a PNG or JPEG header, None for anything else."""
    if data[:8] == b'\x89PNG\r\n\x1a\n' and data[12:16] == b'IHDR':
        return int.from_bytes(data[16:20], 'big'), int.from_bytes(data[20:24], 'big')
    if data[:2] != b'\xff\xd8':
        return None
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD9:  # markers without a length
            pos += 2
            continue
        if marker in _JPEG_SOF:
            if pos + 9 > len(data):
                return None
            height = int.from_bytes(data[pos + 5 : pos + 7], 'big')
            width = int.from_bytes(data[pos + 7 : pos + 9], 'big')
            return width, height
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], 'big')
    return None


def _format_size(size: int) -> str:
    value = float(size)
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if value < 1024 or unit == 'GiB':
            return f'{value:.0f} {unit}' if unit == 'B' else f'{value:.1f} {unit}'
        value /= 1024
    raise AssertionError  # pragma: no cover


def _format_time(ns: int) -> str:
    stamp = dt.datetime.fromtimestamp(ns // 1_000_000_000, tz=dt.timezone.utc)
    return f'{stamp:%Y-%m-%d %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns / 1e9:.9f})'


def _format_image(image: ImageDetails | None) -> str:
    if image is None:
        return ''
    size = f'{image.width}x{image.height}' if image.width is not None else '?x?'
    return f'{size} {image.encoding}'


def format_bag_info(info: BagInfo) -> str:
    """A readable table, in the manner of ``ros2 bag info``."""
    lines = [
        f'Path:      {info.path}',
        f'Storage:   {info.storage}',
        f'Size:      {_format_size(info.size_bytes)}',
        f'Start:     {_format_time(info.start_ns)}',
        f'End:       {_format_time(info.end_ns)}',
        f'Duration:  {info.duration_s:.3f} s',
        f'Messages:  {info.message_count}',
        'Topics:',
    ]
    header = ('Topic', 'Type', 'Count', 'Rate (Hz)', 'Image')
    rows = [
        (
            t.name,
            t.msgtype,
            str(t.count),
            f'{t.rate_hz:.2f}' if t.rate_hz is not None else '-',
            _format_image(t.image),
        )
        for t in info.topics
    ]
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    for row in (header, *rows):
        cells = [
            cell.rjust(width) if i in {2, 3} else cell.ljust(width)
            for i, (cell, width) in enumerate(zip(row, widths))
        ]
        lines.append(('  ' + '  '.join(cells)).rstrip())
    return '\n'.join(lines)
