# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Throughput of ``ibr process`` on the shipped synthetic bag: seconds per keyframe per stage.

Runs :func:`ibr_ros.jobs.process.process_bag` on ``bags/synth_orbit_s0`` with the parameters of
``ibr demo`` (frame_subsampler ``scene_depth_m`` 80 -> 25 keyframes; depth_refiner
``max_neighbours`` 2, ``flush_after_s`` 3), 8 novel views, after a short warm-up run (numba
kernels loaded). ``--defaults`` uses the plain ``config/*.yaml`` parameters instead (67 keyframes).

Baseline in the same process: the live depth_refiner's schedule on the same keyframes (they
arrive one by one, each refined as soon as it has ``min_neighbours`` neighbours among those seen
so far, the rest at the end with a flush), timing MVS + refinement per keyframe; the ratio is
offline / live seconds per refined keyframe. When ``out/logs/depth_refiner.log`` of an earlier
``make demo`` exists, its logged per-keyframe times are printed too (another run, other load).
A bag without poses (e.g. ``--bag bags/brighton_beach --defaults``) runs in SfM mode: the SfM
statistics are printed and there is no live-schedule baseline (it needs the bag's poses).
Exits 1 unless every keyframe was refined.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

import numba

REPO = Path(__file__).resolve().parents[1]
DEMO_PARAMS = """\
frame_subsampler:
  ros__parameters:
    scene_depth_m: 80.0
depth_refiner:
  ros__parameters:
    max_neighbours: 2
    flush_after_s: 3.0
"""
STAGES = ('subsample', 'sfm', 'mvs', 'refine', 'render', 'pipeline', 'write', 'evaluate', 'total')


def live_schedule_seconds(bag: Path, params: Path | None, max_keyframes: int | None) -> list[float]:
    """MVS + refinement seconds per keyframe with the live node's schedule (arrival order, flush at end)."""
    from ibr_ros.core.depth.mvs import MvsView
    from ibr_ros.core.depth.refine import DepthRefiner, refine_job
    from ibr_ros.core.depth.schedule import RefineScheduler
    from ibr_ros.jobs.process.frames import subsample
    from ibr_ros.jobs.process.options import ProcessOptions
    from ibr_ros.jobs.process.params import load_params, process_configs

    options = ProcessOptions(params=params, max_keyframes=max_keyframes)
    cfg = process_configs(load_params(params), options)
    keyframes = subsample(bag, cfg, options, None).keyframes
    scheduler = RefineScheduler(cfg.schedule)
    refiner = DepthRefiner(cfg.refiner)
    times: list[float] = []

    def drain(flush: bool) -> None:
        while (job := scheduler.next_job(flush=flush)) is not None:
            result = refine_job(refiner, job, cfg.schedule.mvs)
            if result.refined is None:
                scheduler.failed(job)
                continue
            scheduler.done(job)
            times.append(result.seconds)

    for k in keyframes:
        scheduler.add(k.stamp, MvsView(k.rgb, k.camera, k.t_wc))
        drain(False)
    drain(cfg.flush)
    return times


def demo_log_seconds(log: Path) -> list[float]:
    """Per-keyframe seconds logged by the depth_refiner of ``ibr demo`` (empty when no log)."""
    if not log.is_file():
        return []
    return [
        float(m[1])
        for m in re.finditer(r'refined keyframe \d+ ns with \d+ neighbours in ([\d.]+) s', log.read_text())
    ]


def main() -> int:
    from ibr_ros.jobs.process import ProcessOptions, process_bag

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', type=Path, default=REPO / 'bags' / 'synth_orbit_s0')
    ap.add_argument('--defaults', action='store_true', help='config/*.yaml parameters, not the demo ones')
    ap.add_argument('--views', type=int, default=8)
    ap.add_argument('--max-keyframes', type=int, help='for a quick look')
    ap.add_argument('--no-live', action='store_true', help='skip the live-schedule baseline')
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        params = None
        if not args.defaults:
            params = Path(tmp) / 'demo.yaml'
            params.write_text(DEMO_PARAMS)
        warmup = ProcessOptions(params=params, max_keyframes=4, views=1)  # 4: SfM mode's sfm_min_keyframes
        process_bag(args.bag, Path(tmp) / 'warmup', warmup)
        s = process_bag(
            args.bag,
            Path(tmp) / 'out',
            ProcessOptions(params=params, views=args.views, max_keyframes=args.max_keyframes),
        )
        sfm = s.get('sfm')
        live = [] if args.no_live or sfm else live_schedule_seconds(args.bag, params, args.max_keyframes)

    n, t = s['keyframes'], s['timings_s']
    print(f'ibr process {args.bag} ({"config defaults" if args.defaults else "ibr demo parameters"}), '
          f'{numba.get_num_threads()} threads: {n} keyframes, {s["refined"]} refined, '
          f'{s["views_answered"]}/{s["views_requested"]} views')  # fmt: skip
    print(f'{"stage":<10} {"seconds":>8} {"s/keyframe":>11}')
    for stage in STAGES:
        print(f'{stage:<10} {t[stage]:>8.2f} {t[stage] / n:>11.3f}')
    if sfm:
        rms = (sfm['gps'] or {}).get('alignment_rms_m')
        print(
            f'SfM ({sfm["why"]}): {sfm["registered"]}/{sfm["keyframes"]} keyframes registered, frame '
            f'{sfm["frame_id"]}, reprojection error {sfm["mean_reprojection_error_px"]:.2f} px, GPS '
            f'alignment RMS {"n/a" if rms is None else f"{rms:.2f}"} m, {sfm["seconds"]:.1f} s'
        )
    if (gt := s.get('ground_truth')) is not None:
        print(
            f'depth median abs rel {gt["depth_median_abs_rel"]:.4f}, '
            f'rephoto mean AUC {gt["rephoto_auc_mean"]:.2f}'
        )
    offline = (t['mvs'] + t['refine']) / max(s['refined'], 1)
    print(f'offline MVS + refine: {offline:.3f} s per refined keyframe')
    if live:
        mean_live = statistics.fmean(live)
        print(f'live schedule, same process: {mean_live:.3f} s per refined keyframe ({len(live)} refined); '
              f'offline / live = {offline / mean_live:.2f}')  # fmt: skip
    if logged := demo_log_seconds(REPO / 'out' / 'logs' / 'depth_refiner.log'):
        print(f'last `make demo` log: {statistics.fmean(logged):.3f} s per keyframe ({len(logged)} refined; '
              'another run and load)')  # fmt: skip
    return 0 if s['refined'] == n else 1


if __name__ == '__main__':
    sys.exit(main())
