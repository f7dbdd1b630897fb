# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""End to end over DDS: the node graph as separate processes on the shipped synthetic bag.

bag_player -> frame_subsampler -> depth_refiner -> view_renderer, then novel-view queries between
keyframes compared with the exact re-rendered ground truth. Bars: every keyframe refined with a
median relative depth error below 0.1, and every query answered with a rephotography AUC (7x7,
shift 2) below 12 grey levels, half of what showing the nearest keyframe unchanged scores (~24, see
test_refiner_renderer_nodes.py).
"""

from __future__ import annotations

import json

import pytest

from ibr_ros.jobs.demo import run_demo


@pytest.mark.dds
@pytest.mark.e2e
def test_demo_graph_end_to_end(repo, tmp_path, ros_env, monkeypatch):
    for key in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'PYTHONPATH'):
        monkeypatch.setenv(key, ros_env[key])
    summary = run_demo(repo / 'bags' / 'synth_orbit_s0', tmp_path, n_queries=4, timeout_s=600)
    assert summary['keyframes'] >= 10
    assert summary['refined'] == summary['keyframes']
    assert summary['depth_median_abs_rel'] < 0.1
    assert summary['answered'] == summary['queries'] == 4
    assert summary['rephoto_auc_mean'] < 12.0
    assert json.loads((tmp_path / 'summary.json').read_text())['answered'] == 4
    assert len(list((tmp_path / 'novel_views').glob('*.png'))) == 4
    assert len(list((tmp_path / 'depth').glob('*.png'))) == summary['keyframes']
