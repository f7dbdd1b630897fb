# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS settings study (issue 15): :class:`MvsOptions` variants against the defaults, same process.

Does a cheaper sweep keep the defaults' precision? Each variant runs on the same inputs as the
defaults, interleaved (a warm run each, then ``--runs`` timed rounds over all variants), medians of
wall and CPU seconds, printed as ratios to the defaults' medians on that input.

Synthetic inputs (``bench_mvs.views``: reference = middle of 5 frames 16 m apart, 4 source views
from ``select_neighbours``, range from 300 ground-truth points per view): orbit seed 1 and
lawnmower seed 2 at 1000x750, orbit seeds 1 and 4 at 640x360. Per variant: accuracy (fraction of
non-sky ground-truth pixels within 5 %), completeness (fraction with a depth), precision (fraction
of the pixels with a depth within 5 %) and the fraction of the pixels with a depth more than 20 %
off (confident wrong depth).

Real photos (``--bag``, default ``bags/brighton_beach``; keyframes, poses and SfM points as in
``bench_mvs.py``, cached in ``--cache``): ``--views`` keyframes spread over the flight, up to 4
neighbours each; against the SfM points each keyframe observed: share of the pixels with a depth,
share of the points with a depth, share of those within 5 %, number more than 20 % off.

    .venv/bin/python bench/bench_mvs_variants.py                 # every variant
    .venv/bin/python bench/bench_mvs_variants.py --variants A B  # some of them (defaults always run)

No target: it prints measurements (bench/README.md, "MVS speed (issue 15)", "Cheaper sweep settings
at the defaults' precision"). Three more variants of the coarse-to-fine sweep (more bands per pixel,
the coarse sweep without the resolution drop) need MvsOptions fields of commit 9af7e27, reverted
after the study.
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numba
import numpy as np
from bench_mvs import views

from ibr_ros.core.depth import mvs

D = mvs.MvsOptions()
#: name -> (options, description). 'default' is always run first and is the ratios' baseline.
VARIANTS: dict[str, tuple[mvs.MvsOptions, str]] = {
    'default': (D, 'MvsOptions()'),
    'A': (replace(D, coarse_band=2), 'coarse_band 2'),
    'A1': (replace(D, coarse_band=1), 'coarse_band 1'),
    'A3': (replace(D, coarse_band=3), 'coarse_band 3'),
    'B': (
        replace(D, coarse_band=2, propagate_at_sweep_scale=True),
        'coarse_band 2, propagate_at_sweep_scale',
    ),
    'D': (replace(D, plane_step_px=3.0), 'plane_step_px 3'),
    'DA': (replace(D, plane_step_px=3.0, coarse_band=2), 'plane_step_px 3, coarse_band 2'),
    'Aw9': (replace(D, coarse_band=2, window=9), 'coarse_band 2, window 9'),
    'S4': (replace(D, sweep_scale=0.4), 'sweep_scale 0.4'),
    'DR1': (replace(D, plane_step_px=3.0, propagation_radius=0), 'plane_step_px 3, propagation_radius 0'),
    'R1': (replace(D, propagation_radius=0), 'propagation_radius 0 (5 propagation candidates, not 7)'),
    'fast': (
        replace(
            D, coarse_band=2, propagate_at_sweep_scale=True, refine_steps=2, surface_passes=2, surface_steps=1
        ),
        'the "fast" preset of bench_mvs.py',
    ),
}
SYNTH = (
    ((1000, 750), 'orbit', 1),
    ((1000, 750), 'lawnmower', 2),
    ((640, 360), 'orbit', 1),
    ((640, 360), 'orbit', 4),
)


def timed(
    names: list[str], args: tuple, kw: dict, runs: int
) -> dict[str, tuple[float, float, mvs.MvsResult]]:
    """Per variant: (median wall s, median CPU s, result); variants interleaved, each warmed first."""
    fns = {k: (lambda o=VARIANTS[k][0]: mvs.mvs_depth(*args, options=o, **kw)) for k in names}
    res = {k: fn() for k, fn in fns.items()}
    t: dict[str, list[tuple[float, float]]] = {k: [] for k in names}
    for _ in range(runs):
        for k, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            res[k] = fn()
            t[k].append((time.perf_counter() - t0, time.process_time() - c0))
    return {
        k: (float(np.median([w for w, _ in v])), float(np.median([c for _, c in v])), res[k])
        for k, v in t.items()
    }


def metrics(depth: np.ndarray, gt: np.ndarray) -> tuple[float, float, float, float]:
    """(accuracy, completeness, precision, fraction of pixels with a depth > 20 % off), non-sky GT."""
    g = np.isfinite(gt) & (gt > 0)
    m = (depth > 0) & g
    rel = np.abs(depth[m] - gt[m]) / gt[m]
    n = max(int(m.sum()), 1)
    return (
        float((rel < 0.05).sum() / g.sum()),
        float(m.sum() / g.sum()),
        float((rel < 0.05).sum() / n),
        float((rel > 0.2).sum() / n),
    )


