# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``diagnostic_msgs/DiagnosticStatus`` <-> a name, a level, a message and string key-values;
``diagnostic_msgs/DiagnosticArray`` <-> the :class:`~ibr_ros.core.render.reply.ReplyStatus` of a query,
and <-> a node's ``/diagnostics`` report (:class:`~ibr_ros.core.diagnostics.AreaStatus` per area)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ibr_ros.core.diagnostics import AreaStatus
from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, coerce_header, new_message, stamp_to_ns

if TYPE_CHECKING:  # imported where used: ibr_ros.core.render loads the renderer (numba, OpenCV)
    from ibr_ros.core.render.reply import ReplyStatus

__all__ = [
    'LEVELS',
    'areas_to_diagnostics',
    'diagnostics_to_areas',
    'diagnostics_to_reply',
    'pairs_to_status',
    'reply_to_diagnostics',
    'status_to_pairs',
]

#: DiagnosticStatus.level values by name.
LEVELS = {'ok': 0, 'warn': 1, 'error': 2, 'stale': 3}


def pairs_to_status(
    name: str,
    pairs: Sequence[tuple[str, str]],
    *,
    message: str = '',
    level: str = 'ok',
    hardware_id: str = '',
    flavor: Flavor = 'rclpy',
) -> Any:
    """A ``DiagnosticStatus`` named ``name`` whose ``values`` are ``pairs`` (in order)."""
    if level not in LEVELS:
        raise MessageError(f'level must be one of {", ".join(LEVELS)}, got {level!r}')
    values = [new_message('diagnostic_msgs/msg/KeyValue', flavor, key=str(k), value=str(v)) for k, v in pairs]
    return new_message(
        'diagnostic_msgs/msg/DiagnosticStatus',
        flavor,
        level=bytes([LEVELS[level]]) if flavor == 'rclpy' else LEVELS[level],
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=values,
    )


def status_to_pairs(msg: Any) -> list[tuple[str, str]]:
    """The ``values`` of a ``DiagnosticStatus`` as ``(key, value)`` pairs; MessageError if it has none."""
    values = getattr(msg, 'values', None)
    if values is None:
        raise MessageError(f'{type(msg).__name__} is not a DiagnosticStatus (no values field)')
    return [(str(kv.key), str(kv.value)) for kv in values]


def _level(status: Any) -> int:
    """A ``DiagnosticStatus``'s level as an int (rclpy gives one byte, rosbags an int)."""
    return status.level[0] if isinstance(status.level, bytes) else int(status.level)


def reply_to_diagnostics(
    status: ReplyStatus, header: Any = None, *, name: str, flavor: Flavor = 'rclpy'
) -> Any:
    """A ``DiagnosticArray`` stamped by ``header`` (the query's) holding one ``DiagnosticStatus`` named
    ``name`` with ``status``'s level, message and key-values."""
    return new_message(
        'diagnostic_msgs/msg/DiagnosticArray',
        flavor,
        header=coerce_header(header, flavor),
        status=[
            pairs_to_status(
                name, status.to_pairs(), message=status.message, level=status.level, flavor=flavor
            )
        ],
    )


def diagnostics_to_reply(msg: Any) -> tuple[int, ReplyStatus]:
    """``(stamp ns, status)`` of a :func:`reply_to_diagnostics` message; MessageError when it holds not
    exactly one status, or one that is not a reply status (its level must match its result)."""
    statuses = getattr(msg, 'status', None)
    if statuses is None or len(statuses) != 1:
        raise MessageError(
            f'a reply status is a DiagnosticArray with one DiagnosticStatus, got {type(msg).__name__} with '
            f'{"no" if statuses is None else len(statuses)} statuses'
        )
    from ibr_ros.core.render.reply import ReplyStatus

    st = statuses[0]
    try:
        reply = ReplyStatus.from_pairs(status_to_pairs(st), message=str(st.message))
    except ValueError as exc:
        raise MessageError(f'not a reply status: {exc}') from exc
    level = _level(st)
    if level != LEVELS[reply.level]:
        raise MessageError(f'reply status level {level} does not match its result {reply.result!r}')
    return stamp_to_ns(msg.header.stamp), reply


def areas_to_diagnostics(
    areas: Sequence[AreaStatus],
    header: Any = None,
    *,
    node: str,
    hardware_id: str = '',
    flavor: Flavor = 'rclpy',
) -> Any:
    """A node's ``/diagnostics`` message: a ``DiagnosticArray`` stamped by ``header`` (the report's
    time) with one ``DiagnosticStatus`` per area, named ``<node>: <area>`` (diagnostic_updater's
    convention) with ``hardware_id``, the area's level, message and key-values."""
    return new_message(
        'diagnostic_msgs/msg/DiagnosticArray',
        flavor,
        header=coerce_header(header, flavor),
        status=[
            pairs_to_status(
                f'{node}: {a.area}',
                a.values,
                message=a.message,
                level=a.level,
                hardware_id=hardware_id,
                flavor=flavor,
            )
            for a in areas
        ],
    )


def diagnostics_to_areas(msg: Any, node: str) -> dict[str, AreaStatus]:
    """The areas of ``node`` in a ``DiagnosticArray`` (statuses named ``<node>: <area>``; others are
    ignored), by area; MessageError for a status of ``node`` with an unknown level."""
    statuses = getattr(msg, 'status', None)
    if statuses is None:
        raise MessageError(f'{type(msg).__name__} is not a DiagnosticArray (no status field)')
    names = {v: k for k, v in LEVELS.items()}
    out = {}
    for st in statuses:
        prefix, sep, area = str(st.name).partition(': ')
        if not sep or prefix != node:
            continue
        level = _level(st)
        if level not in names:
            raise MessageError(f'diagnostics of {node}: {area} has level {level}, not one of 0..3')
        out[area] = AreaStatus(area, names[level], str(st.message), tuple(status_to_pairs(st)))
    return out
