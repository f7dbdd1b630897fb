# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Depth refinement core benchmarks: fusion (960x540), pruning and LUT remapping (1228x816).

Warm timings (every kernel compiled first), median of N_RUNS runs, one thread, on a synthetic
outdoor view: a ground plane seen obliquely, box buildings, sky; MVS depth with holes, noise and
outliers; monocular ``G`` an affine function of inverse depth.  Baselines run in the same process:

* fusion: the same tree filter on an MST built the plain way (numpy edge list, ``np.argsort`` edge
  sort, union by rank), and OpenCV's Telea inpainting of the same holes as a reference timing;
* pruning: OpenCV's 5x5 ``medianBlur`` (unweighted, unknowns not ignored) as a reference timing;
* remap: the median-factor baseline.

Exits 1 if fuse_depth misses its target (TARGET_FUSE_S at 960x540).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

import cv2
import numba
import numpy as np
from numba import njit

from ibr_ros.core.depth import fusion, prune, remap

N_RUNS = 10
TARGET_FUSE_S = 0.040
AIM_PRUNE_S = 0.100


def scene(h: int, w: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Synthetic view: (rgb uint8, ground-truth depth float32 with +inf sky, MVS depth, G uint16)."""
    rng = np.random.default_rng(seed)
    yy = np.mgrid[0:h, 0:w][0].astype(np.float64)
    horizon, f, cam_h = 0.3 * h, 0.9 * w, 30.0
    gt = np.full((h, w), np.inf)
    ground = yy > horizon + 2
    gt[ground] = cam_h * f / (yy[ground] - horizon)

    def smooth_noise(cells: int) -> np.ndarray:
        small = rng.random((max(2, h // cells), max(2, w // cells))).astype(np.float32)
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)

    rgb = np.empty((h, w, 3))
    rgb[...] = [90, 110, 60]
    rgb += 60 * smooth_noise(40)[..., None] * [1.0, 0.8, 0.5]
    sky = ~ground
    rgb[sky] = np.stack([120 + 40 * yy[sky] / h, 160 + 30 * yy[sky] / h, 230 + 0 * yy[sky]], -1)
    for _ in range(8):  # buildings
        bw, bh = rng.integers(w // 16, w // 6), rng.integers(h // 8, h // 3)
        x0, base = rng.integers(0, w - bw), rng.integers(int(horizon) + 10, int(0.6 * h))
        z = cam_h * f / (base - horizon)
        sl = np.s_[max(0, base - bh) : base, x0 : x0 + bw]
        closer = gt[sl] > z
        gt[sl][closer] = z
        rgb[sl][closer] = rng.uniform(60, 220, 3)
    rgb += rng.normal(0, 3, rgb.shape)
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)

    mvs = gt * (1 + 0.005 * rng.standard_normal((h, w)))
    holes = smooth_noise(24) > 0.75  # texture-less patches
    mvs[holes | ~np.isfinite(gt) | (gt > 800)] = 0
    isolated = rng.random((h, w)) < 0.003
    base = np.where(np.isfinite(gt[isolated]), gt[isolated], 200)
    mvs[isolated] = base * rng.uniform(0.3, 3, isolated.sum())
    for _ in range(40):  # small clusters of false depth in the sky
        y0, x0 = rng.integers(0, int(horizon) - 4), rng.integers(0, w - 4)
        mvs[y0 : y0 + 3, x0 : x0 + 3] = rng.uniform(50, 300)
    g = np.clip(1.5e6 / np.minimum(gt, 1e6) + 800, 0, 65535).astype(np.uint16)
    return rgb, gt.astype(np.float32), mvs.astype(np.float32), g


def timed(fn, *args, runs: int = N_RUNS) -> float:
    """Median wall time of ``runs`` warm calls (the minimum is printed too: the machine is shared)."""
    fn(*args)  # warm: compile / load caches
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t)
    timed.last_min = min(times)
    return float(np.median(times))


# --------------------------------------------------------------------------------------------- baselines


@njit(cache=True)
def _naive_kruskal(edges, n, w):
    """Union by rank with full path compression over pre-sorted edges: tree neighbour bits."""
    par = np.arange(n)
    rank = np.zeros(n, np.int64)
    nbr = np.zeros(n, np.uint8)
    roots = np.empty(2, np.int64)
    for i in range(edges.shape[0]):
        e = edges[i]
        p = e >> 1
        q = p + w if e & 1 else p + 1
        for k in range(2):
            x = p if k == 0 else q
            a = x
            while par[a] != a:
                a = par[a]
            while par[x] != a:
                nxt = par[x]
                par[x] = a
                x = nxt
            roots[k] = a
        a, b = roots[0], roots[1]
        if a == b:
            continue
        if rank[a] < rank[b]:
            a, b = b, a
        par[b] = a
        if rank[a] == rank[b]:
            rank[a] += 1
        if e & 1:
            nbr[p] |= 2
            nbr[q] |= 8
        else:
            nbr[p] |= 1
            nbr[q] |= 4
    return nbr


def naive_fuse(rgb: np.ndarray, d_mvs: np.ndarray, d_mono: np.ndarray, sigma=0.06, alpha=1e-5) -> np.ndarray:
    """The same tree and filter, built the plain way: numpy edges, ``np.argsort``, union by rank."""
    h, w = d_mvs.shape
    c = rgb.astype(np.int16)
    we = np.zeros((h, w, 2), np.uint8)  # edge id 2p: right, 2p + 1: down (as in fusion)
    we[:, :-1, 0] = np.abs(c[:, 1:] - c[:, :-1]).max(-1)
    we[:-1, :, 1] = np.abs(c[1:] - c[:-1]).max(-1)
    exists = np.ones((h, w, 2), bool)
    exists[:, -1, 0] = False
    exists[-1, :, 1] = False
    we = we.reshape(-1)
    ids = np.flatnonzero(exists.reshape(-1))
    edges = ids[np.argsort(we[ids], kind='stable')]  # same tie order as the counting sort
    nbr = _naive_kruskal(edges, h * w, w)
    order, ppos, wpar = fusion._bfs(nbr, we, w)
    dm = d_mvs.reshape(-1)
    agg = fusion._aggregate(order, ppos, wpar, dm, fusion._similarity(sigma))
    return fusion._combine(order, agg, dm, d_mono.reshape(-1), alpha).reshape(h, w)


def telea(d_mvs: np.ndarray) -> np.ndarray:
    holes = (~(d_mvs > 0)).astype(np.uint8)
    return cv2.inpaint(np.nan_to_num(d_mvs, posinf=0), holes, 3, cv2.INPAINT_TELEA)


# --------------------------------------------------------------------------------------------- main


def main() -> int:
    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    ok = True

    rgb, gt, mvs, g = scene(540, 960)
    pruned = prune.prune_depth(mvs, rgb)
    mono = remap.lut_remap(g, pruned)
    t_fuse = timed(fusion.fuse_depth, rgb, pruned, mono)
    t_fuse_min = timed.last_min
    t_naive = timed(naive_fuse, rgb, pruned, mono)
    t_telea = timed(telea, pruned, runs=3)
    same = np.array_equal(naive_fuse(rgb, pruned, mono), fusion.fuse_depth(rgb, pruned, mono))
    print(
        f'fuse_depth 960x540: median {t_fuse * 1e3:.1f} ms, min {t_fuse_min * 1e3:.1f} ms '
        f'(target {TARGET_FUSE_S * 1e3:.0f} ms)'
    )
    print(f'  naive MST (argsort, union by rank): {t_naive * 1e3:.1f} ms, ratio {t_naive / t_fuse:.2f}x')
    print(f'  naive and fast outputs identical: {same}')
    print(f'  cv2.inpaint TELEA r=3 (reference): {t_telea * 1e3:.1f} ms, ratio {t_telea / t_fuse:.2f}x')
    if t_fuse > TARGET_FUSE_S:
        print('  FUSION TARGET MISSED')
        ok = False

    rgb, gt, mvs, g = scene(816, 1228)
    t_prune = timed(prune.prune_depth, mvs, rgb)
    t_prune_min = timed.last_min
    t_blur = timed(lambda d: cv2.medianBlur(d, 5), mvs)
    pruned = prune.prune_depth(mvs, rgb)
    known = mvs > 0
    removed = known & (pruned == 0)
    bad = known & (np.abs(mvs / np.where(np.isfinite(gt), gt, np.inf) - 1) > 0.1)
    print(
        f'prune_depth 1228x816: median {t_prune * 1e3:.1f} ms, min {t_prune_min * 1e3:.1f} ms '
        f'(aim {AIM_PRUNE_S * 1e3:.0f} ms)'
    )
    print(f'  cv2.medianBlur 5x5 (reference): {t_blur * 1e3:.1f} ms, ratio {t_blur / t_prune:.2f}x')
    print(
        f'  removed {removed.sum()} of {known.sum()} samples; outliers (>10% off) removed '
        f'{(removed & bad).sum()} of {bad.sum()}; good samples removed {(removed & ~bad).sum()}'
    )

    t_lut = timed(remap.lut_remap, g, pruned)
    t_med = timed(remap.median_factor_remap, g, pruned)
    print(f'lut_remap 1228x816: {t_lut * 1e3:.1f} ms')
    print(f'  median_factor_remap (baseline): {t_med * 1e3:.1f} ms, ratio {t_med / t_lut:.2f}x')

    t_total = t_prune + t_lut + timed(fusion.fuse_depth, rgb, pruned, remap.lut_remap(g, pruned))
    print(f'prune + remap + fuse at 1228x816: {t_total * 1e3:.1f} ms (refinement target 250 ms)')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
