# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The message type store shared by bag reading and writing (rosbags, ROS 2 Jazzy)."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from rosbags.typesys import Stores, get_typestore

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

#: Which rosbags store :data:`TYPESTORE` is.
STORE = Stores.ROS2_JAZZY

#: ROS 2 Jazzy message types. Build messages with ``TYPESTORE.types['sensor_msgs/msg/Image'](...)``.
#: Shared: do not ``register`` types in it, make your own store for that.
TYPESTORE: Typestore = get_typestore(STORE)

_RCLPY_MODULE = re.compile(r'^(?P<pkg>\w+)\.(?P<kind>msg|srv|action)\._\w+$')


def is_rclpy_message(msg: object) -> bool:
    """Whether ``msg`` is an rclpy (rosidl_generator_py) message object."""
    cls = type(msg)
    return hasattr(cls, '_TYPE_SUPPORT') or type(cls).__name__.startswith('Metaclass_')


def msgtype_of(msg: object) -> str:
    """The ROS 2 type name (``pkg/msg/Name``) of a rosbags or rclpy message object.

    Raises:
        TypeError: ``msg`` is neither.

    """
    if isinstance(msgtype := getattr(msg, '__msgtype__', None), str):
        return msgtype
    cls = type(msg)
    if is_rclpy_message(msg) and (match := _RCLPY_MODULE.match(cls.__module__)):
        return f'{match["pkg"]}/{match["kind"]}/{cls.__name__}'
    raise TypeError(f'not a ROS message object: {cls.__module__}.{cls.__qualname__}')


def serialize(msg: object, typestore: Typestore = TYPESTORE) -> tuple[str, bytes]:
    """``(msgtype, CDR bytes)`` of a rosbags message (serialised with ``typestore``) or an rclpy one.

    rclpy messages are re-serialised through ``typestore`` where it knows the type, so that equal
    messages give equal bytes.
    """
    msgtype = msgtype_of(msg)
    if hasattr(msg, '__msgtype__'):
        if msgtype not in typestore.types:
            raise KeyError(f'message type {msgtype!r} is not in the type store')
        return msgtype, bytes(typestore.serialize_cdr(msg, msgtype))
    from rclpy.serialization import serialize_message

    cdr = serialize_message(msg)
    if msgtype in typestore.types:  # rclpy leaves alignment padding uninitialised: make it zeros
        cdr = bytes(typestore.serialize_cdr(typestore.deserialize_cdr(cdr, msgtype), msgtype))
    return msgtype, cdr


def ros2msg_definition(msgtype: str, typestore: Typestore = TYPESTORE) -> str:
    """The ``ros2msg`` schema text of ``msgtype`` (with its dependencies), as rosbag2 stores it."""
    return typestore.generate_msgdef(msgtype, ros_version=2)[0]
