# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Flying policy of the web viewer: motion, speed, the keyframe map and the newest-only gates."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.navigation import (
    Motion,
    NavigationError,
    Navigator,
    NewestOnly,
    TopDownMap,
    ViewSession,
    scene_speed,
)

#: A camera 20 m up at the origin looking north (+y), level.
NORTH = look_at([0.0, 0.0, 20.0], [0.0, 10.0, 20.0])


def test_keys_move_in_the_camera_frame_at_the_scene_speed() -> None:
    nav = Navigator(NORTH, speed_mps=4.0, fast_factor=4.0)
    np.testing.assert_allclose(nav.step(Motion(forward=1, dt=0.25))[:3, 3], [0, 1, 20], atol=1e-12)
    np.testing.assert_allclose(nav.step(Motion(right=1, dt=0.25))[:3, 3], [1, 1, 20], atol=1e-12)  # east
    np.testing.assert_allclose(nav.step(Motion(up=1, dt=0.25))[:3, 3], [1, 1, 21], atol=1e-12)  # -y: up
    np.testing.assert_allclose(
        nav.step(Motion(forward=-1, dt=0.25, fast=True))[:3, 3], [1, -3, 21], atol=1e-12
    )
    np.testing.assert_allclose(nav.pose[:3, :3], NORTH[:3, :3], atol=1e-12)  # moving does not turn


def test_a_stalled_page_does_not_teleport_the_camera() -> None:
    nav = Navigator(NORTH, speed_mps=1.0)
    assert nav.step(Motion(forward=1, dt=30.0))[1, 3] == pytest.approx(0.25)  # MAX_DT_S