def synthetic(names: list[str], runs: int) -> None:
    print(
        '| input | planes (default) | variant | wall / default | CPU / default | accuracy | completeness '
        '| precision | > 20 % off |'
    )
    print('| --- ' * 9 + '|')
    for size, kind, seed in SYNTH:
        cam, frames, poses, pts = views(size, kind, seed)
        ref_i = len(frames) // 2
        js = mvs.select_neighbours(ref_i, poses, cam, points_w=pts, max_neighbours=4)
        args = (frames[ref_i].rgb, cam, poses[ref_i], [frames[j].rgb for j in js], cam, poses[js])
        r = timed(names, args, {'points_w': pts}, runs)
        w0, c0, r0 = r['default']
        tag = f'{size[0]}x{size[1]} {kind} s{seed} ({len(js)} nbrs)'
        for k in names:
            acc, comp, prec, off = metrics(r[k][2].depth, frames[ref_i].depth)
            print(
                f'| {tag} | {r0.n_planes} | {k} | {r[k][0] / w0:.2f} | {r[k][1] / c0:.2f} '
                f'| {acc:.3f} | {comp:.3f} | {prec:.3f} | {off:.4f} |',
                flush=True,
            )
        print(
            f'|  | default: {w0:.2f} s wall, {c0:.2f} s CPU; load {os.getloadavg()[0]:.1f} | | | | | | | |',
            flush=True,
        )


def real(names: list[str], bag: Path, cache: Path, n_views: int, runs: int) -> None:
    if not cache.is_file():
        import bench_mvs

        bench_mvs.IMPLS = bench_mvs.IMPLS[:1]  # builds the cache (keyframes + SfM of ibr process)
        bench_mvs.brighton(bag, cache, 1, 1)
    kfs, points, observed = pickle.loads(cache.read_bytes())
    poses = np.stack([k[2] for k in kfs])
    cams = [k[1] for k in kfs]
    picks = [int(i) for i in np.linspace(0, len(kfs) - 1, n_views + 2).round()[1:-1]]
    print(
        f'\n{bag}: {len(kfs)} keyframes {cams[0].width}x{cams[0].height}, {len(points)} SfM points; '
        f'views {picks}'
    )
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in names}
    stats: dict[str, list[tuple[float, int, int, int]]] = {k: [] for k in names}
    n_obs = 0
    for i in picks:
        js = mvs.select_neighbours(i, poses, cams, points_w=points, max_neighbours=4)
        if not js:
            continue
        args = (kfs[i][0], cams[i], poses[i], [kfs[j][0] for j in js], [cams[j] for j in js], poses[js])
        r = timed(names, args, {'points_w': points}, runs)
        u, v, z = cams[i].pixels_of(observed[kfs[i][3]], poses[i])
        n_obs += len(z)
        for k in names:
            times[k].append(r[k][:2])
            d = r[k][2].depth
            has = d[v, u] > 0
            rel = np.abs(d[v, u][has] - z[has]) / z[has]
            stats[k].append(
                (float((d > 0).mean()), int(has.sum()), int((rel < 0.05).sum()), int((rel > 0.2).sum()))
            )
    w0 = sum(w for w, _ in times['default'])
    c0 = sum(c for _, c in times['default'])
    print(
        '| variant | wall / default | CPU / default | pixels with depth '
        f'| SfM points with depth (of {n_obs}) | within 5 % | > 20 % off |'
    )
    print('| --- ' * 7 + '|')
    for k in names:
        st = np.array(stats[k], dtype=float)
        has, ok, off = st[:, 1].sum(), st[:, 2].sum(), st[:, 3].sum()
        print(
            f'| {k} | {sum(w for w, _ in times[k]) / w0:.2f} | {sum(c for _, c in times[k]) / c0:.2f} '
            f'| {st[:, 0].mean():.3f} | {int(has)} ({has / n_obs:.3f}) | {ok / max(has, 1):.3f} '
            f'| {int(off)} |',
            flush=True,
        )
    print(f'default: {w0:.2f} s wall, {c0:.2f} s CPU summed over the views (medians)')


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument(
        '--variants', nargs='*', default=[k for k in VARIANTS if k != 'default'], choices=list(VARIANTS)
    )
    p.add_argument('--runs', type=int, default=2, help='timed rounds over the variants (median)')
    p.add_argument(
        '--bag', type=Path, default=Path(__file__).resolve().parents[1] / 'bags' / 'brighton_beach'
    )
    p.add_argument('--cache', type=Path, default=Path('/tmp/ibr_bench_mvs_brighton.pkl'))
    p.add_argument('--views', type=int, default=6, help='real keyframes')
    p.add_argument('--skip-real', action='store_true')
    p.add_argument('--skip-synthetic', action='store_true')
    a = p.parse_args()
    names = ['default'] + [k for k in a.variants if k != 'default']
    for k in names:
        print(f'{k}: {VARIANTS[k][1]}')
    print(
        f'threads: numba {numba.get_num_threads()}, cores {os.cpu_count()}; '
        f'load average (1 min) {os.getloadavg()[0]:.2f}'
    )
    if not a.skip_synthetic:
        synthetic(names, a.runs)
    if not a.skip_real:
        real(names, a.bag, a.cache, a.views, a.runs)
    print(f'load average (1 min) at the end {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
