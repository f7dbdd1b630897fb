# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark of the synthetic drone renderer: one 20 s, 15 fps, 640x360 flight (300 frames).

Prints the total wall time of the flight, median ms per frame, process CPU time, and two
reference ratios measured in the same process (so a busy machine shows up in both):

* ``vs numpy ground``: median frame time over the time of a numpy-only render of the ground plane
  (ray-plane intersection and a checker texture) at the same size;
* ``parallel speed-up``: single-threaded median over the parallel median, on a few frames.

Exits 1 when the flight takes longer than ``--budget`` seconds (default 60). Usage:
``.venv/bin/python bench/bench_synth.py [--kind orbit] [--frames 300] [--budget 60]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.synth import (
    SceneConfig,
    build_scene,
    flight_camera,
    make_trajectory,
    render_view,
    safe_altitude_range,
)


def numpy_ground(camera: PinholeCamera, t_wc: np.ndarray) -> np.ndarray:
    """Reference workload: z = 0 plane with a 1 m checker texture, numpy only."""
    d = camera.pixel_rays() @ t_wc[:3, :3].T
    with np.errstate(divide='ignore', invalid='ignore'):
        t = -t_wc[2, 3] / d[..., 2]
    p = t_wc[:3, 3] + t[..., None] * d
    hit = np.isfinite(t) & (t > 0)
    chk = (np.floor(p[..., 0]) + np.floor(p[..., 1])) % 2
    img = np.where(hit, 60 + 120 * chk, 200).astype(np.uint8)
    return np.repeat(img[..., None], 3, axis=2)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--kind', default='orbit', choices=['orbit', 'lawnmower', 'forward'])
    ap.add_argument('--frames', type=int, default=300, help='frames to render (default: 20 s at 15 fps)')
    ap.add_argument('--budget', type=float, default=60.0, help='seconds allowed for the 300-frame flight')
    ap.add_argument('--seed', type=int, default=0)
    args = ap.parse_args()

    cfg = SceneConfig(seed=args.seed)
    t0 = time.perf_counter()
    scene = build_scene(cfg)
    t_scene = time.perf_counter() - t0
    camera = flight_camera((640, 360), 70.0)
    samples = make_trajectory(
        args.kind, duration_s=20.0, fps=15.0, seed=cfg.seed, altitude_range=safe_altitude_range(cfg)
    )[: args.frames]
    t0 = time.perf_counter()
    render_view(scene, camera.scaled(0.1), samples[0].t_wc)  # numba compile or cache load
    t_compile = time.perf_counter() - t0

    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    times = []
    for s in samples:
        ts = time.perf_counter()
        render_view(scene, camera, s.t_wc)
        times.append(time.perf_counter() - ts)
    total = time.perf_counter() - t0
    cpu = time.process_time() - c0
    load1 = os.getloadavg()[0]
    med = float(np.median(times))

    ref = []
    for s in samples[:: max(1, len(samples) // 10)]:
        ts = time.perf_counter()
        numpy_ground(camera, s.t_wc)
        ref.append(time.perf_counter() - ts)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    single = []
    for s in samples[:: max(1, len(samples) // 5)][:5]:
        ts = time.perf_counter()
        render_view(scene, camera, s.t_wc)
        single.append(time.perf_counter() - ts)
    numba.set_num_threads(threads)

    n = len(samples)
    budget = args.budget * n / 300
    layer = numba.threading_layer()
    print(f'synthetic flight: {args.kind}, {n} frames 640x360, {threads} numba threads ({layer})')
    print(f'scene build {t_scene:.2f} s, compile/cache load {t_compile:.2f} s')
    print(f'load average {load0:.2f} -> {load1:.2f} (other processes compete for the cores)')
    p90 = 1e3 * np.percentile(times, 90)
    print(f'total {total:.1f} s  median {1e3 * med:.0f} ms/frame  p90 {p90:.0f} ms')
    print(f'process CPU {cpu:.1f} s ({1e3 * cpu / n:.0f} ms/frame, {cpu / total:.2f} cores busy on average)')
    est = cpu / threads * 300 / n
    print(f'estimate on {threads} idle cores (CPU / {threads}): {est:.1f} s per 300 frames')
    print(f'vs numpy ground: {med / float(np.median(ref)):.1f}x ({1e3 * np.median(ref):.1f} ms/frame)')
    t1 = float(np.median(single))
    print(f'parallel speed-up: {t1 / med:.2f}x (single thread {1e3 * t1:.0f} ms/frame)')
    ok = total <= budget
    print(f'{"PASS" if ok else "FAIL"}: {total:.1f} s {"<=" if ok else ">"} budget {budget:.1f} s')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
