# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``diagnostic_msgs/DiagnosticStatus`` <-> a name, a level, a message and string key-values."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, new_message

__all__ = ['LEVELS', 'pairs_to_status', 'status_to_pairs']

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
