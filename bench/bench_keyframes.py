# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe decision rate at 960x540: blur_px + KeyframeSelector.decide per frame.

Warm, median over N_FRAMES frames of a synthetic flight (rendered once). Baseline in the same
process: the variance of the Laplacian at full resolution (no downscaling; the blur score before
blur_px, content-dependent). Target: >= 30 decisions per second, one per frame of a 30 fps camera
(blur_px measures edge widths in four directions at up to 1000 px: far more work than one
Laplacian). Exits 1 if missed.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

import cv2

from ibr_ros.core.flight.keyframes import KeyframeSelector, blur_px
from ibr_ros.core.synth import SceneConfig, build_scene, flight_camera, make_trajectory, render_view

N_FRAMES = 12
REPEAT = 20
TARGET_FPS = 30.0


def main() -> int:
    scene = build_scene(SceneConfig(seed=0))
    cam = flight_camera((960, 540), 70.0)
    samples = make_trajectory('orbit', duration_s=N_FRAMES / 4, fps=4, seed=0)[:N_FRAMES]
    frames = [(int(s.t_s * 1e9), s.t_wc, render_view(scene, cam, s.t_wc).rgb) for s in samples]
    times, base = [], []
    for _ in range(REPEAT):
        sel = KeyframeSelector()
        for stamp, pose, rgb in frames:
            t = time.perf_counter()
            sel.decide(stamp, pose, blur_px(rgb), 80.0)
            times.append(time.perf_counter() - t)
            t = time.perf_counter()
            float(cv2.Laplacian(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), cv2.CV_32F).var())
            base.append(time.perf_counter() - t)
    med, med_base = statistics.median(times), statistics.median(base)
    rate = 1.0 / med
    print(
        f'keyframe decision 960x540: median {med * 1e3:.2f} ms = {rate:.0f} decisions/s '
        f'(target {TARGET_FPS:.0f})'
    )
    print(
        f'baseline full-resolution Laplacian variance: {med_base * 1e3:.2f} ms; ratio {med / med_base:.2f}x'
    )
    print(f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')
    return 0 if rate >= TARGET_FPS else 1


if __name__ == '__main__':
    sys.exit(main())
