# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""A node's diagnostics as pure classes: what went in and out and how fast, how late its outputs
are, what it rejected and why, how full its queues are and how big its model is.

The node feeds events (:meth:`NodeDiagnostics.received`, :meth:`~NodeDiagnostics.published`,
:meth:`~NodeDiagnostics.started` / :meth:`~NodeDiagnostics.finished`) with times in seconds of one
monotonic clock; :meth:`NodeDiagnostics.report` turns them, with the node's rejection counts, queue
depths and model size, into one :class:`AreaStatus` per area (:data:`AREAS`) whose level follows the
rules of :meth:`NodeDiagnostics.report`. ``msg_utils.areas_to_diagnostics`` makes the
``diagnostic_msgs/DiagnosticArray`` of them. Every value is a string (``diagnostic_msgs/KeyValue``);
rates in Hz, latencies in ms, sizes in bytes.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass

__all__ = [
    'AREAS',
    'FATAL_REASONS',
    'LATENCY_SAMPLES',
    'RATE_WINDOW_S',
    'AreaStatus',
    'LatencyStats',
    'LatencyTracker',
    'NodeDiagnostics',
    'Queue',
    'RateMeter',
]

#: The areas of a node's report, in order: one ``DiagnosticStatus`` each, named ``<node>: <area>``.
AREAS = ('inputs', 'outputs', 'rejected', 'queues', 'model')

#: Rates are counted over the last this many seconds (or since the start, when that is shorter).
RATE_WINDOW_S = 10.0

#: Output latencies are summarised over the last this many outputs.
LATENCY_SAMPLES = 100

#: Rejection reasons that mean no data can flow on an input: level ERROR while counted.
FATAL_REASONS = ('incompatible_qos',)


class RateMeter:
    """Events per second over a sliding window of their times (seconds of one monotonic clock).

    ``rate_hz(now)``: the events in ``(now - window_s, now]`` divided by ``window_s``, or by the time
    since ``start_s`` while that is shorter (a stream that just started is not under-counted);
    ``count``: every event since the start.
    """

    def __init__(self, window_s: float = RATE_WINDOW_S, start_s: float = 0.0) -> None:
        if not window_s > 0:
            raise ValueError(f'window_s must be > 0, got {window_s}')
        self.window_s = float(window_s)
        self.start_s = float(start_s)
        self.count = 0
        self._times: deque[float] = deque()

    def tick(self, now_s: float) -> None:
        """One event at ``now_s``."""
        self.count += 1
        self._times.append(float(now_s))
        self._trim(now_s)

    def _trim(self, now_s: float) -> None:
        while self._times and self._times[0] <= now_s - self.window_s:
            self._times.popleft()

    def rate_hz(self, now_s: float) -> float:
        """Events per second in the window ending at ``now_s`` (0 before any time has passed)."""
        self._trim(now_s)
        span = min(self.window_s, now_s - self.start_s)
        return len(self._times) / span if span > 0 else 0.0


@dataclass(frozen=True)
class LatencyStats:
    """Latencies (seconds) of the last ``samples`` outputs: median, 95th percentile (nearest rank) and
    maximum; NaN when there are none. ``count``: outputs measured since the start."""

    count: int
    samples: int
    median_s: float
    p95_s: float
    max_s: float


class LatencyTracker:
    """Latency of each output: from :meth:`start` (the input that completed the item arrived) to
    :meth:`stop` (its output was published), on one monotonic clock; or :meth:`add` of a measured one.

    Statistics are over the last ``samples`` latencies. At most ``max_open`` items are open; the oldest
    is forgotten beyond that (an item that never gets an output, e.g. a frame that is no keyframe).
    """

    def __init__(self, samples: int = LATENCY_SAMPLES, max_open: int = 1000) -> None:
        if samples < 1 or max_open < 1:
            raise ValueError(f'samples and max_open must be >= 1, got {samples} and {max_open}')
        self.count = 0
        self.max_open = max_open
        self._recent: deque[float] = deque(maxlen=samples)
        self._open: dict[Hashable, float] = {}

    def start(self, key: Hashable, now_s: float) -> None:
        """Item ``key`` is ready at ``now_s`` (a later start of the same key replaces it)."""
        self._open.pop(key, None)
        self._open[key] = float(now_s)
        while len(self._open) > self.max_open:
            del self._open[next(iter(self._open))]

    def stop(self, key: Hashable, now_s: float) -> float | None:
        """Item ``key``'s output went out at ``now_s``: its latency (s), None if it was not started."""
        t0 = self._open.pop(key, None)
        if t0 is None:
            return None
        latency = max(0.0, float(now_s) - t0)
        self.add(latency)
        return latency

    def discard(self, key: Hashable) -> None:
        """Item ``key`` gets no output."""
        self._open.pop(key, None)

    def add(self, seconds: float) -> None:
        """One measured latency."""
        self.count += 1
        self._recent.append(float(seconds))

    @property
    def open(self) -> int:
        """Items started and not stopped yet."""
        return len(self._open)

    def stats(self) -> LatencyStats:
        values = sorted(self._recent)
        if not values:
            return LatencyStats(self.count, 0, math.nan, math.nan, math.nan)
        n = len(values)
        median = values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])
        p95 = values[max(0, math.ceil(0.95 * n) - 1)]
        return LatencyStats(self.count, n, median, p95, values[-1])


