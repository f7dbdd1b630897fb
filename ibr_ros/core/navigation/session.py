# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""One page's flight through the model: its camera and its two newest-only gates.

Queries: at most one ``novel_view/query`` in flight; poses made meanwhile wait, only the newest
(the others are counted as superseded), and it is sent, with a new stamp, when the renderer's reply
to the one in flight came (or it was given up as lost). Frames: at most one view on its way to the
page; the page says when it has shown it, and a view that arrives meanwhile replaces the waiting one
(counted). So the page never queues stale views, however slow the renderer, the socket or the page.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.navigation.flight import Motion, Navigator
from ibr_ros.core.navigation.gate import NewestOnly

__all__ = ['Query', 'ViewSession']

F = TypeVar('F')


@dataclass(frozen=True)
class Query:
    """A query to send: its stamp (ns, unique), camera-to-world pose and the page's newest input
    sequence number that the pose includes (for the page's latency readout)."""

    stamp: int
    t_wc: NDArray[np.float64]
    seq: int


class ViewSession(Generic[F]):
    """The camera and gates of one page (see module docstring); ``stamps()`` gives unique stamps.

    The navigator is None until the first keyframe gives a start pose (:meth:`start`); inputs before
    it are counted (``no_model``) and dropped.
    """

    def __init__(self, stamps: Callable[[], int], navigator: Navigator | None = None) -> None:
        self.stamps = stamps
        self.navigator = navigator
        self.queries: NewestOnly[tuple[NDArray[np.float64], int]] = NewestOnly()
        self.frames: NewestOnly[tuple[int, F]] = NewestOnly()
        self.in_flight: Query | None = None
        self.last_seq = 0  # input sequence number of the last query answered (for a retry)
        self.on_page: int | None = None  # stamp of the frame on its way to the page
        self.counts: Counter[str] = Counter()

    def start(self, navigator: Navigator, seq: int = 0) -> Query | None:
        """Fly with ``navigator`` from its pose; the query of that pose when it can go now."""
        self.navigator = navigator
        return self._offer(seq)

    def fly(self, motion: Motion, seq: int) -> Query | None:
        """Apply page input ``seq``; the query to send now, or None (nothing moved, or it waits)."""
        if self.navigator is None:
            self.counts['no_model'] += 1
            return None
        if motion.still:
            return None
        self.navigator.step(motion)
        return self._offer(seq)

    def jump(self, t_wc: ArrayLike, seq: int) -> Query | None:
        """Put the camera at ``t_wc`` (a keyframe's pose); the query to send now, or None."""
        if self.navigator is None:
            self.counts['no_model'] += 1
            return None
        self.navigator.jump(t_wc)
        return self._offer(seq)

    def refresh(self, seq: int) -> Query | None:
        """Ask again for the current pose (the model grew; the output size changed)."""
        return None if self.navigator is None else self._offer(seq)

    def _offer(self, seq: int) -> Query | None:
        assert self.navigator is not None
        return self._send(self.queries.offer((self.navigator.pose, seq)))

    def _send(self, item: tuple[NDArray[np.float64], int] | None) -> Query | None:
        if item is None:
            return None
        self.in_flight = Query(self.stamps(), item[0], item[1])
        return self.in_flight

    def replied(self, stamp: int, result: str) -> Query | None:
        """The renderer's reply to query ``stamp`` is complete (``result``: answered, incomplete,
        refused or lost); the waiting query to send now, or None. A reply to another stamp (not
        this page's, or one given up) changes nothing."""
        if self.in_flight is None or stamp != self.in_flight.stamp:
            return None
        self.counts[result] += 1
        self.last_seq = self.in_flight.seq
        self.in_flight = None
        return self._send(self.queries.done())

    def frame(self, stamp: int, payload: F) -> tuple[int, F] | None:
        """A view for the page; ``(stamp, payload)`` to send now, or None (it waits, newest only)."""
        sent = self.frames.offer((stamp, payload))
        if sent is not None:
            self.on_page = sent[0]
        return sent

    def shown(self, stamp: int) -> tuple[int, F] | None:
        """The page has shown view ``stamp``; the waiting view to send now, or None."""
        if stamp != self.on_page:
            self.counts['stale_ack'] += 1
            return None
        self.on_page = None
        sent = self.frames.done()
        if sent is not None:
            self.on_page = sent[0]
        return sent

    def stats(self) -> dict[str, int]:
        """Counters for the page's readout: queries sent and superseded, views superseded, results."""
        return {
            'queries': self.queries.sent,
            'superseded_queries': self.queries.superseded,
            'views_sent': self.frames.sent,
            'superseded_views': self.frames.superseded,
            **self.counts,
        }
