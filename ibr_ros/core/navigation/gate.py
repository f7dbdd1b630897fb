# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""At most one request in flight, and only the newest waiting: the others are superseded (counted)."""

from __future__ import annotations

from typing import Generic, TypeVar

__all__ = ['NewestOnly']

T = TypeVar('T')


class NewestOnly(Generic[T]):
    """A gate that lets one item through at a time and keeps only the newest of those waiting.

    :meth:`offer` returns the item when nothing is in flight (send it now), else keeps it as the
    waiting one, replacing (and counting as ``superseded``) the one that waited before. :meth:`done`
    ends the item in flight and returns the waiting one, now in flight, if any.
    """

    def __init__(self) -> None:
        self.busy = False
        self.waiting: T | None = None
        self.sent = 0
        self.superseded = 0

    def offer(self, item: T) -> T | None:
        """``item`` to send now, or None when it waits (see class docstring)."""
        if not self.busy:
            self.busy = True
            self.sent += 1
            return item
        if self.waiting is not None:
            self.superseded += 1
        self.waiting = item
        return None

    def done(self) -> T | None:
        """The item in flight is over; the waiting one to send now, or None (the gate is free)."""
        self.busy = False
        item, self.waiting = self.waiting, None
        return None if item is None else self.offer(item)
