# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval depth``: depth refinement against ground truth on a synthetic bag (paper Tables 1 and 2).

Views: every ``step``-th frame of the bag (at most ``max_views``), decoded from its JPEG images with
the bag's exact poses and intrinsics; ground truth is re-rendered exactly from the bag's
``synth.json`` (:class:`ibr_ros.jobs.synth_bag.GroundTruthRenderer`). Synthetic bags have no SfM
model, so 500 ground-truth points per view stand in for the sparse SfM points that set the MVS
sweep range and the neighbour probes. MVS is the CPU backend of :mod:`ibr_ros.core.depth.mvs`.

Metrics (sky = ground-truth sky, excluded everywhere; "holes" = non-sky pixels without pruned MVS):

* Table 1 analogue, Abs Rel = mean |d - ref| / ref of the remapped monocular depth with the LUT,
  median-factor and linear remaps, on pixels where the monocular backend predicts (G > 0):
  ``vs_mvs`` (remapped with MVS, error against MVS on MVS pixels),
  ``mvs_ref_vs_gt`` (remapped with MVS, error against GT on all non-sky pixels) and ``gt_ref_vs_gt``
  (remapped with GT itself, error against GT).
* Table 2 analogue over the holes and over all non-sky pixels: RMSE (m), MAE (m) and PBRE-0.05/
  0.07/0.10 (% of pixels with absolute relative error above the threshold) for raw MVS (holes count
  as depth 0), FMM (``cv2.inpaint`` Telea of the MVS depth), ours with alpha = 0 and ours.
* Sky IoU of the sky mask before erosion against the ground-truth sky.

Writes ``depth_eval.md``, ``depth_eval.json`` and ``view_NNN.png`` (input, MVS, G, remapped,
fused, final, ground truth) into the output folder.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.core.depth.colour import colour_depth as colour_inverse_depth
from ibr_ros.core.depth.fusion import fuse_depth
from ibr_ros.core.depth.mvs import MvsOptions, MvsView, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefinerConfig
from ibr_ros.core.depth.remap import linear_remap, lut_remap, median_factor_remap
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.synth_bag import TOPICS, GroundTruthRenderer

__all__ = [
    'DepthEvalOptions',
    'depth_metrics',
    'evaluate_depth',
    'load_views',
    'sparse_points',
    'write_atomic',
]

LOG = logging.getLogger(__name__)

REMAPS = {'lut': lut_remap, 'median_factor': median_factor_remap, 'linear': linear_remap}
METHODS = ('mvs', 'fmm', 'ours_alpha0', 'ours')
PBRE = (0.05, 0.07, 0.10)


@dataclass(frozen=True)
class DepthEvalOptions:
    """Which views to evaluate and how to refine them."""

    step: int = 10
    max_views: int = 20
    first: int = 0
    refiner: RefinerConfig = field(default_factory=RefinerConfig)
    mvs: MvsOptions = field(default_factory=MvsOptions)
    seed: int = 0
    png: bool = True


def depth_metrics(
    pred: NDArray[np.floating], gt: NDArray[np.floating], mask: NDArray[np.bool_]
) -> dict[str, float]:
    """RMSE and MAE (m), Abs Rel and PBRE-t (percent) of ``pred`` against ``gt`` on ``mask``."""
    p = np.asarray(pred, np.float64)[mask]
    g = np.asarray(gt, np.float64)[mask]
    if g.size == 0:
        return {'n': 0}
    p = np.where(np.isfinite(p), p, 0.0)
    err = p - g
    rel = np.abs(err) / g
    out = {
        'n': int(g.size),
        'rmse': float(np.sqrt(np.mean(err**2))),
        'mae': float(np.mean(np.abs(err))),
        'abs_rel': float(np.mean(rel)),
    }
    for t in PBRE:
        out[f'pbre_{t:.2f}'] = float(100.0 * np.mean(rel > t))
    return out


def _abs_rel(pred: NDArray, ref: NDArray, mask: NDArray) -> float:
    return (
        float(np.mean(np.abs(pred[mask].astype(np.float64) - ref[mask]) / ref[mask]))
        if mask.any()
        else float('nan')
    )


def load_views(bag: Path, step: int, max_views: int, first: int = 0) -> list[tuple[int, MvsView]]:
    """``(frame index, view)`` of every ``step``-th image from ``first`` on (at most ``max_views``).

    Views carry the bag's decoded image, exact pose and pinhole intrinsics. Raises UserError for a
    bag without the topics of `ibr bag synth` or with fewer than 2 selected views.
    """
    with open_bag(bag) as reader:
        for t in (TOPICS['image'], TOPICS['pose'], TOPICS['camera_info']):
            if t not in reader.topics:
                raise UserError(f'{bag}: no {t} topic: `ibr eval` needs a bag made by `ibr bag synth`')
        poses = {
            m.timestamp_ns: msg_utils.pose_stamped_to_matrix(m.msg) for m in reader.messages([TOPICS['pose']])
        }
        infos = {m.timestamp_ns: m.msg for m in reader.messages([TOPICS['camera_info']])}
        views: list[tuple[int, MvsView]] = []
        for i, m in enumerate(reader.messages([TOPICS['image']])):
            if i < first or (i - first) % step or len(views) >= max_views:
                continue
            if m.timestamp_ns not in poses or m.timestamp_ns not in infos:
                raise UserError(f'{bag}: image at {m.timestamp_ns} ns has no pose or camera_info')
            rgb = msg_utils.camera_image_to_rgb(m.msg)
            cam = msg_utils.camera_info_to_pinhole(infos[m.timestamp_ns])
            views.append((i, MvsView(rgb, cam, poses[m.timestamp_ns])))
    if len(views) < 2:
        raise UserError(f'{bag}: {len(views)} view(s) selected; need >= 2 (lower --step)')
    return views


