# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The neighbour-sweep variants of ``bench_job_mvs.py`` on the refine jobs of a real capture.

Two steps, both in this checkout:

* ``dump JOBS.pkl -- <ibr eval rephoto arguments>`` runs ``ibr eval rephoto`` in this process and
  pickles every refine job it ran (views by stamp, stamps, depth and probe ranges);
* ``replay JOBS.pkl [--jobs N] [VARIANT ...]`` runs the first N jobs through
  :func:`~ibr_ros.core.depth.job_mvs.job_depth`: the baseline (neighbours swept whole), then each
  variant, all in one process. Prints the work (pixels x hypotheses x source views scored) and CPU
  ratios to the baseline, the completeness of the filtered depth, the ratio of its pixel count to
  the baseline's and the share of the baseline's pixels it keeps (no ground truth on real photos).
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

import numpy as np

from ibr_ros.core.depth import mvs
from ibr_ros.core.depth.job_mvs import job_depth
from ibr_ros.core.depth.mvs import MvsOptions

VARIANTS: dict[str, dict[str, object]] = {
    'roi': {'neighbour_roi': True},
    'sources2': {'neighbour_sources': 2},
    'sources1': {'neighbour_sources': 1},
}
WORK = [0]


def _count_work() -> None:
    real = mvs._Stack.sweep

    def scored(self: mvs._Stack, base: object, offsets: object, *a: object) -> object:
        WORK[0] += self.ref.size * np.asarray(offsets).size * len(self.srcs)
        return real(self, base, offsets, *a)  # type: ignore[arg-type]

    mvs._Stack.sweep = scored  # type: ignore[method-assign]


def dump(path: Path, argv: list[str]) -> int:
    """``ibr eval rephoto argv`` with every refine job pickled to ``path``."""
    from ibr_ros.cli.main import main
    from ibr_ros.jobs.process import refine

    views: dict[int, Any] = {}
    jobs: list[tuple[list[int], Any, Any]] = []
    real = refine.refine_job

    def recorded(refiner: Any, job: Any, options: Any, *caches: Any) -> Any:
        for s, v in zip(job.stamps, job.views, strict=True):
            views.setdefault(s, v)
        jobs.append((list(job.stamps), job.depth_range, job.probe_range))
        return real(refiner, job, options, *caches)

    refine.refine_job = recorded  # type: ignore[assignment]
    rc = main(argv)
    tmp = path.with_suffix('.tmp')
    with open(tmp, 'wb') as f:
        pickle.dump({'views': views, 'jobs': jobs}, f)
    tmp.replace(path)
    print(f'{len(jobs)} jobs, {len(views)} views -> {path}')
    return rc


def replay(path: Path, n_jobs: int, variants: list[str]) -> int:
    """The baseline and ``variants`` on the first ``n_jobs`` jobs of ``path``."""
    with open(path, 'rb') as f:
        d = pickle.load(f)  # a file this script wrote
    views, jobs = d['views'], d['jobs'][:n_jobs]
    _count_work()
    baseline = MvsOptions(neighbour_roi=False)

    def run(o: MvsOptions) -> tuple[list[np.ndarray], float, int]:
        WORK[0] = 0
        c0 = time.process_time()
        out = [
            job_depth([views[s] for s in stamps], stamps, rng, o, probe_range=probe).depth
            for stamps, rng, probe in jobs
        ]
        return out, time.process_time() - c0, WORK[0]

    v0 = next(iter(views.values()))
    print(f'{len(jobs)} jobs of {path.name}, {v0.camera.width}x{v0.camera.height}')
    print(
        '| run | work ratio | CPU ratio | CPU s / job | completeness | pixels vs baseline '
        '| baseline pixels kept |'
    )
    print('| --- | --- | --- | --- | --- | --- | --- |')
    base, c_base, w_base = run(baseline)
    n_base = sum(int((b > 0).sum()) for b in base)
    size = sum(b.size for b in base)
    print(f'| baseline | 1 | 1 | {c_base / len(jobs):.2f} | {n_base / size:.4f} | 1 | 1 |', flush=True)
    for name in variants:
        out, c, w = run(replace(baseline, **VARIANTS[name]))  # type: ignore[arg-type]
        n = sum(int((a > 0).sum()) for a in out)
        both = sum(int(((a > 0) & (b > 0)).sum()) for a, b in zip(out, base, strict=True))
        print(
            f'| {name} | {w / w_base:.3f} | {c / c_base:.3f} | {c / len(jobs):.2f} | {n / size:.4f} '
            f'| {n / n_base:.3f} | {both / n_base:.3f} |',
            flush=True,
        )
    print(f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')
    return 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    sub = p.add_subparsers(dest='cmd', required=True)
    d = sub.add_parser('dump', help='run `ibr eval rephoto ARGS` and pickle its refine jobs')
    d.add_argument('jobs', type=Path)
    d.add_argument('args', nargs=argparse.REMAINDER, help='-- then the `ibr` arguments (eval rephoto ...)')
    r = sub.add_parser('replay', help='the baseline and the variants on the pickled jobs')
    r.add_argument('jobs', type=Path)
    r.add_argument('--jobs', dest='n_jobs', type=int, default=10)
    r.add_argument('variants', nargs='*', help=f'of {", ".join(VARIANTS)} (default: all)')
    a = p.parse_args()
    if a.cmd == 'dump':
        return dump(a.jobs, a.args[1:] if a.args[:1] == ['--'] else a.args)
    if bad := sorted(set(a.variants) - set(VARIANTS)):
        p.error(f'unknown variants {bad}: choose from {list(VARIANTS)}')
    return replay(a.jobs, a.n_jobs, a.variants or list(VARIANTS))


if __name__ == '__main__':
    sys.exit(main())
