#!/usr/bin/env python3
# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Refined depth beyond the range MVS sampled, on synthetic bags with ground truth.

``ibr eval depth`` sets the MVS sweep from ground-truth points; the depth_refiner (and ``ibr
process`` without sparse points) sweeps ``near_ratio..far_ratio`` x the scene depth along the
optical axis (:func:`ibr_ros.core.depth.schedule.axis_scene_depth`). With a small ``far_ratio`` (4
before) the far ground of flights that see the horizon lies beyond every MVS sample and its depth
comes from the monocular remap alone. This script refines every ``--step``-th frame (at most
``--max-views``) as the depth_refiner does (its scheduler, ranges and neighbours) and reports the
mean Abs Rel of the fused depth (``RefinedDepth.fused``: before the sky depth) on non-sky
ground-truth pixels:

* ``beyond level``: pixels with ``0 < G < 256 lo``, ``lo`` the farthest level ``G // 256`` with a
  pruned MVS sample among pixels with ``G > 0``: where the lookup table extrapolates;
* ``beyond depth``: pixels whose true depth exceeds the largest pruned MVS depth;
* ``far``: pixels whose true depth exceeds 4 x the median scene depth (the old sweep's far end);
* ``all``: every non-sky pixel, next to FMM (Telea inpainting of the pruned MVS depth).

Example (a low-pitch flight; a few minutes here, most of it MVS)::

    ibr bag synth --seed 7 --pitch=-10,-4 --duration 8 --fps 2 --out /tmp/horizon_s7
    .venv/bin/python tools/far_depth_eval.py /tmp/horizon_s7 --mono plane onnx
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth  # noqa: E402
from ibr_ros.core.depth.mvs import MvsView  # noqa: E402
from ibr_ros.core.depth.refine import DepthRefiner, RefinerConfig  # noqa: E402
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig  # noqa: E402
from ibr_ros.jobs.eval_depth import load_views  # noqa: E402
from ibr_ros.jobs.synth_bag import GroundTruthRenderer  # noqa: E402
from ibr_ros.models import mono_spec  # noqa: E402

HILL = 6  # ibr_ros.core.synth.LABEL_NAMES.index('hill')
#: The "far ground" region: true depth beyond this many times the scene depth (the far end of the
#: schedule's sweep before it was moved beyond the horizon), whatever the sweep reaches.
FAR_REGION_RATIO = 4.0


def scheduled_mvs(
    views: list[MvsView], far_ratio: float | None = None, reuse: bool = False
) -> tuple[list[np.ndarray], float]:
    """MVS depth of every view as the depth_refiner and ``ibr process`` compute it (no sparse
    points): :class:`RefineScheduler` ranges and neighbours, :func:`job_depth` (``reuse``: with the
    ``reuse_neighbour_depth`` cache); and the median scene depth (m) the ranges came from."""
    cfg = ScheduleConfig(reuse_neighbour_depth=reuse)
    if far_ratio is not None:
        cfg = replace(cfg, far_ratio=far_ratio)
    scheduler = RefineScheduler(cfg)
    for i, v in enumerate(views):
        scheduler.add(i, v)
    cache = PhotometricCache.for_flight(cfg.reuse_neighbour_depth)
    out = [np.zeros((v.camera.height, v.camera.width), np.float32) for v in views]
    scene = []
    while (job := scheduler.next_job(flush=True)) is not None:
        m = job_depth(
            job.views, job.stamps, job.depth_range, cfg.mvs, probe_range=job.probe_range, cache=cache
        )
        out[job.stamp] = m.depth
        scene.append(job.depth_range[0] / cfg.near_ratio)
        scheduler.done(job)
    return out, float(np.median(scene))


def abs_rel(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """Mean |pred - gt| / gt on ``mask`` and the pixel count."""
    if not mask.any():
        return float('nan'), 0
    p = pred[mask].astype(np.float64)
    return float(np.mean(np.abs(p - gt[mask]) / gt[mask])), int(mask.sum())


def evaluate(
    mono: str, views: list[MvsView], gts: list, d_mvs: list[np.ndarray], far_m: float = np.inf
) -> dict[str, float]:
    """Pixel-weighted Abs Rel per region over all views (see the module docstring)."""
    model = mono_spec('ibr_mono') if mono == 'onnx' else None
    refiner = DepthRefiner(RefinerConfig(mono='onnx' if mono == 'onnx' else 'plane', mono_model=model))
    sums: dict[str, list[float]] = {}

    def add(key: str, value: tuple[float, int]) -> None:
        s = sums.setdefault(key, [0.0, 0.0])
        if value[1]:
            s[0] += value[0] * value[1]
            s[1] += value[1]

    for view, f, d in zip(views, gts, d_mvs, strict=True):
        if not np.any(d > 0):
            continue
        r = refiner.refine_from_mvs(view, d)
        nonsky = np.isfinite(f.depth) & ~f.sky
        gt = np.where(nonsky, f.depth, 1.0)
        pruned = r.mvs_pruned
        sampled = (r.g > 0) & (pruned > 0)
        lo = int(r.g[sampled].min()) >> 8 if sampled.any() else 0
        beyond_level = nonsky & (r.g > 0) & (r.g < 256 * lo)
        beyond_depth = nonsky & (gt > pruned.max())
        fmm = cv2.inpaint(pruned, (pruned == 0).astype(np.uint8), 5, cv2.INPAINT_TELEA)
        add('nonsky', (0.0, int(nonsky.sum())))
        add('beyond_level', abs_rel(r.fused, gt, beyond_level))
        add('beyond_depth', abs_rel(r.fused, gt, beyond_depth))
        add('beyond_depth_hill', abs_rel(r.fused, gt, beyond_depth & (f.label == HILL)))
        add('beyond_depth_other', abs_rel(r.fused, gt, beyond_depth & (f.label != HILL)))
        add('far', abs_rel(r.fused, gt, nonsky & (gt > far_m)))
        add('all', abs_rel(r.fused, gt, nonsky))
        add('all_fmm', abs_rel(fmm, gt, nonsky))
    n = sums['nonsky'][1]
    out = {k: (s[0] / s[1] if s[1] else float('nan')) for k, s in sums.items() if k != 'nonsky'}
    for k in ('beyond_level', 'beyond_depth', 'beyond_depth_hill', 'far'):
        out[f'{k}_share'] = sums[k][1] / n
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('bags', nargs='+', type=Path, help='bags made by `ibr bag synth`')
    p.add_argument('--mono', nargs='+', choices=('plane', 'onnx'), default=['plane', 'onnx'])
    p.add_argument('--step', type=int, default=2, help='every Nth frame')
    p.add_argument('--max-views', type=int, default=8)
    p.add_argument(
        '--mvs-cache', type=Path, help='folder for the MVS depth (<bag name>.npz), reused if there'
    )
    p.add_argument(
        '--far-ratio', type=float, help="far end of the sweep x the scene depth (default: the schedule's)"
    )
    p.add_argument('--reuse-neighbour-depth', action='store_true', help='the depth_refiner parameter')
    a = p.parse_args(argv)
    print(
        '| bag | mono | beyond level: share, Abs Rel | beyond depth: share (hills), Abs Rel (hills / other) '
        f'| beyond {FAR_REGION_RATIO:g} x scene depth: share, Abs Rel | all non-sky: ours / FMM |'
    )
    print('| --- | --- | --- | --- | --- | --- |')
    for bag in a.bags:
        views = [v for _, v in load_views(bag, a.step, a.max_views)]
        renderer = GroundTruthRenderer(bag)
        gts = [renderer.render(v.t_wc, v.camera) for v in views]
        cache = a.mvs_cache / f'{bag.name}.npz' if a.mvs_cache else None
        if cache is not None and cache.is_file():
            d_mvs, scene = list(np.load(cache)['depth']), float(np.load(cache)['scene'])
        else:
            d_mvs, scene = scheduled_mvs(views, a.far_ratio, a.reuse_neighbour_depth)
            if cache is not None:
                cache.parent.mkdir(parents=True, exist_ok=True)
                np.savez_compressed(cache, depth=np.stack(d_mvs), scene=scene)
        far_m = FAR_REGION_RATIO * scene
        for mono in a.mono:
            m = evaluate(mono, views, gts, d_mvs, far_m)
            print(
                f'| {bag.name} | {mono} | {m["beyond_level_share"]:.1%}, {m["beyond_level"]:.3f} '
                f'| {m["beyond_depth_share"]:.1%} ({m["beyond_depth_hill_share"]:.1%}), '
                f'{m["beyond_depth"]:.3f} '
                f'({m["beyond_depth_hill"]:.3f} / {m["beyond_depth_other"]:.3f}) '
                f'| {m["far_share"]:.1%}, {m["far"]:.3f} '
                f'| {m["all"]:.3f} / {m["all_fmm"]:.3f} |',
                flush=True,
            )
    return 0


if __name__ == '__main__':
    sys.exit(main())
