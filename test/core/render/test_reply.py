# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""ReplyPolicy and ReplyStatus: which renders answer a query, and the status every query gets."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.render import REFUSALS, ReplyPolicy, ReplyStatus


def test_views_below_the_threshold_are_refused_unless_published_flagged():
    policy = ReplyPolicy(0.8)
    ok = policy.judge(np.float64(0.8), ['1', '2'], 12.5)
    assert (ok.result, ok.reason, ok.level, ok.published) == ('answered', '', 'ok', True)
    assert ok.valid_fraction == 0.8
    assert type(ok.valid_fraction) is float
    assert ok.views == ('1', '2')
    assert ok.render_ms == 12.5
    torn = policy.judge(0.31, ['1'])
    assert (torn.result, torn.reason, torn.level, torn.published) == ('refused', 'incomplete', 'error', False)
    assert torn.message == '31% rendered (< min_valid_fraction 0.8): not published'
    flagged = ReplyPolicy(0.8, publish_incomplete=True).judge(0.31)
    assert (flagged.result, flagged.reason, flagged.level, flagged.published) == (
        'incomplete', 'incomplete', 'warn', True,
    )  # fmt: skip
    assert ReplyPolicy(0.0).judge(0.0).result == 'answered'
    no = policy.refuse('no_model', 'no keyframe with depth received yet')
    assert (no.result, no.reason, no.level, no.valid_fraction) == ('refused', 'no_model', 'error', 0.0)


@pytest.mark.parametrize(
    'status',
    [
        ReplyStatus('answered', '', 0.8731481481481481, 0.75, '87% rendered', ('17', '18'), 31.25),
        ReplyStatus('incomplete', 'incomplete', 0.1, 0.75, 'torn'),
        *(ReplyStatus('refused', r, 0.0, 0.75, f'because {r}') for r in REFUSALS),
    ],
)
def test_status_pairs_round_trip(status):
    pairs = status.to_pairs()
    assert dict(pairs)['published'] == str(status.published).lower()
    assert ReplyStatus.from_pairs(pairs, status.message) == status


@pytest.mark.parametrize(
    ('args', 'match'),
    [
        (('done', '', 1.0, 0.5), 'result'),
        (('answered', 'frame', 1.0, 0.5), 'does not fit'),
        (('refused', '', 0.0, 0.5), 'does not fit'),
        (('refused', 'tired', 0.0, 0.5), 'does not fit'),
        (('incomplete', 'frame', 0.2, 0.5), 'incomplete'),
        (('answered', '', 1.5, 0.5), 'valid_fraction'),
        (('answered', '', float('nan'), 0.5), 'valid_fraction'),
    ],
)
def test_inconsistent_statuses_are_rejected(args, match):
    with pytest.raises(ValueError, match=match):
        ReplyStatus(*args)


def test_malformed_pairs_name_the_field():
    with pytest.raises(ValueError, match='result missing'):
        ReplyStatus.from_pairs([('reason', '')])
    with pytest.raises(ValueError, match="valid_fraction: 'most'"):
        ReplyStatus.from_pairs([('result', 'answered'), ('reason', ''), ('valid_fraction', 'most')])
    with pytest.raises(ValueError, match='min_valid_fraction'):
        ReplyPolicy(1.5)
