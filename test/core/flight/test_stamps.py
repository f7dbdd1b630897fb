# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""StampAssembler: messages of one frame matched by stamp, bounded, incomplete ones reported (no DDS)."""

from __future__ import annotations

import pytest

from ibr_ros.core.flight.stamps import StampAssembler
from ibr_ros.nodes.common import StampAssembler as Reexported

FIELDS = ('image', 'camera_info', 'pose')


def make(max_pending: int = 2, **kw) -> tuple[StampAssembler, list[str]]:
    lost: list[str] = []
    return StampAssembler(FIELDS, max_pending, lost.append, **kw), lost


def test_a_record_completes_in_any_order_and_leaves_the_pending_set():
    a, lost = make()
    assert Reexported is StampAssembler
    assert a.put(10, 'pose', 'p') is None
    assert a.put(10, 'image', 'i0') is None
    assert a.put(10, 'image', 'i1') is None  # a repeated field replaces the earlier value
    assert a.partial(10) == {'pose': 'p', 'image': 'i1'}
    assert a.put(10, 'camera_info', 'c') == {'pose': 'p', 'image': 'i1', 'camera_info': 'c'}
    assert 10 not in a
    assert len(a) == 0
    assert a.partial(10) == {}
    assert lost == []
    with pytest.raises(ValueError, match=r"field must be one of .* got 'depth'"):
        a.put(11, 'depth', 1)
    with pytest.raises(ValueError, match='max_pending'):
        StampAssembler(FIELDS, 0, lost.append)
    with pytest.raises(ValueError, match='distinct'):
        StampAssembler(('a', 'a'), 1, lost.append)


def test_when_full_the_oldest_is_dropped_and_older_messages_are_rejected():
    a, lost = make(max_pending=2, what='keyframe')
    a.put(20, 'image', 1)
    a.put(30, 'image', 1)
    a.put(30, 'pose', 1)
    assert a.put(10, 'pose', 1) is None  # older than everything pending: rejected
    assert lost == ['pose of keyframe 10 ns is older than all 2 pending ones']
    assert 10 not in a
    a.put(40, 'image', 1)  # a new stamp: 20 is dropped
    assert lost[1] == 'keyframe at 20 ns dropped (max_pending 2) before its camera_info, pose arrived'
    assert sorted([s for s in (20, 30, 40) if s in a]) == [30, 40]
    a.put(30, 'camera_info', 1)  # completes; a known stamp never evicts
    assert lost[2:] == []
    a.discard(40)
    assert len(a) == 0


def test_supersede_drops_older_pending_records_on_completion():
    a, lost = make(max_pending=5, supersede=True)
    a.put(1, 'image', 1)
    a.put(2, 'pose', 1)
    a.put(4, 'image', 1)
    for f in FIELDS:
        a.put(3, f, 1)
    assert lost == [
        'frame at 1 ns superseded by 3 ns before its camera_info, pose arrived',
        'frame at 2 ns superseded by 3 ns before its image, camera_info arrived',
    ]
    assert 4 in a
    assert len(a) == 1
