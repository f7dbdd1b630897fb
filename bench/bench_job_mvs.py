# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS of a whole flight, job by job: ways to get the neighbours' depth, against sweeping them per job.

Every ``--step``-th frame of ``bags/synth_orbit_s0`` (default 12 views, 640x360) goes through the
depth_refiner's :class:`~ibr_ros.core.depth.schedule.RefineScheduler` (default configuration: 4
neighbours, the sweep range from the scene depth) and each job's depth comes from
:func:`~ibr_ros.core.depth.job_mvs.job_depth`:

* baseline (in the same process, run first): no cache, so every job sweeps its reference and all
  of its neighbours whole, against the job's views (``refine_job`` before ``neighbour_roi``);
* ``cache``: one :class:`~ibr_ros.core.depth.job_mvs.PhotometricCache` for the flight (the
  depth_refiner's ``reuse_neighbour_depth``);
* ``roi``: ``neighbour_roi`` (the default), each neighbour swept only over the box and the depths
  where the reference's photometric depth projects;
* ``sources2`` / ``sources1``: ``neighbour_sources`` 2 / 1, each neighbour swept against the
  reference and the best other view / the reference alone.

Prints per keyframe the sweeps, the work (pixels x hypotheses x source views scored, summed over
every sweep), CPU seconds (all threads of this process) and wall seconds, the ratios to the
baseline, how each run's depth maps compare against the bag's ground truth (fraction of pixels
within 5 %, completeness) and the share of the baseline's pixels each keeps. Exits 1 if a run is
not cheaper in work or is less accurate by more than 1 point.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

from dataclasses import replace

import numpy as np

from ibr_ros.core.depth import job_mvs, mvs
from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth
from ibr_ros.core.depth.mvs import MvsOptions, MvsView
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.jobs.eval_depth import load_views
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

REPO = Path(__file__).resolve().parents[1]


#: The runs besides the baseline: (MvsOptions changes, photometric cache).
VARIANTS: dict[str, tuple[dict[str, object], bool]] = {
    'cache': ({}, True),
    'roi': ({'neighbour_roi': True}, False),
    'sources2': ({'neighbour_sources': 2}, False),
    'sources1': ({'neighbour_sources': 1}, False),
}


def run(
    views: list[MvsView], options: MvsOptions, cache: PhotometricCache | None
) -> tuple[list[np.ndarray], float, float, int, int]:
    """Depth of every view (scheduler order), CPU and wall seconds, sweeps, work (pixel x
    hypothesis x source scores)."""
    cfg = ScheduleConfig(mvs=options)
    scheduler = RefineScheduler(cfg)
    for i, v in enumerate(views):
        scheduler.add(i, v)
    out = [np.zeros((v.camera.height, v.camera.width), np.float32) for v in views]
    sweeps, work = [0], [0]
    real, real_sweep = job_mvs.mvs_depth, mvs._Stack.sweep

    def counted(*a: object, **k: object) -> object:
        sweeps[0] += 1
        return real(*a, **k)  # type: ignore[arg-type]

    def scored(self: mvs._Stack, base: object, offsets: object, *a: object) -> object:
        work[0] += self.ref.size * np.asarray(offsets).size * len(self.srcs)
        return real_sweep(self, base, offsets, *a)  # type: ignore[arg-type]

    job_mvs.mvs_depth = counted  # type: ignore[assignment]
    mvs._Stack.sweep = scored  # type: ignore[method-assign]
    try:
        c0, t0 = time.process_time(), time.perf_counter()
        while (job := scheduler.next_job(flush=True)) is not None:
            m = job_depth(
                job.views, job.stamps, job.depth_range, cfg.mvs, probe_range=job.probe_range, cache=cache
            )
            out[job.stamp] = m.depth
            scheduler.done(job)
        cpu, seconds = time.process_time() - c0, time.perf_counter() - t0
    finally:
        job_mvs.mvs_depth = real
        mvs._Stack.sweep = real_sweep  # type: ignore[method-assign]
    return out, cpu, seconds, sweeps[0], work[0]


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
    p.add_argument('variants', nargs='*', help=f'of {", ".join(VARIANTS)} (default: all)')
    a = p.parse_args()
    if bad := sorted(set(a.variants) - set(VARIANTS)):
        p.error(f'unknown variants {bad}: choose from {list(VARIANTS)}')
    views = [v for _, v in load_views(a.bag, a.step, a.views)]
    gt = GroundTruthRenderer(a.bag)
    truths = [gt.render(v.t_wc, v.camera).depth for v in views]
    baseline = MvsOptions(neighbour_roi=False)
    run(views[:3], baseline, None)  # compile / load the kernels
    n = len(views)
    base, c_base, t_base, s_base, w_base = run(views, baseline, None)
    acc_b, comp_b = accuracy(base, truths)
    w, h = views[0].camera.width, views[0].camera.height
    print(f'{n} keyframes {w}x{h} of {a.bag.name}, default schedule (4 neighbours)')
    print(
        '| run | sweeps / keyframe | work ratio | CPU ratio | CPU s / keyframe | wall s / keyframe '
        '| within 5 % | completeness | baseline pixels kept |'
    )
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    print(
        f'| baseline: neighbours swept per job | {s_base / n:.2f} | 1 | 1 | {c_base / n:.2f} | '
        f'{t_base / n:.2f} | {acc_b:.3f} | {comp_b:.3f} | 1 |'
    )
    ok = True
    for name in a.variants or list(VARIANTS):
        changes, cached = VARIANTS[name]
        cache = PhotometricCache.for_flight(True) if cached else None
        out, c, t, sw, wk = run(views, replace(baseline, **changes), cache)  # type: ignore[arg-type]
        acc, comp = accuracy(out, truths)
        kept = sum(int(((d > 0) & (b > 0)).sum()) for d, b in zip(out, base)) / max(
            1, sum(int((b > 0).sum()) for b in base)
        )
        print(
            f'| {name} | {sw / n:.2f} | {wk / w_base:.2f} | {c / c_base:.2f} | {c / n:.2f} | {t / n:.2f} '
            f'| {acc:.3f} | {comp:.3f} | {kept:.3f} |',
            flush=True,
        )
        ok &= wk < w_base and acc >= acc_b - 0.01
    print(f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')
    if not ok:
        print('FAIL: a run is not cheaper in work, or less accurate')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
