# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval rephoto`` on real photos without poses (``bags/brighton_beach``: SfM mode, GPS -> ENU).

A few keyframes only (``--max-keyframes 7``, every 3rd held out), so that it stays short: the numbers
are checked for sanity, not quality (the measurements are in bench/README.md).
"""

from __future__ import annotations

import json
import math

import cv2
import pytest

from ibr_ros.cli.main import main

pytestmark = pytest.mark.e2e

METHODS = {'ours@fused', 'paper@fused', 'ulr@fused', 'splat@fused'}


@pytest.fixture(scope='module')
def brighton(repo, tmp_path_factory):
    out = tmp_path_factory.mktemp('rephoto_real') / 'brighton'
    args = ['eval', 'rephoto', str(repo / 'bags' / 'brighton_beach'), '--out', str(out)]
    rc = main([*args, '--max-keyframes', '7', '--holdout', 'every-3rd', '--no-progress'])
    return rc, out


def test_every_holdout_is_scored_for_every_method(brighton):
    rc, out = brighton
    assert rc == 0
    s = json.loads((out / 'rephoto_eval.json').read_text())
    assert s['views_from'] == 'keyframes'
    assert s['registration']['poses'] == 'sfm'
    assert s['registration']['sfm_saw_holdouts'] is True
    assert s['registration']['sfm']['frame_id'] == 'map'  # GPS -> ENU
    n = len(s['frames'])
    assert s['holdout_frames'] == list(range(2, n, 3))
    assert set(s['methods']) == METHODS
    for h in s['per_holdout']:
        assert set(h['methods']) == METHODS
        for key, r in h['methods'].items():
            assert r['reason'] is None, key
            assert 0.0 <= r['completeness'] <= 1.0
            assert math.isfinite(r['psnr'])
            assert 5.0 < r['psnr'] < 60.0
            assert -1.0 <= r['ssim'] <= 1.0
            assert 0.0 < r['auc']['p7_s2'] < 255.0
            assert len(r['auc']) == 9  # the Table 3 grid
            assert str(h['frame']) not in map(str, r['used_frames'])
    for key in METHODS:
        m = s['methods'][key]
        assert m['failed_renders'] == 0
        assert 0.0 < m['completeness'] <= 1.0
        assert math.isfinite(m['psnr'])
        assert m['auc_main'] <= m['tail']


def test_held_out_keyframes_take_no_part_in_mvs(brighton):
    _, out = brighton
    s = json.loads((out / 'rephoto_eval.json').read_text())
    held = set(s['holdout_stamps'])
    assert held == {s['stamps'][i] for i in s['holdout_frames']}
    for v in s['views']:
        if v['held_out']:
            assert not v['refined']
            assert not v['neighbours']
        else:
            assert not held & set(v['neighbours']), v
    assert sum(v['refined'] for v in s['views']) == s['render']['sources'] >= 2


def test_outputs_are_written(brighton):
    _, out = brighton
    s = json.loads((out / 'rephoto_eval.json').read_text())
    md = (out / 'rephoto_eval.md').read_text()
    assert md.startswith('# Rephotography evaluation')
    assert 'SfM saw the held-out photos: yes' in md
    assert 'GPS alignment RMS' in md
    assert cv2.imread(str(out / 'rephoto_curves.png')) is not None
    for h in s['holdout_frames']:
        side = cv2.imread(str(out / f'holdout_{h:03d}.png'))
        assert side is not None
        assert side.shape == (562, 5 * 1000, 3)  # photo | ours | ULR | splat | error map
    assert not list(out.glob('.*'))  # atomic writes leave no temporary files
