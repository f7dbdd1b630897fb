# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Timing helper shared by the benchmarks (imported as ``timing``: bench/ is the scripts' own folder)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_ms(fn: Callable[[int], object], runs: int, warmup: int = 0) -> tuple[float, float]:
    """Median wall-clock and median process CPU time of ``fn(i)``, ``i = 0 .. runs - 1``, in ms.

    ``warmup`` untimed calls ``fn(0)`` come first.
    """
    for _ in range(warmup):
        fn(0)
    wall, cpu = [], []
    for i in range(runs):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn(i)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return 1e3 * statistics.median(wall), 1e3 * statistics.median(cpu)
