# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""core.diagnostics: rate meters, latency statistics, rejection, queue and model areas and their levels,
on a fake clock."""

from __future__ import annotations

import math

import pytest

from ibr_ros.core.diagnostics import AREAS, LatencyTracker, NodeDiagnostics, Queue, RateMeter


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_rate_meter_counts_the_window_and_the_time_since_the_start():
    m = RateMeter(window_s=10.0, start_s=0.0)
    assert m.rate_hz(0.0) == 0.0  # no time passed yet
    for k in range(20):  # 4 Hz for 5 s
        m.tick(0.25 * (k + 1))
    assert m.count == 20
    assert m.rate_hz(5.0) == pytest.approx(4.0)  # 20 events over the 5 s since the start
    assert m.rate_hz(10.0) == pytest.approx(2.0)  # 20 events over the 10 s window
    assert m.rate_hz(12.5) == pytest.approx(1.0)  # events at (2.5, 5]: 10
    assert m.rate_hz(20.0) == 0.0  # the stream stopped
    assert m.count == 20
    with pytest.raises(ValueError, match='window_s must be > 0'):
        RateMeter(0.0)


def test_latency_median_p95_max_over_the_last_samples():
    lat = LatencyTracker(samples=20)
    assert math.isnan(lat.stats().median_s)
    assert lat.stats().count == 0
    for k in range(1, 21):  # 10 ms .. 200 ms
        lat.start(k, 1000.0)
        assert lat.stop(k, 1000.0 + 0.01 * k) == pytest.approx(0.01 * k)
    s = lat.stats()
    assert (s.count, s.samples) == (20, 20)
    assert s.median_s == pytest.approx(0.105)  # between 100 and 110 ms
    assert s.p95_s == pytest.approx(0.19)  # nearest rank: the 19th of 20
    assert s.max_s == pytest.approx(0.2)
    lat.add(1.0)  # the oldest (10 ms) falls out of the last 20
    s = lat.stats()
    assert (s.count, s.samples, s.max_s) == (21, 20, 1.0)
    assert s.median_s == pytest.approx(0.115)
    assert lat.stop(99, 5.0) is None  # never started: no sample
    assert lat.stats().count == 21


def test_latency_forgets_items_without_output():
    lat = LatencyTracker(samples=5, max_open=3)
    for k in range(5):
        lat.start(k, float(k))
    assert lat.open == 3
    assert lat.stop(0, 10.0) is None  # evicted: the oldest of more than max_open
    assert lat.stop(4, 10.0) == pytest.approx(6.0)
    lat.discard(3)
    assert lat.stop(3, 10.0) is None
    assert lat.open == 1


def test_report_areas_values_and_levels():
    clock = FakeClock(100.0)
    d = NodeDiagnostics(('image', 'pose'), ('keyframes',), clock=clock)
    for k in range(10):  # 10 images and 5 poses in the first 2 s, 2 keyframes
        clock.t = 100.0 + 0.2 * (k + 1)
        d.received('image')
        if k % 2:
            d.received('pose')
    d.started(1, 100.5)
    d.finished(1, 100.75)
    d.published('keyframes', 100.75)
    d.started(2, 101.0)
    d.published('keyframes', 101.5)
    d.finished(2, 101.5)
    rejected = {'image': 1, 'lost': 2}
    areas = d.report(102.0, rejected=rejected, queues={'pending': Queue(3, 20)}, model={'keyframes': 2})
    assert [a.area for a in areas] == list(AREAS)
    inputs, outputs, rej, queues, model = areas
    assert dict(inputs.values) == {
        'image.count': '10', 'image.rate_hz': '5', 'pose.count': '5', 'pose.rate_hz': '2.5',
    }  # fmt: skip
    assert inputs.level == 'ok'
    assert inputs.message == 'image 5 Hz, pose 2.5 Hz'
    assert outputs.value('keyframes.count') == '2'
    assert outputs.value('keyframes.rate_hz') == '1'
    assert outputs.value('latency.count') == '2'
    assert outputs.value('latency_ms.median') == '375'  # of 250 and 500 ms
    assert outputs.value('latency_ms.p95') == outputs.value('latency_ms.max') == '500'
    assert rej.level == 'warn'  # grew since the (no) previous report
    assert dict(rej.values) == {'total': '3', 'image': '1', 'lost': '2'}
    assert rej.message == '3 rejected since the last report (image 1, lost 2); 3 in total'
    assert (queues.level, dict(queues.values)) == ('ok', {'pending': '3', 'pending.bound': '20'})
    assert (model.level, dict(model.values), model.message) == ('ok', {'keyframes': '2'}, 'keyframes 2')

    # The next period: no new rejection is OK; a full queue is WARN.
    areas = d.report(103.0, rejected=rejected, queues={'pending': Queue(20, 20), 'free': Queue(5)})
    rej, queues = areas[2], areas[3]
    assert rej.level == 'ok'
    assert rej.message == 'none rejected since the last report; 3 in total'
    assert queues.level == 'warn'
    assert queues.message == 'full: pending 20/20'
    assert queues.value('free.bound') == '0'
    # One more: WARN again, naming only the new one.
    rej = d.report(104.0, rejected={'image': 1, 'lost': 3})[2]
    assert rej.level == 'warn'
    assert rej.message.startswith('1 rejected since the last report (lost 1)')
    # A publisher whose QoS cannot match: ERROR for as long as it is counted.
    for t in (105.0, 106.0):
        rej = d.report(t, rejected={'image': 1, 'lost': 3, 'incompatible_qos': 1})[2]
        assert rej.level == 'error'
        assert rej.message.startswith('incompatible_qos')


def test_streams_reported_before_their_first_message_and_added_on_the_fly():
    clock = FakeClock(0.0)
    d = NodeDiagnostics(('image',), ('depth',), clock=clock)
    inputs, outputs = d.report()[:2]
    assert dict(inputs.values) == {'image.count': '0', 'image.rate_hz': '0'}
    assert outputs.value('latency_ms.median') == 'nan'
    assert outputs.message == 'depth 0 Hz'
    clock.t = 2.0
    d.published('/camera/pose')
    assert d.count('/camera/pose') == 1
    assert d.count('image') == 0
    outputs = d.report()[1]
    assert outputs.value('/camera/pose.rate_hz') == '0.5'
    areas = NodeDiagnostics(clock=clock).report()
    assert [a.message for a in areas] == [
        'no input streams', 'no output streams', 'none rejected since the last report; 0 in total',
        'no queues', 'nothing held',
    ]  # fmt: skip
    with pytest.raises(KeyError, match="inputs: no value 'x'"):
        areas[0].value('x')
