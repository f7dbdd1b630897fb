# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark: SLIC superpixels at 960x540 (target <= 20 ms) and the shiftable-L1 rephoto error.

Warm (numba compiled first), median of >= 20 runs, with 2 threads and with 1 thread (numba and
OpenCV both). The baseline, run in the same process, is the same SLIC assignment (9 candidate
clusters per pixel, 5 iterations, CIELAB, same compactness) written as straightforward vectorised
numpy, without gradient seeding and without connectivity enforcement (so it does less work).
Input: a real drone photo from ../shared/data (resized to 960x540) when present, else a procedural
image. Exits 1 when no thread count meets the 20 ms wall-clock target. When other processes
overload the machine (1-minute load average above the CPU count) a run whose single-thread CPU
time meets the target only warns, since the wall-clock target cannot be checked then.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import cv2
import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # benchmark the checkout, not an installed copy

from timing import median_ms  # noqa: E402

from ibr_ros.core.evaluation.rephoto import shiftable_l1  # noqa: E402
from ibr_ros.core.render.superpixels import slic  # noqa: E402

W, H = 960, 540
N_SEGMENTS = 1500
RUNS = 25
TARGET_MS = 20.0
PHOTO = REPO.parent / 'shared' / 'data' / 'brighton_beach' / 'images' / 'DJI_0018.JPG'


def test_image() -> tuple[np.ndarray, str]:
    if PHOTO.exists():
        bgr = cv2.imread(str(PHOTO))
        if bgr is not None:
            rgb = cv2.resize(bgr, (W, H), interpolation=cv2.INTER_AREA)[:, :, ::-1]
            return np.ascontiguousarray(rgb), f'{PHOTO.name} resized to {W}x{H}'
    rng = np.random.default_rng(0)
    img = cv2.resize(rng.uniform(0, 255, (H // 8, W // 8, 3)).astype(np.float32), (W, H))
    for _ in range(60):
        c = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        cv2.circle(img, c, int(rng.integers(10, 80)), rng.uniform(0, 255, 3).tolist(), -1)
    img += rng.normal(0, 6, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8), f'procedural {W}x{H}'


def numpy_slic(
    rgb: np.ndarray, n_segments: int, compactness: float = 10.0, iterations: int = 5
) -> np.ndarray:
    """Baseline: the same pixel-centric SLIC in vectorised numpy (no seed refinement, no connectivity)."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab).astype(np.float32)
    lab[..., 0] *= 100.0 / 255.0
    lab[..., 1:] -= 128.0
    h, w = rgb.shape[:2]
    step = math.sqrt(h * w / n_segments)
    ny, nx = max(1, round(h / step)), max(1, round(w / step))
    yb = np.round(np.linspace(0, h, ny + 1)).astype(int)
    xb = np.round(np.linspace(0, w, nx + 1)).astype(int)
    cell_y = np.searchsorted(yb, np.arange(h), 'right') - 1
    cell_x = np.searchsorted(xb, np.arange(w), 'right') - 1
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    feats = np.concatenate([lab, xx[..., None], yy[..., None]], axis=2).reshape(-1, 5)
    cy = (yb[:-1] + yb[1:] - 1) // 2
    cx = (xb[:-1] + xb[1:] - 1) // 2
    centres = feats.reshape(h, w, 5)[cy[:, None], cx[None, :]].reshape(-1, 5).copy()
    weight = np.float32((compactness / step) ** 2)
    scale = np.array([1, 1, 1, weight, weight], np.float32)
    ids = np.zeros(h * w, np.int64)
    for _ in range(iterations):
        best = np.full(h * w, np.inf, np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ky, kx = cell_y + dy, cell_x + dx
                ok = ((ky >= 0) & (ky < ny))[:, None] & ((kx >= 0) & (kx < nx))[None, :]
                cand = (np.clip(ky, 0, ny - 1)[:, None] * nx + np.clip(kx, 0, nx - 1)[None, :]).ravel()
                d = (((feats - centres[cand]) ** 2) * scale).sum(axis=1)
                d[~ok.ravel()] = np.inf
                better = d < best
                best[better] = d[better]
                ids[better] = cand[better]
        count = np.bincount(ids, minlength=ny * nx).astype(np.float32)
        has = count > 0
        for j in range(5):
            s = np.bincount(ids, weights=feats[:, j], minlength=ny * nx)
            centres[has, j] = s[has] / count[has]
    return ids.reshape(h, w)


def set_threads(n: int) -> None:
    numba.set_num_threads(n)
    cv2.setNumThreads(n)


def main() -> int:
    img, source = test_image()
    max_threads = numba.config.NUMBA_NUM_THREADS
    thread_counts = sorted({min(2, max_threads), 1}, reverse=True)
    print(f'input: {source}; n_segments={N_SEGMENTS}; {RUNS} warm runs each, median')
    print(
        f'cpus: {os.cpu_count()}, numba threading layer threads: {max_threads}, load avg: {os.getloadavg()}'
    )

    labels = slic(img, n_segments=N_SEGMENTS)  # compile
    gt = img
    synth = np.ascontiguousarray(np.roll(img, (1, 2), axis=(0, 1)))
    shiftable_l1(gt, synth)  # compile

    results: dict[int, tuple[float, float]] = {}
    for n in thread_counts:
        set_threads(n)
        results[n] = median_ms(lambda _: slic(img, n_segments=N_SEGMENTS), RUNS)
    set_threads(1)
    base_labels = numpy_slic(img, N_SEGMENTS)
    base, _ = median_ms(lambda _: numpy_slic(img, N_SEGMENTS), 20)
    rephoto = {}
    for n in thread_counts:
        set_threads(n)
        rephoto[n] = median_ms(lambda _: shiftable_l1(gt, synth, 7, 2), RUNS)
    set_threads(max_threads)
    load = os.getloadavg()[0]

    print(f'slic labels: {labels.max() + 1} (baseline: {np.unique(base_labels).size})')
    for n, (ms, cpu) in results.items():
        print(
            f'slic          {n} thread(s): {ms:7.2f} ms wall ({cpu:6.2f} ms CPU)  base/slic {base / ms:5.1f}x'
        )
    print(f'numpy SLIC baseline, 1 thread: {base:7.2f} ms wall')
    for n, (ms, cpu) in rephoto.items():
        print(f'shiftable_l1  {n} thread(s): {ms:7.2f} ms wall ({cpu:6.2f} ms CPU)  (patch 7, shift 2)')
    print(f'load average after the runs: {load:.2f} on {os.cpu_count()} CPUs')

    best_n = min(results, key=lambda n: results[n][0])
    best = results[best_n][0]
    if best <= TARGET_MS:
        print(f'OK: slic {best:.2f} ms wall with {best_n} thread(s) <= target {TARGET_MS:.0f} ms')
        return 0
    cpu_1 = results[1][1]
    if load > (os.cpu_count() or 1) and cpu_1 <= TARGET_MS:
        # Other processes held the CPUs: the wall-clock target cannot be checked on this run.
        print(
            f'WARN: machine overloaded (load {load:.2f}): slic {best:.2f} ms wall with {best_n} thread(s) '
            f'misses {TARGET_MS:.0f} ms, but 1-thread CPU time {cpu_1:.2f} ms meets it; rerun when idle'
        )
        return 0
    print(f'FAIL: slic {best:.2f} ms wall with {best_n} thread(s) > target {TARGET_MS:.0f} ms')
    return 1


if __name__ == '__main__':
    sys.exit(main())
