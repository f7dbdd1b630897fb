#!/usr/bin/env python3
# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS neighbour choice and the geometrically filtered MVS depth it gives, on synthetic bags.

Every ``--step``-th frame (at most ``--max-views``) of each bag is a view; neighbours are chosen
among those views by :func:`ibr_ros.core.depth.mvs.select_neighbours` with the depth range the
depth_refiner's schedule uses (``tools/far_depth_eval.py``'s ``scheduler_range``; ``--range gt``:
500 ground-truth points per view as the sparse points, as ``ibr eval depth``), and
:func:`~ibr_ros.core.depth.mvs.compute_depth_maps` computes the filtered depth. Per view:

* the picks' sides: the direction of each pick's baseline (its centre minus the reference's)
  in the reference image plane, as an angle (0 = right, 90 = down), and the angle between the
  pick's optical axis and the reference's;
* completeness: the fraction of non-sky ground-truth pixels with filtered MVS depth, over the whole
  view and over its bottom third; accuracy: the fraction of those depths within 5 % of the truth.

``--set NAME=VALUE`` overrides an :class:`~ibr_ros.core.depth.mvs.MvsOptions` field (repeatable).

Example::

    ibr bag synth --seed 5 --trajectory orbit --pitch=-12,-6 --duration 8 --fps 2 --out /tmp/orbit_s5
    .venv/bin/python tools/neighbour_eval.py /tmp/orbit_s5 --set neighbour_spread=0
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'tools'))

from far_depth_eval import scheduler_range  # noqa: E402

from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps, select_neighbours  # noqa: E402
from ibr_ros.jobs.eval_depth import load_views, sparse_points  # noqa: E402
from ibr_ros.jobs.synth_bag import GroundTruthRenderer  # noqa: E402


def options(sets: list[str]) -> MvsOptions:
    types = {f.name: f.type for f in fields(MvsOptions)}
    kw: dict[str, Any] = {}
    for s in sets:
        name, value = s.split('=', 1)
        if name not in types:
            raise SystemExit(f'no MvsOptions field {name}')
        kw[name] = int(value) if 'int' in str(types[name]) else float(value)
    return replace(MvsOptions(), **kw)


def sides(ref: int, picks: list[int], poses: np.ndarray) -> list[tuple[float, float]]:
    """(baseline direction in the reference image, deg; optical axis angle to the reference's, deg)."""
    r = poses[ref]
    out = []
    for j in picks:
        b = (poses[j][:3, 3] - r[:3, 3]) @ r[:3, :3]  # camera frame: x right, y down, z forward
        az = math.degrees(math.atan2(b[1], b[0]))
        ax = math.degrees(math.acos(np.clip(r[:3, 2] @ poses[j][:3, 2], -1, 1)))
        out.append((az, ax))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('bags', nargs='+', type=Path)
    p.add_argument('--step', type=int, default=1)
    p.add_argument('--max-views', type=int, default=16)
    p.add_argument('--range', choices=('schedule', 'gt'), default='schedule')
    p.add_argument('--set', action='append', default=[], help='MvsOptions field=value')
    p.add_argument('--no-mvs', action='store_true', help='neighbours only')
    p.add_argument('--json', type=Path, help='write per-view numbers here')
    a = p.parse_args(argv)
    o = options(a.set)
    report = {}
    for bag in a.bags:
        views = [v for _, v in load_views(bag, a.step, a.max_views)]
        gts = [GroundTruthRenderer(bag).render(v.t_wc, v.camera) for v in views]
        poses = np.stack([v.t_wc for v in views])
        cams = [v.camera for v in views]
        kw: dict = {}
        if a.range == 'gt':
            kw['points_w'] = sparse_points(gts, views, 0)
        else:
            kw['depth_range'] = scheduler_range(views)
        print(f'## {bag.name} ({len(views)} views, {a.range} range, {a.set or "defaults"})', flush=True)
        picks = [select_neighbours(i, poses, cams, **kw, **o.neighbour_options()) for i in range(len(views))]
        for i, js in enumerate(picks):
            s = ', '.join(f'{j}@{az:+.0f}/{ax:.0f}' for j, (az, ax) in zip(js, sides(i, js, poses)))
            print(f'  view {i:2d}: {s}')
        rows: list[dict[str, Any]] = []
        if not a.no_mvs:
            results = compute_depth_maps(views, options=o, **kw)
            for i, (r, f) in enumerate(zip(results, gts)):
                nonsky = np.isfinite(f.depth) & ~f.sky
                h = nonsky.shape[0]
                bottom = np.zeros_like(nonsky)
                bottom[2 * h // 3 :] = True
                d = r.depth
                has = (d > 0) & nonsky
                good = has & (np.abs(d - np.where(nonsky, f.depth, 1)) <= 0.05 * np.where(nonsky, f.depth, 1))
                rows.append(
                    {
                        'view': i,
                        'picks': list(picks[i]),
                        'nonsky': int(nonsky.sum()),
                        'bottom': int((nonsky & bottom).sum()),
                        'has': int(has.sum()),
                        'has_bottom': int((has & bottom).sum()),
                        'good': int(good.sum()),
                    }
                )
                x = rows[-1]
                print(
                    f'  view {i:2d}: complete {x["has"] / max(x["nonsky"], 1):.3f}, '
                    f'bottom third {x["has_bottom"] / max(x["bottom"], 1):.3f}, '
                    f'within 5 % {x["good"] / max(x["has"], 1):.3f}',
                    flush=True,
                )
            tot = {k: sum(x[k] for x in rows) for k in ('nonsky', 'bottom', 'has', 'has_bottom', 'good')}
            per = [x['has'] / max(x['nonsky'], 1) for x in rows]
            per_b = [x['has_bottom'] / max(x['bottom'], 1) for x in rows]
            print(
                f'  TOTAL {bag.name}: complete {tot["has"] / tot["nonsky"]:.3f}, '
                f'bottom third {tot["has_bottom"] / tot["bottom"]:.3f}, '
                f'within 5 % {tot["good"] / max(tot["has"], 1):.3f}; '
                f'worst view complete {min(per):.3f}, bottom {min(per_b):.3f}',
                flush=True,
            )
        report[bag.name] = rows
    if a.json:
        a.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
