# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pick the camera, camera info, pose, GNSS, depth and sky mask topics of a bag by message type.

Explicit topic names override detection. Where several topics fit, the choice is deterministic
(best name, then alphabetical) and logged.
"""

from __future__ import annotations

import logging
import posixpath
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ibr_ros.errors import BagError

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Mapping

    from ibr_ros.bag.reader import BagReader, TopicInfo

__all__ = [
    'CAMERA_INFO',
    'COMPRESSED_IMAGE',
    'IMAGE',
    'NAVSATFIX',
    'POSE_TYPES',
    'TopicSelection',
    'detect_topics',
]

log = logging.getLogger(__name__)

IMAGE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
NAVSATFIX = 'sensor_msgs/msg/NavSatFix'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
ODOMETRY = 'nav_msgs/msg/Odometry'
TF = 'tf2_msgs/msg/TFMessage'
#: Pose message types, preferred first.
POSE_TYPES = (POSE_STAMPED, ODOMETRY, TF)
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
#: Image topics with these words in their name are not the camera image.
NOT_CAMERA_WORDS = ('depth', 'mask', 'sky')


@dataclass(frozen=True)
class TopicSelection:
    """Chosen topics (None: not in the bag), whether the image is compressed, the pose type."""

    image: str | None = None
    camera_info: str | None = None
    pose: str | None = None
    navsat: str | None = None
    depth: str | None = None
    sky_mask: str | None = None
    image_compressed: bool = False
    pose_type: str | None = None


def detect_topics(
    reader: BagReader,
    *,
    image: str | None = None,
    camera_info: str | None = None,
    pose: str | None = None,
    navsat: str | None = None,
    depth: str | None = None,
    sky_mask: str | None = None,
) -> TopicSelection:
    """Choose the topics of ``reader``'s bag; a given name must exist and have a fitting type.

    Raises:
        BagError: A named topic is missing (the message lists the bag's topics) or of the wrong type.

    """
    topics = reader.topics
    path = reader.path

    def pick(
        role: str,
        given: str | None,
        types: Collection[str],
        accept: Callable[[TopicInfo], bool] = lambda t: True,
        rank: Callable[[TopicInfo], tuple] = lambda t: (),
    ) -> str | None:
        if given is not None:
            return _check(path, topics, role, given, types)
        candidates = sorted(
            (t for t in topics.values() if t.msgtype in types and accept(t)), key=lambda t: (rank(t), t.name)
        )
        if len(candidates) > 1:
            names = ', '.join(t.name for t in candidates)
            log.info('%s: several %s topics (%s); using %s', path, role, names, candidates[0].name)
        return candidates[0].name if candidates else None

    chosen_image = pick('image', image, IMAGE_TYPES, _is_camera, _image_rank)
    namespace = _namespace(chosen_image)
    chosen_pose = pick(
        'pose',
        pose,
        POSE_TYPES,
        lambda t: t.msgtype != TF or t.name == '/tf',
        lambda t: (POSE_TYPES.index(t.msgtype),),
    )
    return TopicSelection(
        image=chosen_image,
        camera_info=pick(
            'camera_info', camera_info, (CAMERA_INFO,), rank=lambda t: (not t.name.startswith(namespace),)
        ),
        pose=chosen_pose,
        navsat=pick('navsat', navsat, (NAVSATFIX,)),
        depth=pick('depth', depth, (IMAGE,), lambda t: 'depth' in t.name.lower()),
        sky_mask=pick('sky_mask', sky_mask, (IMAGE,), lambda t: 'sky' in t.name.lower()),
        image_compressed=chosen_image is not None and topics[chosen_image].msgtype == COMPRESSED_IMAGE,
        pose_type=topics[chosen_pose].msgtype if chosen_pose is not None else None,
    )


def _check(
    path: object, topics: Mapping[str, TopicInfo], role: str, name: str, types: Collection[str]
) -> str:
    if (info := topics.get(name)) is None:
        available = ', '.join(f'{t.name} ({t.msgtype})' for t in topics.values()) or 'none'
        raise BagError(path, f'{role} topic {name} is not in the bag; topics: {available}')
    if info.msgtype not in types:
        raise BagError(path, f'{role} topic {name} is {info.msgtype}, expected {" or ".join(types)}')
    return name


def _is_camera(topic: TopicInfo) -> bool:
    name = topic.name.lower()
    return not any(word in name for word in NOT_CAMERA_WORDS)


def _image_rank(topic: TopicInfo) -> tuple:
    """Names with ``image_raw`` first, then ``image``, then ``compressed``; uncompressed before compressed."""
    name = topic.name.lower()
    score = 0 if 'image_raw' in name else 1 if 'image' in name else 2 if name.endswith('/compressed') else 3
    return score, topic.msgtype != IMAGE


def _namespace(topic: str | None) -> str:
    """``/cam/image_raw/compressed`` -> ``/cam/``: camera info topics here are preferred."""
    if topic is None:
        return '/'
    parts = [p for p in topic.split('/') if p]
    while parts and (parts[-1] == 'compressed' or 'image' in parts[-1]):
        parts.pop()
    return posixpath.join('/', *parts, '')
