# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The depth_refiner's parameter table: defaults are the core defaults, cross-parameter rules, errors."""

from __future__ import annotations

import pytest

from ibr_ros.core.depth.mvs import MvsOptions
from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.depth.schedule import ScheduleConfig
from ibr_ros.core.registration.sfm_session import ScaleHint
from ibr_ros.core.registration.trigger import SfmConfig
from ibr_ros.errors import UserError
from ibr_ros.node_config import DEPTH_REFINER


def test_defaults_are_the_core_defaults():
    cfg = DEPTH_REFINER.config({})
    assert cfg.schedule == ScheduleConfig()
    assert cfg.mvs is cfg.schedule.mvs
    assert cfg.mvs == MvsOptions()
    assert cfg.refiner == RefinerConfig()
    assert cfg.sfm == SfmConfig()
    assert cfg.notes == ()
    assert cfg.max_pending_bytes == 128 * 2**20


def test_values_reach_the_core_configurations():
    cfg = DEPTH_REFINER.config({
        'max_neighbours': 2, 'min_neighbours': 1, 'depth_range': [2, 50], 'refine_again': True,
        'num_workers': 3, 'worker_index': 2, 'sfm_mode': 'off', 'sfm_scale': 'altitude', 'sfm_scale_m': 40.0,
    })  # fmt: skip
    assert cfg.mvs.max_neighbours == 2
    assert cfg.schedule.min_neighbours == 1
    assert cfg.schedule.depth_range == (2.0, 50.0)
    assert cfg.schedule.refine_again
    assert (cfg.schedule.num_workers, cfg.schedule.worker_index) == (3, 2)
    assert cfg.sfm.scale == ScaleHint('altitude', 40.0)


def test_auto_sfm_acts_as_off_with_several_workers_and_says_so():
    cfg = DEPTH_REFINER.config({'num_workers': 2})
    assert cfg.sfm.mode == 'off'
    assert cfg.notes == ('num_workers > 1: sfm_mode auto acts as off (one SfM registration per graph)',)
    assert DEPTH_REFINER.config({'num_workers': 2, 'sfm_mode': 'off'}).notes == ()


@pytest.mark.parametrize(
    ('values', 'match'),
    [
        ({'num_workers': 2, 'sfm_mode': 'always'},
         r"parameter sfm_mode 'always' needs num_workers 1 \(one SfM registration .*, got num_workers 2"),
        ({'sfm_mode': 'sometimes'}, "parameter sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'"),
        ({'sfm_scale': 'depth'}, "parameter sfm_scale_m must be > 0 with sfm_scale 'depth', got 0.0"),
        ({'sky': 'clouds'}, "parameter sky must be 'fallback', 'onnx' or 'none', got 'clouds'"),
        ({'mono': 'midas'}, "parameter mono must be 'plane' or 'onnx', got 'midas'"),
        ({'depth_range': [5.0, 1.0]}, r'parameter depth_range must be \[near, far\] .* got \[5.0, 1.0\]'),
        ({'min_neighbours': 3, 'max_neighbours': 2}, 'max_neighbours 2 must be >= min_neighbours 3'),
        ({'num_workers': 2, 'worker_index': 2}, r'parameter worker_index 2 must be in \[0, num_workers 2\)'),
        ({'max_neighbours': 17}, 'parameter max_neighbours must be 1..16, got 17'),
        ({'max_neighbors': 2}, "'max_neighbors' is not a parameter of depth_refiner"),
    ],
)  # fmt: skip
def test_bad_values_are_user_errors_naming_the_parameter(values, match):
    with pytest.raises(UserError, match=match):
        DEPTH_REFINER.config(values)
