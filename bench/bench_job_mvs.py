# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS of a whole flight, job by job: each keyframe's photometric depth cached vs swept per job.

Every ``--step``-th frame of ``bags/synth_orbit_s0`` (default 12 views, 640x360) goes through the
depth_refiner's :class:`~ibr_ros.core.depth.schedule.RefineScheduler` (default configuration: 4
neighbours, the sweep range from the scene depth) and each job's depth comes from
:func:`~ibr_ros.core.depth.job_mvs.job_depth`:

* baseline (in the same process, run first): no cache, so every job sweeps its reference and all
  of its neighbours (what ``refine_job`` did through ``compute_depth_maps``);
* cached: one :class:`~ibr_ros.core.depth.job_mvs.PhotometricCache` for the flight (the
  depth_refiner's ``reuse_neighbour_depth``).

Prints sweeps and seconds per keyframe for both, the ratio, and how the two depth maps of each
keyframe compare against the bag's ground truth (fraction of pixels within 5 %, completeness).
Exits 1 if the cached run is not faster or is less accurate by more than 1 point.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

import numpy as np

from ibr_ros.core.depth import job_mvs
from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth
from ibr_ros.core.depth.mvs import MvsView
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.jobs.eval_depth import load_views
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

REPO = Path(__file__).resolve().parents[1]


def run(views: list[MvsView], cache: PhotometricCache | None) -> tuple[list[np.ndarray], float, int]:
    """Depth of every view (scheduler order), wall seconds, and the number of sweeps."""
    cfg = ScheduleConfig()
    scheduler = RefineScheduler(cfg)
    for i, v in enumerate(views):
        scheduler.add(i, v)
    out = [np.zeros((v.camera.height, v.camera.width), np.float32) for v in views]
    sweeps = [0]
    real = job_mvs.mvs_depth

    def counted(*a: object, **k: object) -> object:
        sweeps[0] += 1
        return real(*a, **k)  # type: ignore[arg-type]

    job_mvs.mvs_depth = counted  # type: ignore[assignment]
    try:
        t0 = time.perf_counter()
        while (job := scheduler.next_job(flush=True)) is not None:
            m = job_depth(
                job.views, job.stamps, job.depth_range, cfg.mvs, probe_range=job.probe_range, cache=cache
            )
            out[job.stamp] = m.depth
            scheduler.done(job)
        seconds = time.perf_counter() - t0
    finally:
        job_mvs.mvs_depth = real
    return out, seconds, sweeps[0]


def accuracy(depths: list[np.ndarray], truths: list[np.ndarray]) -> tuple[float, float]:
    """Pooled fraction of known pixels within 5 % of the truth, and of pixels known."""
    ok = known = total = 0
    for d, t in zip(depths, truths, strict=True):
        k = (d > 0) & np.isfinite(t)
        ok += int((np.abs(d[k] / t[k] - 1) < 0.05).sum())
        known += int(k.sum())
        total += d.size
    return ok / max(known, 1), known / total


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--bag', type=Path, default=REPO / 'bags' / 'synth_orbit_s0')
    p.add_argument('--step', type=int, default=4)
    p.add_argument('--views', type=int, default=12)
    a = p.parse_args()
    views = [v for _, v in load_views(a.bag, a.step, a.views)]
    gt = GroundTruthRenderer(a.bag)
    truths = [gt.render(v.t_wc, v.camera).depth for v in views]
    run(views[:3], None)  # compile / load the kernels
    n = len(views)
    base, t_base, s_base = run(views, None)
    cached, t_cached, s_cached = run(views, PhotometricCache.for_flight(True))
    acc_b, comp_b = accuracy(base, truths)
    acc_c, comp_c = accuracy(cached, truths)
    w, h = views[0].camera.width, views[0].camera.height
    print(f'{n} keyframes {w}x{h} of {a.bag.name}, default schedule (4 neighbours)')
    print('| run | sweeps / keyframe | s / keyframe | within 5 % | completeness |')
    print('| --- | --- | --- | --- | --- |')
    print(f'| baseline: no cache | {s_base / n:.2f} | {t_base / n:.2f} | {acc_b:.3f} | {comp_b:.3f} |')
    print(f'| photometric cache | {s_cached / n:.2f} | {t_cached / n:.2f} | {acc_c:.3f} | {comp_c:.3f} |')
    print(f'ratio cached / baseline: {t_cached / t_base:.2f}x time, {s_cached / s_base:.2f}x sweeps')
    print(f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')
    if t_cached >= t_base or acc_c < acc_b - 0.01:
        print('FAIL: the cache is not faster, or less accurate')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
