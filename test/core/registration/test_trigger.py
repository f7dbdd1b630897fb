# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""SfmTrigger: when the depth_refiner registers keyframes without poses itself (no DDS, no SfM)."""

from __future__ import annotations

import pytest

from ibr_ros.core.registration.trigger import SfmConfig, SfmTrigger


def test_always_is_sfm_mode_from_the_start_and_ignores_poses():
    t = SfmTrigger(SfmConfig(mode='always'))
    assert t.active
    assert not t.pose()
    assert t.poses_seen == 0
    assert t.status('pose') == ''  # only 'auto' warns that the flight stays in SfM mode
    assert t.active


def test_auto_starts_only_when_the_status_says_no_poses():
    t = SfmTrigger(SfmConfig(mode='auto'))
    assert not t.active
    assert [t.wait_for_pose(s) for s in (1, 2, 3, 4, 3)] == [False, False, True, False, False]
    assert t.status('pose') == ''
    assert t.status('unknown') == ''
    assert not t.active
    assert t.status('none') == 'start'
    assert t.active
    assert sorted(t.waiting) == [1, 2, 3, 4]  # registered first by the caller
    assert t.status('none') == ''  # started once
    assert t.status('pose') == 'keep_sfm'  # the frame is fixed: stays
    assert t.active
    assert not t.pose()


def test_auto_with_poses_seen_stays_posed():
    t = SfmTrigger(SfmConfig(mode='auto'))
    assert t.pose()
    assert t.poses_seen == 1
    assert not t.wait_for_pose(7)  # a pose was seen: its own pose will come
    assert not t.waiting
    assert t.status('none') == 'keep_poses'
    assert not t.active


def test_off_never_registers():
    t = SfmTrigger(SfmConfig(mode='off'))
    assert t.status('none') == ''
    assert not t.active
    t.add(1)
    assert not t.due(flush=True, registered=10, framed=True)


def test_first_registration_needs_min_keyframes_then_every_or_flush():
    t = SfmTrigger(SfmConfig(mode='always', min_keyframes=4, every=2))
    assert not t.due(flush=True, registered=0, framed=False)  # nothing queued
    for s in (1, 2, 3):
        t.add(s)
    assert not t.due(flush=True, registered=0, framed=False)  # flushing does not lower the minimum
    assert t.due(flush=False, registered=1, framed=False)  # one added before, still without a frame
    t.add(4)
    assert t.due(flush=False, registered=0, framed=False)
    assert t.take() == [1, 2, 3, 4]
    assert t.queue == []
    t.add(5)
    assert not t.due(flush=False, registered=4, framed=True)
    assert t.due(flush=True, registered=4, framed=True)
    t.add(6)
    assert t.due(flush=False, registered=4, framed=True)


@pytest.mark.parametrize(
    ('kw', 'match'),
    [
        ({'mode': 'sometimes'}, "mode must be 'auto', 'always' or 'off', got 'sometimes'"),
        ({'min_keyframes': 2}, 'min_keyframes must be >= 3, got 2'),
        ({'every': 0}, 'every must be >= 1, got 0'),
        ({'max_side': -1}, r'max_side must be >= 0 \(0 = as received\), got -1'),
    ],
)
def test_config_errors_name_the_field_and_value(kw, match):
    with pytest.raises(ValueError, match=match):
        SfmConfig(**kw)
