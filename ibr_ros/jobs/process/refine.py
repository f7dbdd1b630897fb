# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS + refinement of every keyframe with the whole flight known (the depth_refiner's policy)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ibr_ros.core.depth.job_mvs import PhotometricCache
from ibr_ros.core.depth.mono import MonoModelError
from ibr_ros.core.depth.mvs import MvsView
from ibr_ros.core.depth.refine import DepthRefiner, refine_job
from ibr_ros.core.depth.schedule import RefineScheduler
from ibr_ros.errors import UserError
from ibr_ros.jobs.process.frames import Keyframe
from ibr_ros.jobs.process.options import Progress
from ibr_ros.jobs.process.params import ProcessConfigs
from ibr_ros.jobs.process.sfm import SparsePoints
from ibr_ros.jobs.process.spill import loaded
from msg_utils import CONVERSION_ERRORS

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules


def _loaded(v: MvsView) -> MvsView:
    """``v`` with its image in memory (a spilled image read by file, its mapping left untouched)."""
    rgb = loaded(v.rgb)
    return v if rgb is v.rgb else MvsView(rgb, v.camera, v.t_wc)


def refine_all(
    keyframes: list[Keyframe],
    cfg: ProcessConfigs,
    progress: Progress | None,
    sparse: SparsePoints | None = None,
    spill: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, object]:
    """MVS + refinement of every keyframe, oldest first, with the whole flight known.

    Only ``keyframes`` take part: a keyframe left out of the list is nobody's MVS neighbour (``ibr
    eval rephoto`` leaves its held-out keyframes out this way). Sets each refined keyframe's
    ``depth`` and ``neighbours``; returns ``attempts``, ``not_refined`` (stamp -> why) and
    ``warnings`` (the scheduler's, also logged). ``sparse``: SfM's sparse points (they bound each
    keyframe's depth range and seed its depth, :meth:`RefineScheduler.set_points`). ``spill``: where
    each refined depth and confidence go (e.g. :meth:`SpillStore.put`); spilled images are read by
    file for each job (:func:`loaded`), so that no keyframe's image stays in memory.
    """
    by_stamp = {k.stamp: k for k in keyframes}
    scheduler = RefineScheduler(cfg.schedule)
    for k in keyframes:
        scheduler.add(k.stamp, MvsView(k.rgb, k.camera, k.t_wc))
    if sparse is not None:
        scheduler.set_points(sparse.points, sparse.observed)
    try:
        refiner = DepthRefiner(cfg.refiner)  # loads the ONNX models of mono/sky 'onnx'
    except MonoModelError as exc:
        raise UserError(f'depth_refiner mono_model/sky_model: {exc}') from exc
    photometric = PhotometricCache.for_flight(cfg.schedule.reuse_neighbour_depth)
    keep = spill or (lambda a: a)
    failures: dict[int, str] = {}
    warnings: list[str] = []
    attempts = 0
    refined: set[int] = set()
    if progress is not None:
        progress('keyframes', 0, len(keyframes))
    while True:
        try:
            job = scheduler.next_job(flush=cfg.flush)
        except CONVERSION_ERRORS as exc:  # a degenerate keyframe set (e.g. coincident cameras)
            raise UserError(f'cannot choose MVS neighbours: {exc}') from exc
        for w in scheduler.pop_warnings():
            LOG.warning(w)
            warnings.append(w)
        if job is None:
            break
        attempts += 1
        kf = by_stamp[job.stamp]
        views = (_loaded(job.view), tuple(_loaded(v) for v in job.neighbour_views))
        job_in_memory = replace(job, view=views[0], neighbour_views=views[1])
        result = refine_job(refiner, job_in_memory, cfg.schedule.mvs, photometric)
        kf.timings_s = dict(result.timings_s)
        if result.refined is None:
            scheduler.failed(job)
            failures[job.stamp] = f'{result.context}: {result.error}'
            LOG.warning('keyframe %d ns not refined: %s', job.stamp, failures[job.stamp])
            continue
        scheduler.done(job)
        refined.add(job.stamp)
        failures.pop(job.stamp, None)
        kf.depth = keep(result.refined.depth)
        conf = result.refined.confidence
        kf.confidence = None if conf is None else keep(conf)
        kf.neighbours = job.neighbours
        LOG.info(
            'refined keyframe %d/%d (%d ns) with %d neighbours in %.2f s',
            len(refined), len(keyframes), job.stamp, len(job.neighbours), result.seconds,
        )  # fmt: skip
        if progress is not None:
            progress('keyframes', len(refined), len(keyframes))
    for s in scheduler.unrefined():
        failures.setdefault(s, 'no neighbour with enough overlap and parallax')
    return {
        'attempts': attempts,
        'not_refined': {str(s): why for s, why in sorted(failures.items())},
        'warnings': warnings,
    }
