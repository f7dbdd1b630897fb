# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Sweep-kernel benchmark (issue 15): ``mvs._sweep`` against the kernels before the speed-up.

Baseline in the same process: ``bench/_sweep_kernel_baseline.py`` (``_warp_rows``, ``_zncc_rows``,
``_sweep`` of main at cf48d5e, before round 3, float64 sums; round 3 gave the same output, round 4
sums in float32); ``--round1`` also times the kernels before round 1
(``_sweep_kernel_baseline_606ef63.py``) for the cumulative ratio. Inputs: the synthetic orbit of
``bench_mvs.py`` (seed 1) at 1000x750 and 640x360 with 4 neighbours, and ``--views`` keyframes of
``--bag`` (real photos, keyframes and SfM as ``ibr process`` makes them, cached like
``bench_mvs.py --bag``) with up to 4 neighbours.

Per input:

* **kernel**: the ``_sweep`` calls of one ``mvs_depth`` (recorded on the baseline kernels) run on
  both kernels alternately, ``--runs`` times; medians of the CPU (``time.process_time``, all
  threads) and wall time, split into the sweep over all planes ("planes", calls with more than 8
  hypotheses) and the full-resolution hypotheses ("refine"); new / old is the claim.
* **ZNCC**: each source alone (``top_k`` 1, one hypothesis: the score is that source's ZNCC) at 6
  hypotheses of the plane sweep and the first refinement call, new against old, at the reference
  pixels textured enough for a depth: the difference exceeded by 0.2 % of the pixels where both
  score, the share beyond 1e-3, and the share whose validity differs.
* **pipeline**: ``mvs_depth`` with each kernel (alternately, timed the same way) and its depth maps
  compared: the share of pixels with depth in both within 1e-3 (relative), the share of all pixels
  that have depth in one only, and accuracy / completeness (synthetic: within 5 % of the ground
  truth / with a depth; real: pixels with depth / SfM points with depth / within 5 % of them).
  Acceptance: :data:`MAX_ZNCC_ERR` and the limits next to it.

The machine is shared: the 1-minute load average is printed; compare ratios, not seconds.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _sweep_kernel_baseline as old_kernels
import _sweep_kernel_baseline_606ef63 as round1_kernels
import bench_mvs
import numba
import numpy as np

from ibr_ros.core.depth import mvs

KERNELS: tuple[tuple[str, Callable[..., Any]], ...] = (('old', old_kernels._sweep), ('new', mvs._sweep))
#: Acceptance (the new kernel sums in float32 since issue 15's fourth round, the old one in float64,
#: so a winner-takes-all pick flips where two planes score within float32 noise): the single-source
#: ZNCC at textured reference pixels within MAX_ZNCC_ERR on all but ZNCC_OUTLIERS of those where
#: both score, the validity (-1: nothing scored) differing on <= ZNCC_OUTLIERS of them (the new
#: kernel scores source windows flatter than mvs._MIN_WINDOW_VAR 0); the pixels with depth
#: differing on <= MAX_SET_DIFF of all pixels; each quality number within MAX_QUALITY_DIFF. The
#: share of common depth within REL_TOL (relative) is printed, not judged.
REL_TOL, MAX_SET_DIFF = 1e-3, 0.002
MAX_ZNCC_ERR, ZNCC_OUTLIERS, MAX_QUALITY_DIFF = 1e-3, 0.002, 0.002


def record(args: tuple, kw: dict) -> tuple[list[tuple], mvs.MvsResult]:
    """The ``_sweep`` calls (copied arguments) of ``mvs_depth(*args, **kw)`` on the old kernels."""
    calls: list[tuple] = []

    def rec(*a: Any) -> Any:
        calls.append(tuple(np.copy(x) if isinstance(x, np.ndarray) else x for x in a))
        return old_kernels._sweep(*a)

    with mock.patch.object(mvs, '_sweep', rec):
        res = mvs.mvs_depth(*args, **kw)
    return calls, res


def run_calls(fn: Callable[..., Any], calls: list[tuple]) -> list[Any]:
    with numba.parallel_chunksize(1):  # as mvs._Stack.sweep runs it
        return [fn(*c) for c in calls]


def clock(fn: Callable[[], Any]) -> tuple[float, float, Any]:
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, time.process_time() - c0, out


def kernel_times(
    calls: list[tuple], runs: int, kernels: tuple[tuple[str, Callable[..., Any]], ...] = KERNELS
) -> dict[str, dict[str, tuple[float, float]]]:
    """Per part ('planes', 'refine', 'all') and kernel: median (wall s, CPU s), runs alternating."""
    parts = {
        'planes': [c for c in calls if c[8].size > 8],
        'refine': [c for c in calls if c[8].size <= 8],
    }
    t: dict[str, dict[str, list[tuple[float, float]]]] = {p: {k: [] for k, _ in kernels} for p in parts}
    for _, fn in kernels:
        run_calls(fn, calls[:1])  # compiled / loaded
    for i in range(runs):
        order = kernels if i % 2 == 0 else kernels[::-1]
        for p, cs in parts.items():
            for k, fn in order:
                w, c, _ = clock(lambda fn=fn, cs=cs: run_calls(fn, cs))
                t[p][k].append((w, c))
    out = {
        p: {
            k: (float(np.median([w for w, _ in v])), float(np.median([c for _, c in v])))
            for k, v in d.items()
        }
        for p, d in t.items()
    }
    out['all'] = {
        k: (out['planes'][k][0] + out['refine'][k][0], out['planes'][k][1] + out['refine'][k][1])
        for k, _ in kernels
    }
    return out


def zncc_check(calls: list[tuple]) -> tuple[float, float, float]:
    """(|ZNCC new - old| exceeded by ZNCC_OUTLIERS of the pixels where both score, the share of those
    beyond MAX_ZNCC_ERR, the share of pixels whose validity differs) over single sources at 6
    hypotheses of the plane sweep and the first full-resolution call, at the reference pixels
    textured enough for a depth (``min_std``)."""
    diffs: list[np.ndarray] = []
    n_valid = n_all = 0
    picks = [c for c in calls if c[8].size > 8][:1] + [c for c in calls if c[8].size <= 8][:1]
    for c in picks:
        ref, mr, vr, srcs, sizes, a, b, base, offsets, r, _, strip, _, sep = c
        for h in np.unique(np.linspace(0, offsets.size - 1, 6).round().astype(int)):
            for i in range(srcs.shape[0]):
                bh = base[h : h + 1] if base.ndim == 3 and base.shape[0] > 1 else base  # its own base map
                sc = [
                    fn(ref, mr, vr, srcs[i : i + 1], sizes[i : i + 1], a[i : i + 1], b[i : i + 1], bh,
                       offsets[h : h + 1], r, 1, strip, False, sep)[1]
                    for _, fn in KERNELS
                ]  # fmt: skip
                textured = vr >= mvs.MvsOptions().min_std ** 2  # the others get no depth (min_std)
                both = (sc[0] > -1) & (sc[1] > -1) & textured
                n_valid += int(((sc[0] > -1) != (sc[1] > -1))[textured].sum())
                n_all += int(textured.sum())
                diffs.append(np.abs(sc[0][both] - sc[1][both]))
    d = np.concatenate(diffs)
    return float(np.quantile(d, 1 - ZNCC_OUTLIERS)), float((d > MAX_ZNCC_ERR).mean()), n_valid / n_all


def compare(d_old: np.ndarray, d_new: np.ndarray) -> tuple[float, float]:
    """(share of pixels with depth in both equal within REL_TOL, share of pixels with depth in one)."""
    both = (d_old > 0) & (d_new > 0)
    rel = np.abs(d_new[both] - d_old[both]) / d_old[both]
    close = float((rel <= REL_TOL).mean()) if both.any() else 1.0
    return close, float(((d_old > 0) != (d_new > 0)).mean())


def pipeline(args: tuple, kw: dict, runs: int) -> dict[str, tuple[float, float, mvs.MvsResult]]:
    """Per kernel: (median wall s, median CPU s, result) of ``mvs_depth``, runs alternating."""
    res: dict[str, Any] = {}
    t: dict[str, list[tuple[float, float]]] = {k: [] for k, _ in KERNELS}
    for i in range(runs):
        order = KERNELS if i % 2 == 0 else KERNELS[::-1]
        for k, fn in order:
            with mock.patch.object(mvs, '_sweep', fn):
                w, c, res[k] = clock(lambda: mvs.mvs_depth(*args, **kw))
            t[k].append((w, c))
    return {
        k: (float(np.median([w for w, _ in v])), float(np.median([c for _, c in v])), res[k])
        for k, v in t.items()
    }


def report(
    name: str, args: tuple, kw: dict, runs: int, quality: Callable[[np.ndarray], str], round1: bool
) -> bool:
    """Prints one table row per input; True if the output passes the acceptance checks."""
    calls, _ = record(args, kw)
    kt = kernel_times(
        calls, runs, KERNELS + ((('r1', old_kernels.batched(round1_kernels._sweep)),) if round1 else ())
    )
    zerr, zout, zvalid = zncc_check(calls)
    pt = pipeline(args, kw, runs)
    close, set_diff = compare(pt['old'][2].depth, pt['new'][2].depth)
    q_old, q_new = quality(pt['old'][2].depth), quality(pt['new'][2].depth)
    q_diff = max(
        abs(float(a) - float(b)) for a, b in zip(q_old.split(' / '), q_new.split(' / '), strict=True)
    )
    ok = (
        set_diff <= MAX_SET_DIFF and q_diff <= MAX_QUALITY_DIFF
        and zout <= ZNCC_OUTLIERS and zvalid <= ZNCC_OUTLIERS
    )  # fmt: skip

    def ratio(d: dict[str, tuple[float, float]] | dict[str, tuple[float, float, Any]]) -> str:
        return f'{d["new"][1] / d["old"][1]:.2f} ({d["new"][0] / d["old"][0]:.2f})'

    print(
        f'| {name} | {pt["new"][2].n_planes} | {kt["all"]["old"][1]:.2f} | {kt["all"]["new"][1]:.2f} | '
        f'{ratio(kt["planes"])} | {ratio(kt["refine"])} | {ratio(kt["all"])} | '
        f'{pt["old"][1]:.2f} | {pt["new"][1]:.2f} | {ratio(pt)} | {zerr:.1e} / {zout:.4f} / {zvalid:.4f} | '
        f'{close:.5f} | {set_diff:.5f} | {q_old} | {q_new} | {"ok" if ok else "DIFFERS"} |'
        + (f' {kt["all"]["new"][1] / kt["all"]["r1"][1]:.2f} |' if round1 else ''),
        flush=True,
    )
    return ok


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--runs', type=int, default=3, help='timed runs per kernel (median)')
    p.add_argument(
        '--bag', type=Path, default=Path(__file__).resolve().parents[1] / 'bags' / 'brighton_beach'
    )
    p.add_argument('--cache', type=Path, default=Path('/tmp/ibr_bench_mvs_brighton.pkl'))
    p.add_argument('--views', type=int, default=3, help='real keyframes')
    p.add_argument('--skip-real', action='store_true')
    p.add_argument('--round1', action='store_true', help='also time the kernels before round 1')
    p.add_argument('--sizes', default='1000x750,640x360')
    a = p.parse_args()
    load0 = os.getloadavg()[0]
    print(
        f'threads: numba {numba.get_num_threads()}, cores {os.cpu_count()}; load average (1 min) {load0:.2f}'
    )
    print(
        '| input | planes | old kernel CPU s | new kernel CPU s | planes new/old CPU (wall) '
        '| refine new/old | kernel new/old | old mvs_depth CPU s | new mvs_depth CPU s | mvs_depth new/old '
        f'| ZNCC diff at {1 - ZNCC_OUTLIERS:.1%} / share > {MAX_ZNCC_ERR:g} / validity differs '
        f'| depth within {REL_TOL:g} | depth set differs '
        '| quality old | quality new | check |' + (' kernel new / before round 1 CPU |' if a.round1 else '')
    )
    print('| --- ' * (17 if a.round1 else 16) + '|')
    ok = True
    for size in (tuple(int(v) for v in s.split('x')) for s in a.sizes.split(',')):
        cam, frames, poses, pts = bench_mvs.views(size, 'orbit', 1)
        ref_i = len(frames) // 2
        js = mvs.select_neighbours(ref_i, poses, cam, points_w=pts, max_neighbours=4)
        args = (frames[ref_i].rgb, cam, poses[ref_i], [frames[j].rgb for j in js], cam, poses[js])
        gt = frames[ref_i].depth

        def synth_quality(d: np.ndarray, gt: np.ndarray = gt) -> str:
            return '{:.3f} / {:.3f}'.format(*bench_mvs.accuracy(d, gt))

        name = f'{size[0]}x{size[1]} orbit, {len(js)} nbrs'
        ok &= report(name, args, {'points_w': pts}, a.runs, synth_quality, a.round1)
    if not a.skip_real:
        kfs, points, observed = bench_mvs.real_keyframes(a.bag, a.cache)
        poses = np.stack([k[2] for k in kfs])
        cams = [k[1] for k in kfs]
        picks = [int(i) for i in np.linspace(0, len(kfs) - 1, a.views + 2).round()[1:-1]]
        for i in picks:
            js = mvs.select_neighbours(i, poses, cams, points_w=points, max_neighbours=4)
            if not js:
                continue
            args = (kfs[i][0], cams[i], poses[i], [kfs[j][0] for j in js], [cams[j] for j in js], poses[js])
            u, v, z = cams[i].pixels_of(observed[kfs[i][3]], poses[i])

            def real_quality(d: np.ndarray, u: Any = u, v: Any = v, z: Any = z) -> str:
                has = d[v, u] > 0
                rel = np.abs(d[v, u][has] - z[has]) / z[has]
                return f'{(d > 0).mean():.3f} / {has.mean():.3f} / {(rel < 0.05).mean():.3f}'

            name = f'{a.bag.name} kf {i}, {len(js)} nbrs'
            ok &= report(name, args, {'points_w': points}, a.runs, real_quality, a.round1)
    print(f'load average (1 min) before {load0:.2f}, after {os.getloadavg()[0]:.2f}')
    if not ok:
        print('OUTPUT DIFFERS from the old kernels beyond floating-point noise')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
