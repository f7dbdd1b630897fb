# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Scheduling alone over a long flight: milliseconds per keyframe at 100 / 300 / 600 / 1000 keyframes.

Feeds the synthetic lawnmower flight of ``bench_long_flight.py`` (1120 poses, 2.3 m apart, the town
revisited lane after lane) into a :class:`~ibr_ros.core.depth.schedule.RefineScheduler` with the
default configuration, one keyframe at a time, and hands out every due job (``next_job``, ``done``)
after each arrival, as the depth_refiner does. No MVS runs: tiny images, only neighbour search, depth
ranges and bookkeeping are timed. Flat columns = no cost growing with the flight.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

from ibr_ros.core.depth.mvs import MvsView
from ibr_ros.core.depth.schedule import RefineScheduler, ScheduleConfig
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.synth.trajectory import make_trajectory

MARKS = (100, 300, 600, 1000)


def main() -> int:
    cam = PinholeCamera(width=64, height=36, k=np.array([[50.0, 0, 32.0], [0, 50.0, 18.0], [0, 0, 1]]))
    rgb = np.zeros((36, 64, 3), np.uint8)
    flight = make_trajectory('lawnmower', duration_s=320.0, fps=3.5)
    sched = RefineScheduler(ScheduleConfig())
    jobs = 0
    last_t, last_n = time.perf_counter(), 0
    print('keyframes  ms/keyframe (since the previous row)  jobs')
    for n, sample in enumerate(flight[: MARKS[-1]], start=1):
        sched.add(round(sample.t_s * 1e9) + 1, MvsView(rgb, cam, sample.t_wc))
        while (job := sched.next_job()) is not None:
            sched.done(job)
            jobs += 1
        if n in MARKS:
            now = time.perf_counter()
            print(f'{n:9d}  {(now - last_t) / (n - last_n) * 1e3:8.1f}  {jobs:6d}', flush=True)
            last_t, last_n = now, n
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
