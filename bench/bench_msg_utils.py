# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark: 1920x1080 rgb8 numpy <-> sensor_msgs/Image with msg_utils, both flavours.

Prints the median of RUNS runs for each direction next to a naive baseline measured in the same
process (``msg.data = arr.tobytes()`` / ``np.array(msg.data).reshape``) and exits 1 when a
msg_utils conversion misses the TARGET_MS budget. Lines marked ``info`` are not gated: the naive
setter with ROS_PYTHON_CHECK_FIELDS=1, and conversions into never-touched memory, whose cost is
dominated by the kernel's page faults for the new 6 MB buffer.
Run: ``.venv/bin/python bench/bench_msg_utils.py``.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from msg_utils import image_to_numpy, make_header, new_message, numpy_to_image

H, W = 1080, 1920
RUNS = 50
TARGET_MS = 3.0


def median_ms(fn: Callable[[], object], runs: int = RUNS) -> float:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def fresh_memory_ms(fn: Callable[[], object], runs: int = 20) -> float:
    """Median time when every result stays alive, so each call writes to never-touched memory."""
    keep, times = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        keep.append(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def naive_to_image(a: np.ndarray, flavor: str, *, check_fields: bool = False) -> object:
    msg = new_message(
        'sensor_msgs/msg/Image',
        flavor,
        header=make_header(0, 'cam', flavor),
        height=H,
        width=W,
        encoding='rgb8',
    )
    msg.step = W * 3
    if flavor == 'rosbags':
        msg.data = np.frombuffer(a.tobytes(), np.uint8)
    else:
        msg._check_fields = check_fields  # what ROS_PYTHON_CHECK_FIELDS=1 turns on
        msg.data = a.tobytes()
    return msg


def naive_to_numpy(msg: object) -> np.ndarray:
    return np.array(msg.data, dtype=np.uint8).reshape(H, W, 3)


def bench_flavor(a: np.ndarray, flavor: str) -> bool:
    header = make_header(0, 'cam', flavor)
    msg = numpy_to_image(a, 'rgb8', header, flavor=flavor)
    naive_msg = naive_to_image(a, flavor)
    assert np.array_equal(image_to_numpy(msg), a)
    assert np.array_equal(naive_to_numpy(naive_msg), a)
    rows = [
        (
            'numpy->Image',
            lambda: numpy_to_image(a, 'rgb8', header, flavor=flavor),
            lambda: naive_to_image(a, flavor),
        ),
        ('Image->numpy', lambda: image_to_numpy(msg), lambda: naive_to_numpy(naive_msg)),
    ]
    ok = True
    for name, fast, naive in rows:
        t_fast, t_naive = median_ms(fast), median_ms(naive)
        ok &= t_fast <= TARGET_MS
        flag = '' if t_fast <= TARGET_MS else '  MISSED TARGET'
        print(f'{flavor:8} {name:15} {t_fast:9.3f} {t_naive:8.3f} {t_naive / t_fast:7.1f}x{flag}')
    return ok


def main() -> int:
    a = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    print(f'{W}x{H} rgb8, median of {RUNS} runs (ms); target <= {TARGET_MS} ms')
    print(f'{"flavour":8} {"direction":15} {"msg_utils":>9} {"naive":>8} {"speed-up":>8}')
    ok = all([bench_flavor(a, flavor) for flavor in ('rclpy', 'rosbags')])
    checked = median_ms(lambda: naive_to_image(a, 'rclpy', check_fields=True), runs=3)
    print(f'info: naive rclpy numpy->Image with ROS_PYTHON_CHECK_FIELDS=1: {checked:.1f} ms (median of 3)')
    for flavor in ('rclpy', 'rosbags'):
        fresh = fresh_memory_ms(lambda flavor=flavor: numpy_to_image(a, 'rgb8', flavor=flavor))
        naive = fresh_memory_ms(lambda flavor=flavor: naive_to_image(a, flavor))
        print(
            f'info: {flavor} numpy->Image keeping every message alive (no memory reuse, page faults): '
            f'{fresh:.2f} ms, naive {naive:.2f} ms (median of 20)'
        )
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