@dataclass(frozen=True)
class Queue:
    """A queue's ``depth`` (items waiting) and its ``bound`` (0: unbounded); full at ``depth >= bound``."""

    depth: int
    bound: int = 0

    @property
    def full(self) -> bool:
        return self.bound > 0 and self.depth >= self.bound


@dataclass(frozen=True)
class AreaStatus:
    """One area of a node's report: ``level`` ``ok``, ``warn`` or ``error``, a one-line ``message``
    and string key-values (the ``DiagnosticStatus`` values)."""

    area: str
    level: str
    message: str
    values: tuple[tuple[str, str], ...]

    def value(self, key: str) -> str:
        """The value of ``key``; KeyError naming it and the area when absent."""
        for k, v in self.values:
            if k == key:
                return v
        raise KeyError(f'{self.area}: no value {key!r}')


def _fmt(x: float, digits: int = 3) -> str:
    return 'nan' if math.isnan(x) else f'{x:.{digits}g}' if abs(x) < 1e6 else f'{x:.0f}'


class NodeDiagnostics:
    """A node's event counts and meters, and its report (see the module docstring).

    ``inputs`` / ``outputs``: the streams to report from the start (with count 0); others join when
    their first event arrives. ``clock``: seconds of a monotonic clock, read when an event or report
    gives no time (rates count from its value when this is made). Thread-safe: a worker thread may
    feed events while the executor reports.
    """

    def __init__(
        self,
        inputs: Iterable[str] = (),
        outputs: Iterable[str] = (),
        *,
        clock: Callable[[], float] = time.monotonic,
        window_s: float = RATE_WINDOW_S,
        latency_samples: int = LATENCY_SAMPLES,
    ) -> None:
        self.clock = clock
        self.start_s = float(clock())
        self.window_s = float(window_s)
        self._lock = threading.Lock()
        self._in = {s: RateMeter(window_s, self.start_s) for s in inputs}
        self._out = {s: RateMeter(window_s, self.start_s) for s in outputs}
        self.latency = LatencyTracker(latency_samples)
        self._rejected_before: dict[str, int] = {}

    def _now(self, now_s: float | None) -> float:
        return float(self.clock()) if now_s is None else float(now_s)

    # -- events -----------------------------------------------------------------------------------
    def received(self, stream: str, now_s: float | None = None) -> None:
        """One message of input ``stream`` arrived (accepted or not)."""
        with self._lock:
            self._meter(self._in, stream).tick(self._now(now_s))

    def published(self, stream: str, now_s: float | None = None) -> None:
        """One output of ``stream`` went out."""
        with self._lock:
            self._meter(self._out, stream).tick(self._now(now_s))

    def started(self, key: Hashable, now_s: float | None = None) -> None:
        """Item ``key`` (e.g. a stamp) is complete at ``now_s``: its output's latency counts from here."""
        with self._lock:
            self.latency.start(key, self._now(now_s))

    def finished(self, key: Hashable, now_s: float | None = None) -> float | None:
        """Item ``key``'s output went out at ``now_s``; its latency (s), None when it was not started."""
        with self._lock:
            return self.latency.stop(key, self._now(now_s))

    def discard(self, key: Hashable) -> None:
        """Item ``key`` gets no output (no latency is measured for it)."""
        with self._lock:
            self.latency.discard(key)

    def measured(self, seconds: float) -> None:
        """One output's latency, measured by the node."""
        with self._lock:
            self.latency.add(seconds)

    def count(self, stream: str) -> int:
        """Messages of input or output ``stream`` so far (0 when none)."""
        with self._lock:
            meter = self._in.get(stream) or self._out.get(stream)
            return 0 if meter is None else meter.count

    def _meter(self, meters: dict[str, RateMeter], stream: str) -> RateMeter:
        meter = meters.get(stream)
        if meter is None:
            meter = meters[stream] = RateMeter(self.window_s, self.start_s)
        return meter

    # -- report -----------------------------------------------------------------------------------
    def report(
        self,
        now_s: float | None = None,
        *,
        rejected: Mapping[str, int] | None = None,
        queues: Mapping[str, Queue] | None = None,
        model: Mapping[str, object] | None = None,
    ) -> list[AreaStatus]:
        """One :class:`AreaStatus` per area of :data:`AREAS` at ``now_s`` (default: the clock's now).

        - ``inputs``, ``outputs``: ``<stream>.count`` and ``<stream>.rate_hz`` of each stream;
          ``outputs`` also ``latency.count`` (outputs measured) and ``latency_ms.median`` /
          ``.p95`` / ``.max`` over the last outputs. Level OK.
        - ``rejected``: ``total`` and the count of each reason (``rejected``: every rejection so far
          by reason). WARN when the total grew since the previous report; ERROR while a reason of
          :data:`FATAL_REASONS` is counted (a publisher whose QoS cannot match: nothing arrives).
        - ``queues``: ``<queue>`` (depth) and ``<queue>.bound`` of each; WARN when one is full.
        - ``model``: the ``model`` key-values as given. Level OK.
        """
        now_s = self._now(now_s)
        with self._lock:
            ins = self._streams(self._in, now_s)
            outs = self._streams(self._out, now_s)
            lat = self.latency.stats()
        return [
            AreaStatus('inputs', 'ok', self._summary(ins, 'in'), tuple(p for _, _, ps in ins for p in ps)),
            self._outputs(outs, lat),
            self._rejected(dict(rejected or {})),
            self._queues(dict(queues or {})),
            AreaStatus(
                'model',
                'ok',
                ', '.join(f'{k} {v}' for k, v in (model or {}).items()) or 'nothing held',
                tuple((str(k), str(v)) for k, v in (model or {}).items()),
            ),
        ]

    @staticmethod
    def _streams(
        meters: dict[str, RateMeter], now_s: float
    ) -> list[tuple[str, float, list[tuple[str, str]]]]:
        rows = []
        for name, m in meters.items():
            rate = m.rate_hz(now_s)
            rows.append((name, rate, [(f'{name}.count', str(m.count)), (f'{name}.rate_hz', _fmt(rate))]))
        return rows

    @staticmethod
    def _summary(rows: list[tuple[str, float, list[tuple[str, str]]]], what: str) -> str:
        if not rows:
            return f'no {what}put streams'
        return ', '.join(f'{name} {_fmt(rate)} Hz' for name, rate, _ in rows)

    def _outputs(self, rows: list[tuple[str, float, list[tuple[str, str]]]], lat: LatencyStats) -> AreaStatus:
        pairs = [p for _, _, ps in rows for p in ps]
        pairs += [
            ('latency.count', str(lat.count)),
            ('latency_ms.median', _fmt(1e3 * lat.median_s)),
            ('latency_ms.p95', _fmt(1e3 * lat.p95_s)),
            ('latency_ms.max', _fmt(1e3 * lat.max_s)),
        ]
        message = self._summary(rows, 'out')
        if lat.samples:
            message += f'; latency median {_fmt(1e3 * lat.median_s)} ms, p95 {_fmt(1e3 * lat.p95_s)} ms'
        return AreaStatus('outputs', 'ok', message, tuple(pairs))

    def _rejected(self, counts: dict[str, int]) -> AreaStatus:
        total = sum(counts.values())
        grown = {r: n - self._rejected_before.get(r, 0) for r, n in counts.items()}
        grown = {r: d for r, d in grown.items() if d > 0}
        self._rejected_before = counts
        pairs = [('total', str(total))] + [(r, str(n)) for r, n in sorted(counts.items())]
        fatal = [r for r in FATAL_REASONS if counts.get(r, 0) > 0]
        if fatal:
            level = 'error'
            message = f'{", ".join(fatal)}: a publisher cannot be matched; {total} rejected in total'
        elif grown:
            level = 'warn'
            new = ', '.join(f'{r} {d}' for r, d in sorted(grown.items()))
            message = f'{sum(grown.values())} rejected since the last report ({new}); {total} in total'
        else:
            level = 'ok'
            message = f'none rejected since the last report; {total} in total'
        return AreaStatus('rejected', level, message, tuple(pairs))

    @staticmethod
    def _queues(queues: dict[str, Queue]) -> AreaStatus:
        pairs: list[tuple[str, str]] = []
        for name, q in queues.items():
            pairs += [(name, str(q.depth)), (f'{name}.bound', str(q.bound))]
        full = [f'{n} {q.depth}/{q.bound}' for n, q in queues.items() if q.full]
        if full:
            return AreaStatus('queues', 'warn', 'full: ' + ', '.join(full), tuple(pairs))
        message = ', '.join(f'{n} {q.depth}' + (f'/{q.bound}' if q.bound else '') for n, q in queues.items())
        return AreaStatus('queues', 'ok', message or 'no queues', tuple(pairs))
