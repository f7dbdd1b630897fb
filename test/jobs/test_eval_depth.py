# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval depth`` on the shipped synthetic flight and two other seeds: the paper's quality bars.

Bars (Depth refinement issue): the LUT remap beats the median-factor and linear remaps in Abs Rel
against ground truth on every scene, and our fusion beats FMM inpainting in RMSE and PBRE-0.10 over
the MVS holes. MVS itself: >= 90% of the pixels it outputs within 5% of ground truth.
"""

from __future__ import annotations

import json

import pytest

from ibr_ros.cli.main import main
from ibr_ros.jobs.eval_depth import DepthEvalOptions, evaluate_depth

pytestmark = pytest.mark.e2e


@pytest.fixture(scope='module')
def scenes(synth_bags, tmp_path_factory):
    return tmp_path_factory.mktemp('eval_depth'), synth_bags


@pytest.mark.parametrize('name', ['shipped', 'seed1', 'seed2'])
def test_quality_bars(scenes, name):
    root, bags = scenes
    step = 25 if name == 'shipped' else 2
    summary = evaluate_depth(
        bags[name], root / f'out_{name}', DepthEvalOptions(step=step, max_views=6, png=False)
    )
    assert summary['evaluated'] >= 4
    assert summary['mvs_accuracy_5pct'] >= 0.90
    t1 = summary['table1_abs_rel']
    for ref in ('mvs_ref_vs_gt', 'gt_ref_vs_gt'):
        assert t1['lut'][ref] < t1['median_factor'][ref]
        assert t1['lut'][ref] < t1['linear'][ref]
    holes = summary['table2']['holes']
    assert holes['ours']['rmse'] < holes['fmm']['rmse']
    assert holes['ours']['pbre_0.10'] < holes['fmm']['pbre_0.10']


def test_cli_writes_tables_and_pngs(scenes, capsys):
    root, bags = scenes
    out = root / 'cli'
    assert (
        main(['eval', 'depth', str(bags['seed1']), '--out', str(out), '--step', '3', '--max-views', '4']) == 0
    )
    assert '## Table 1 analogue' in capsys.readouterr().out
    summary = json.loads((out / 'depth_eval.json').read_text())
    assert summary['evaluated'] == len(summary['per_view']) == 4
    assert (out / 'depth_eval.md').read_text().startswith('# Depth evaluation')
    assert len(list(out.glob('view_*.png'))) == 4


def test_not_a_synthetic_bag_is_a_user_error(repo, tmp_path, capsys):
    assert main(['eval', 'depth', str(repo / 'bags' / 'brighton_beach'), '--out', str(tmp_path)]) == 2
    assert 'synth.json' in capsys.readouterr().err