def sparse_points(gts: list, views: list[MvsView], seed: int, per_view: int = 500) -> NDArray[np.float64]:
    """World points (m) standing in for sparse SfM points: ``per_view`` random GT pixels of each view."""
    rng = np.random.default_rng(seed)
    pts = []
    for f, v in zip(gts, views, strict=True):
        ys, xs = np.nonzero(np.isfinite(f.depth))
        pick = rng.choice(len(xs), size=min(per_view, len(xs)), replace=False)
        pc = v.camera.backproject(np.c_[xs[pick], ys[pick]], f.depth[ys[pick], xs[pick]])
        pts.append(pc @ v.t_wc[:3, :3].T + v.t_wc[:3, 3])
    return np.concatenate(pts)


def colour_depth(d: NDArray, vmin: float, vmax: float) -> NDArray[np.uint8]:
    """BGR (for cv2) turbo colouring of inverse depth from ``vmin`` to ``vmax`` (m), black where unknown:
    :func:`ibr_ros.core.depth.colour.colour_depth`."""
    return colour_inverse_depth(d, (vmin, vmax), bgr=True)


def _grid_png(path: Path, rgb: NDArray, maps: dict[str, NDArray], g: NDArray) -> None:
    fin = [m[np.isfinite(m) & (m > 0)] for m in maps.values()]
    vals = np.concatenate([f for f in fin if f.size])
    vmin, vmax = np.percentile(vals, [1, 99]) if vals.size else (1.0, 2.0)
    tiles = [cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)]
    tiles.append(cv2.applyColorMap((g >> 8).astype(np.uint8), cv2.COLORMAP_TURBO))
    tiles += [colour_depth(m, max(vmin, 1e-3), max(vmax, vmin * 1.01)) for m in maps.values()]
    names = ['input', 'mono G', *maps]
    for t, name in zip(tiles, names, strict=True):
        cv2.putText(t, name, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    while len(tiles) % 4:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i : i + 4]) for i in range(0, len(tiles), 4)]
    write_atomic(path, cv2.imencode('.png', np.vstack(rows))[1].tobytes())


def _mean(rows: list[dict[str, float]], key: str) -> float:
    vals = [r[key] for r in rows if key in r and np.isfinite(r[key])]
    return float(np.mean(vals)) if vals else float('nan')