def test_yaw_turns_left_about_up_and_pitch_stops_short_of_the_pole() -> None:
    nav = Navigator(NORTH, turn_rate_deg_s=90.0, drag_deg_per_px=0.5)
    z = nav.step(Motion(yaw=1, dt=0.25))[:3, 2]  # 22.5 deg left of north: towards west (-x)
    np.testing.assert_allclose(
        z, [-math.sin(math.radians(22.5)), math.cos(math.radians(22.5)), 0], atol=1e-12
    )
    nav.step(Motion(drag_px=(45.0, 0.0), dt=0.0))  # drag right 45 px = 22.5 deg right: north again
    np.testing.assert_allclose(nav.pose[:3, 2], [0, 1, 0], atol=1e-12)
    nav.step(Motion(drag_px=(0.0, 20.0)))  # drag down: look 10 deg down
    assert nav.elevation_deg() == pytest.approx(-10.0)
    for _ in range(20):
        nav.step(Motion(pitch=1, dt=0.25))
    assert nav.elevation_deg() == pytest.approx(89.0)
    r = nav.pose[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert r[:, 0] @ [0, 0, 1] == pytest.approx(0.0, abs=1e-12)  # no roll: x stays level


def test_a_nadir_camera_may_pitch_back_but_not_further() -> None:
    nadir = look_at([0.0, 0.0, 20.0], [0.0, 0.001, 0.0])
    nav = Navigator(nadir)
    e = nav.elevation_deg()
    assert e < -89.0
    assert nav.step(Motion(pitch=-1, dt=0.1)) is not None
    assert nav.elevation_deg() == pytest.approx(e)
    nav.step(Motion(pitch=1, dt=0.25))
    assert nav.elevation_deg() == pytest.approx(e + 15.0)


@pytest.mark.parametrize(
    ('msg', 'match'),
    [
        ({'forward': 2}, 'input field forward must be -1..1, got 2'),
        ({'yaw': 'left'}, "input field yaw must be a finite number, got 'left'"),
        ({'dt': float('nan')}, 'input field dt must be a finite number'),
        ({'drag': [1]}, r'input field drag must be \[dx, dy\]'),
        ({'fast': 1}, 'input field fast must be true or false, got 1'),
    ],
)
def test_bad_page_input_is_an_error_naming_the_field(msg, match) -> None:
    with pytest.raises(NavigationError, match=match):
        Motion.from_json(msg)


def test_motion_from_the_page() -> None:
    m = Motion.from_json({'type': 'fly', 'forward': 1, 'drag': [3, -2], 'dt': 0.016, 'fast': True})
    assert m == Motion(forward=1.0, drag_px=(3.0, -2.0), dt=0.016, fast=True)
    assert Motion(forward=1.0).still
    assert not m.still
    assert Motion().still


def test_speed_from_the_keyframe_spacing() -> None:
    line = [[2.0 * i, 0.0, 30.0] for i in range(5)] + [[0.0, 0.0, 30.0]]  # a duplicate is not a spacing
    assert scene_speed(line, 2.0, 1.0) == pytest.approx(4.0)
    assert scene_speed(line[:1], 2.0, 1.5) == 1.5
    assert scene_speed([[1, 1, 1], [1, 1, 1]], 2.0, 1.5) == 1.5


def test_map_fits_the_keyframes_north_up_and_picks_the_one_clicked() -> None:
    m = TopDownMap(size_px=200, margin_px=10)
    assert m.add(1, look_at([0.0, 0.0, 20.0], [0.0, 10.0, 0.0]))
    assert m.add(2, look_at([100.0, 50.0, 20.0], [110.0, 50.0, 0.0]))
    assert not m.add(2, look_at([100.0, 50.0, 20.0], [110.0, 50.0, 0.0]))  # unchanged
    a, b = m.keyframes()
    assert (a.stamp, a.u, a.v) == (1, pytest.approx(10.0), pytest.approx(145.0))  # west, south
    assert (b.u, b.v) == (pytest.approx(190.0), pytest.approx(55.0))  # east, north
    assert a.heading == pytest.approx(-math.pi / 2)  # north: up on the canvas
    assert b.heading == pytest.approx(0.0)  # east: right
    assert m.pick(12.0, 150.0) == 1
    assert m.pick(185.0, 60.0) == 2
    assert m.pick(100.0, 100.0) is None


def test_newest_only_gate() -> None:
    g: NewestOnly[int] = NewestOnly()
    assert g.offer(1) == 1
    assert g.offer(2) is None
    assert g.offer(3) is None
    assert g.done() == 3
    assert g.done() is None
    assert not g.busy
    assert (g.sent, g.superseded) == (2, 1)


def _session() -> ViewSession[str]:
    stamps = itertools.count(100)
    return ViewSession(lambda: next(stamps))


def test_one_query_in_flight_and_only_the_newest_pose_waits() -> None:
    s = _session()
    assert s.fly(Motion(forward=1, dt=0.1), 1) is None
    assert s.counts['no_model'] == 1
    q0 = s.start(Navigator(NORTH, speed_mps=10.0))
    assert q0 is not None
    assert q0.stamp == 100
    assert q0.seq == 0
    assert s.fly(Motion(forward=1, dt=0.1), 1) is None  # in flight: waits
    assert s.fly(Motion(forward=1, dt=0.1), 2) is None  # supersedes input 1
    assert s.fly(Motion(), 3) is None  # nothing moved: nothing offered
    assert s.replied(999, 'answered') is None  # not this page's query
    q1 = s.replied(100, 'answered')
    assert q1 is not None
    assert (q1.stamp, q1.seq) == (101, 2)
    assert q1.t_wc[1, 3] == pytest.approx(2.0)
    assert s.replied(101, 'refused') is None
    assert s.in_flight is None
    assert s.refresh(2) is not None
    assert s.stats() == {'queries': 3, 'superseded_queries': 1, 'views_sent': 0, 'superseded_views': 0,
                         'no_model': 1, 'answered': 1, 'refused': 1}  # fmt: skip


def test_one_view_on_its_way_to_the_page_and_only_the_newest_waits() -> None:
    s = _session()
    assert s.frame(1, 'a') == (1, 'a')
    assert s.frame(2, 'b') is None
    assert s.frame(3, 'c') is None
    assert s.shown(2) is None
    assert s.counts['stale_ack'] == 1
    assert s.shown(1) == (3, 'c')
    assert s.shown(3) is None
    assert s.on_page is None
    assert s.stats()['superseded_views'] == 1


def test_a_jump_puts_the_camera_on_the_keyframe() -> None:
    s = _session()
    s.start(Navigator(NORTH))
    target = look_at([5.0, 5.0, 30.0], [0.0, 0.0, 0.0])
    assert s.jump(target, 7) is None  # waits for the query in flight
    q = s.replied(100, 'answered')
    assert q is not None
    assert q.seq == 7
    np.testing.assert_allclose(q.t_wc, target)
