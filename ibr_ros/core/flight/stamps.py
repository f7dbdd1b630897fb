# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Assemble the messages of one frame (image, camera_info, pose, ...) by identical header stamps.

:class:`StampAssembler` keeps the partial records of at most ``max_pending`` stamps (ns). When a new
stamp arrives while it is full, the oldest pending record is dropped, or the new message itself when
it is older than everything pending; either way ``on_incomplete`` is called with a line naming the
stamp and the missing fields (the nodes count it as rejected input, reason ``incomplete``). With
``supersede`` (in-order sensor streams) completing a record also drops every older pending one.
With ``max_bytes`` the pending records are bounded in bytes too (numpy arrays in the values, also
inside tuples): the oldest pending records are dropped to make room, and a single value larger than
``max_bytes`` is rejected outright (``on_incomplete`` again).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ['StampAssembler']


class StampAssembler:
    """Collects one value per field for each stamp; :meth:`put` returns the record once complete.

    ``fields``: the names of the parts of a record; ``what``: how the detail lines name a record
    ('frame', 'keyframe'). Not thread-safe.
    """

    def __init__(
        self,
        fields: Sequence[str],
        max_pending: int,
        on_incomplete: Callable[[str], None],
        *,
        what: str = 'frame',
        supersede: bool = False,
        max_bytes: int | None = None,
    ) -> None:
        if not fields or len(set(fields)) != len(fields):
            raise ValueError(f'fields must be distinct names, got {list(fields)}')
        if max_pending < 1:
            raise ValueError(f'max_pending must be >= 1, got {max_pending}')
        self.fields = tuple(fields)
        self.max_pending = int(max_pending)
        self.on_incomplete = on_incomplete
        self.what = what
        self.supersede = supersede
        self.max_bytes = max_bytes
        self._pending: dict[int, dict[str, Any]] = {}
        self._bytes: dict[int, int] = {}  # stamp -> bytes of its pending values
        self.pending_bytes = 0

    def __len__(self) -> int:
        return len(self._pending)

    def __contains__(self, stamp: object) -> bool:
        return stamp in self._pending

    def partial(self, stamp: int) -> dict[str, Any]:
        """A copy of the pending fields of ``stamp`` (empty when none)."""
        return dict(self._pending.get(stamp, {}))

    def discard(self, stamp: int) -> None:
        """Forget the pending record of ``stamp`` (no ``on_incomplete``)."""
        self._pop(stamp)

    def _pop(self, stamp: int) -> dict[str, Any]:
        self.pending_bytes -= self._bytes.pop(stamp, 0)
        return self._pending.pop(stamp, {})

    def _missing(self, record: dict[str, Any]) -> str:
        return ', '.join(f for f in self.fields if f not in record)

    def put(self, stamp: int, field: str, value: Any) -> dict[str, Any] | None:
        """Store ``value`` as ``field`` of ``stamp`` (ns); the complete record (field -> value) or None.

        A repeated field replaces the earlier value. Raises ValueError for an unknown ``field``.
        """
        if field not in self.fields:
            raise ValueError(f'field must be one of {list(self.fields)}, got {field!r}')
        stamp = int(stamp)
        size = _nbytes(value)
        if self.max_bytes is not None and size > self.max_bytes:
            self.on_incomplete(
                f'{field} of {self.what} {stamp} ns rejected: {size / 2**20:.1f} MiB, more than all pending '
                f'{self.what}s may hold ({self.max_bytes / 2**20:.1f} MiB)'
            )
            return None
        record = self._pending.get(stamp)
        if record is None:
            if len(self._pending) >= self.max_pending:
                oldest = min(self._pending)
                if stamp < oldest:
                    n = len(self._pending)
                    self.on_incomplete(
                        f'{field} of {self.what} {stamp} ns is older than all {n} pending ones'
                    )
                    return None
                self.on_incomplete(
                    f'{self.what} at {oldest} ns dropped (max_pending {self.max_pending}) before its '
                    f'{self._missing(self._pop(oldest))} arrived'
                )
            record = self._pending[stamp] = {}
        old = _nbytes(record.get(field))
        record[field] = value
        self._bytes[stamp] = self._bytes.get(stamp, 0) + size - old
        self.pending_bytes += size - old
        while self.max_bytes is not None and self.pending_bytes > self.max_bytes and len(self._pending) > 1:
            oldest = min(s for s in self._pending if s != stamp)
            self.on_incomplete(
                f'{self.what} at {oldest} ns dropped (pending {self.what}s over {self.max_bytes / 2**20:.1f} '
                f'MiB) before its {self._missing(self._pop(oldest))} arrived'
            )
        if len(record) < len(self.fields):
            return None
        self._pop(stamp)
        if self.supersede:
            for old in sorted(s for s in self._pending if s < stamp):
                self.on_incomplete(
                    f'{self.what} at {old} ns superseded by {stamp} ns before its '
                    f'{self._missing(self._pop(old))} arrived'
                )
        return record


def _nbytes(value: Any) -> int:
    """Bytes of the numpy arrays in ``value`` (itself, or the items of a tuple or list)."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 0
