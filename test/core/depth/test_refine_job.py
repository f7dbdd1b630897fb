# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""refine_job: the MVS -> refinement step the depth_refiner node and ``ibr process`` share."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, known_depth, refine_job
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.jobs.warmup import plane_views

OPTIONS = MvsOptions(max_neighbours=2, neighbour_roi=False)  # job_depth as compute_depth_maps


@pytest.fixture(scope='module')
def job():
    s = RefineScheduler(ScheduleConfig(min_neighbours=1, depth_range=(10.0, 60.0), mvs=OPTIONS))
    for i, v in enumerate(plane_views()):
        s.add(i + 1, v)
    job = s.next_job(flush=True)
    assert job is not None
    return job


def test_the_step_is_mvs_then_refinement_of_the_keyframe(job):
    refiner = DepthRefiner()
    result = refine_job(refiner, job, OPTIONS)
    assert result.refined is not None
    assert result.error == ''
    assert result.context == f'{len(job.neighbours)} neighbours, MVS ok'
    assert set(result.timings_s) == {'mvs', 'refine'}
    assert result.seconds == pytest.approx(sum(result.timings_s.values()))
    mvs = compute_depth_maps(job.views, options=OPTIONS, depth_range=job.depth_range)[0]
    np.testing.assert_array_equal(result.mvs.depth, mvs.depth)
    np.testing.assert_array_equal(result.refined.depth, refiner.refine_from_mvs(job.view, mvs.depth).depth)


class _Failing:
    def refine_from_mvs(self, view, d_mvs, **evidence):
        raise RefineError('d_mvs has 3 known pixels')


class _Unknown:
    def refine_from_mvs(self, view, d_mvs, **evidence):
        class R:
            depth = np.full(d_mvs.shape, np.nan, np.float32)

        return R()


def test_a_failure_is_a_result_saying_why(job):
    n = len(job.neighbours)
    r = refine_job(_Failing(), job, OPTIONS)  # type: ignore[arg-type]
    assert r.refined is None
    assert f'{r.context}: {r.error}' == f'{n} neighbours, MVS ok: d_mvs has 3 known pixels'
    r = refine_job(_Unknown(), job, OPTIONS)  # type: ignore[arg-type]
    assert r.refined is None
    assert f'{r.context}: {r.error}' == f'{n} neighbours: no pixel has a known depth'
    assert set(r.timings_s) == {'mvs', 'refine'}


def test_known_depth_needs_one_finite_positive_value():
    assert not known_depth(np.array([[np.nan, 0.0], [-1.0, np.inf]]))
    assert known_depth(np.array([[np.nan, 0.0], [2.0, np.inf]]))