def evaluate_depth(
    bag: Path,
    out: Path,
    options: DepthEvalOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Run the evaluation (see module docstring); returns the JSON summary."""
    o = options or DepthEvalOptions()
    gt_renderer = GroundTruthRenderer(Path(bag))
    picked = load_views(Path(bag), o.step, o.max_views, o.first)
    views = [v for _, v in picked]
    gts = [gt_renderer.render(v.t_wc, v.camera) for v in views]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    points = sparse_points(gts, views, o.seed)
    total = 2 * len(views)
    mvs_results = compute_depth_maps(
        views,
        options=o.mvs,
        points_w=points,
        progress=(lambda d, n: progress(d, total)) if progress else None,
    )
    refiner = DepthRefiner(o.refiner)
    per_view = []
    for k, ((index, view), frame, mres) in enumerate(zip(picked, gts, mvs_results, strict=True)):
        nonsky = np.isfinite(frame.depth) & ~frame.sky
        gt = np.where(nonsky, frame.depth, 0).astype(np.float32)
        row: dict = {'frame': index, 'mvs_reason': mres.reason}
        if not np.any(mres.depth > 0):
            row['skipped'] = f'no MVS depth ({mres.reason or "empty"})'
            per_view.append(row)
            continue
        r = refiner.refine_from_mvs(view, mres.depth)
        pruned = r.mvs_pruned
        hole = nonsky & (pruned == 0)
        mvs_px = nonsky & (pruned > 0)
        row['mvs_completeness'] = float(mvs_px.sum() / max(1, nonsky.sum()))
        row['mvs_accuracy_5pct'] = float(np.mean(np.abs(pruned[mvs_px] - gt[mvs_px]) / gt[mvs_px] < 0.05))
        predicted = r.g > 0  # G = 0: the monocular backend gives no depth there (e.g. above the horizon)
        row['table1'] = {
            name: {
                'vs_mvs': _abs_rel(fn(r.g, pruned), pruned, mvs_px & predicted),
                'mvs_ref_vs_gt': _abs_rel(fn(r.g, pruned), gt, nonsky & predicted),
                'gt_ref_vs_gt': _abs_rel(fn(r.g, gt), gt, nonsky & predicted),
            }
            for name, fn in REMAPS.items()
        }
        fmm = np.asarray(
            cv2.inpaint(pruned, (pruned == 0).astype(np.uint8), 5, cv2.INPAINT_TELEA), np.float32
        )
        alpha0 = fuse_depth(view.rgb, pruned, r.mono_remapped, sigma=o.refiner.sigma, alpha=0.0)
        preds = {'mvs': pruned, 'fmm': fmm, 'ours_alpha0': alpha0, 'ours': r.fused}
        row['table2_holes'] = {m: depth_metrics(p, gt, hole) for m, p in preds.items()}
        row['table2_all'] = {m: depth_metrics(p, gt, nonsky) for m, p in preds.items()}
        sky_gt = frame.sky
        row['sky_iou'] = (
            float((r.sky & sky_gt).sum() / max(1, (r.sky | sky_gt).sum())) if sky_gt.any() else None
        )
        row['flags'] = list(r.flags)
        per_view.append(row)
        if o.png:
            maps = {
                'MVS': mres.depth,
                'pruned': pruned,
                'remapped': r.mono_remapped,
                'fused': r.fused,
                'final': r.depth,
                'ground truth': frame.depth,
            }
            _grid_png(out / f'view_{index:03d}.png', view.rgb, maps, r.g)
        if progress is not None:
            progress(len(views) + k + 1, total)
    summary = _summarise(Path(bag), o, per_view)
    write_atomic(out / 'depth_eval.json', json.dumps(summary, indent=2) + '\n')
    write_atomic(out / 'depth_eval.md', _markdown(summary))
    return summary


def _summarise(bag: Path, o: DepthEvalOptions, per_view: list[dict]) -> dict:
    rows = [r for r in per_view if 'skipped' not in r]
    t1 = {
        name: {
            key: _mean([r['table1'][name] for r in rows], key)
            for key in ('vs_mvs', 'mvs_ref_vs_gt', 'gt_ref_vs_gt')
        }
        for name in REMAPS
    }
    t2 = {}
    for region in ('holes', 'all'):
        t2[region] = {
            m: {
                k: _mean([r[f'table2_{region}'][m] for r in rows], k)
                for k in ('rmse', 'mae', 'abs_rel', *(f'pbre_{t:.2f}' for t in PBRE))
            }
            for m in METHODS
        }
    return {
        'bag': str(bag),
        'views': len(per_view),
        'evaluated': len(rows),
        'options': {'step': o.step, 'max_views': o.max_views, 'first': o.first},
        'mvs_completeness': _mean(rows, 'mvs_completeness'),
        'mvs_accuracy_5pct': _mean(rows, 'mvs_accuracy_5pct'),
        'sky_iou': _mean([r for r in rows if r.get('sky_iou') is not None], 'sky_iou'),
        'table1_abs_rel': t1,
        'table2': t2,
        'per_view': per_view,
    }


def _markdown(s: dict) -> str:
    lines = [
        f'# Depth evaluation: `{s["bag"]}`',
        '',
        f'{s["evaluated"]} of {s["views"]} views evaluated; pruned MVS completeness (non-sky) '
        f'{s["mvs_completeness"]:.3f}, MVS pixels within 5% of GT {s["mvs_accuracy_5pct"]:.3f}, '
        f'sky IoU {s["sky_iou"]:.3f}.',
        '',
        '## Table 1 analogue: Abs Rel of the remapped monocular depth',
        '',
        '| reference / error against | median factor | linear | LUT (ours) |',
        '| --- | --- | --- | --- |',
    ]
    t1 = s['table1_abs_rel']
    for key, label in (('vs_mvs', 'MVS / MVS'), ('mvs_ref_vs_gt', 'MVS / GT'), ('gt_ref_vs_gt', 'GT / GT')):
        lines.append(
            f'| {label} | {t1["median_factor"][key]:.4f} | {t1["linear"][key]:.4f} | {t1["lut"][key]:.4f} |'
        )
    for region, title in (('holes', 'over MVS holes'), ('all', 'over all non-sky pixels')):
        lines += [
            '',
            f'## Table 2 analogue: depth inpainting {title}',
            '',
            '| method | RMSE (m) | MAE (m) | PBRE-0.05 | PBRE-0.07 | PBRE-0.10 |',
            '| --- | --- | --- | --- | --- | --- |',
        ]
        for m in METHODS:
            v = s['table2'][region][m]
            lines.append(
                f'| {m} | {v["rmse"]:.3f} | {v["mae"]:.3f} | {v["pbre_0.05"]:.2f}% | {v["pbre_0.07"]:.2f}% | '
                f'{v["pbre_0.10"]:.2f}% |'
            )
    return '\n'.join(lines) + '\n'
