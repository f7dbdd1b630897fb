# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Previews, and errors against the exact ground truth of a synthetic bag."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ibr_ros.core.geometry.transforms import rotation_angle_deg, similarity_times_pose
from ibr_ros.core.registration.sfm import similarity_from_orientations
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.eval_depth import colour_depth
from ibr_ros.jobs.process.frames import Keyframe
from ibr_ros.jobs.process.options import Progress
from ibr_ros.jobs.process.render import NovelView
from ibr_ros.jobs.process.spill import loaded

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules


def _png(path: Path, bgr: np.ndarray) -> None:
    ok, buf = cv2.imencode('.png', bgr)
    if not ok:
        raise UserError(f'{path}: PNG encoding failed')
    write_atomic(path, buf.tobytes())


def _depth_limits(*depths: np.ndarray) -> tuple[float, float]:
    vals = np.concatenate([d[np.isfinite(d) & (d > 0)] for d in depths])
    if not vals.size:
        return 1.0, 2.0
    lo, hi = np.percentile(vals, (1, 99))
    return float(max(lo, 1e-3)), float(max(hi, lo * 1.01, 1e-3 * 1.01))


def _label(bgr: np.ndarray, text: str) -> np.ndarray:
    out = np.ascontiguousarray(bgr)
    scale = max(0.35, out.shape[1] / 900)
    cv2.putText(
        out,
        text,
        (6, int(18 * scale / 0.6)),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    return out


def _sfm_to_truth(keyframes: list[Keyframe]) -> tuple[np.ndarray, dict[str, float]] | None:
    """SfM mode: the similarity from SfM's frame to the bag's poses (ground truth), None without them.

    Rotation from the camera orientations (well determined even for a near-collinear path, where
    centres alone leave the roll about the path free), then scale and shift from the centres.
    """
    pairs = [(k.t_wc, k.bag_t_wc) for k in keyframes if k.bag_t_wc is not None]
    if len(pairs) < 3 or len(pairs) < len(keyframes):
        LOG.info('SfM mode: the bag has no poses for all keyframes: no ground-truth evaluation')
        return None
    est, ref = (np.array([p[i][:3, 3] for p in pairs]) for i in (0, 1))
    m = similarity_from_orientations(
        est, ref, np.array([e[:3, :3] for e, _ in pairs]), np.array([g[:3, :3] for _, g in pairs])
    )
    if m is None:
        LOG.info('SfM mode: no similarity from the SfM frame to the bag poses: no ground-truth evaluation')
        return None
    scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
    r = m[:3, :3] / scale
    rms = float(np.sqrt(np.mean(np.sum((est @ m[:3, :3].T + m[:3, 3] - ref) ** 2, axis=1))))
    rot = [rotation_angle_deg(r @ e[:3, :3], g[:3, :3]) for e, g in pairs]
    return m, {
        'scale': scale,
        'centre_rms_m': rms,
        'rotation_rms_deg': float(np.sqrt(np.mean(np.square(rot)))),
    }


def evaluate_ground_truth(
    bag: Path,
    keyframes: list[Keyframe],
    views: list[NovelView],
    previews: Path,
    progress: Progress | None,
    sfm: bool = False,
) -> dict[str, object] | None:
    """Previews, and errors against the exact ground truth when ``bag`` is a synthetic bag (in SfM
    mode after a similarity fit of SfM's camera centres to the bag's poses, when it has them).
    """
    from ibr_ros.core.evaluation.rephoto import score
    from ibr_ros.jobs.synth_bag import GroundTruthRenderer

    gt = GroundTruthRenderer(bag) if (bag / 'synth.json').is_file() else None
    align = _sfm_to_truth(keyframes) if gt is not None and sfm else None
    if sfm and align is None:
        gt = None
    scale = align[1]['scale'] if align is not None else 1.0
    total = len(keyframes) + len(views)
    depth_rows, view_rows = [], []
    for i, k in enumerate(keyframes):
        tiles = [_label(cv2.cvtColor(loaded(k.rgb), cv2.COLOR_RGB2BGR), f'keyframe {i}')]
        truth_pose = k.bag_t_wc if align is not None else k.t_wc
        truth = gt.render(truth_pose, k.camera) if gt is not None and truth_pose is not None else None
        depth = loaded(k.depth) * np.float32(scale) if k.depth is not None else None
        maps = [m for m in (depth, truth.depth if truth is not None else None) if m is not None]
        lo, hi = _depth_limits(*maps) if maps else (1.0, 2.0)
        if depth is not None:
            tiles.append(_label(colour_depth(depth, lo, hi), 'refined depth'))
        if truth is not None:
            tiles.append(_label(colour_depth(truth.depth, lo, hi), 'ground truth'))
            if depth is not None:
                d = depth
                ground = np.isfinite(truth.depth) & ~truth.sky
                ok = ground & np.isfinite(d) & (d > 0)
                rel = np.abs(d[ok] - truth.depth[ok]) / truth.depth[ok]
                depth_rows.append({
                    'keyframe': i, 'stamp': k.stamp,
                    'median_abs_rel': float(np.median(rel)) if rel.size else None,
                    'mean_abs_rel': float(np.mean(rel)) if rel.size else None,
                    'coverage': float(ok.mean()),
                    'false_sky': float(np.mean(np.isposinf(d[ground]))) if ground.any() else 0.0,
                })  # fmt: skip
        _png(previews / f'keyframe_{i:03d}.png', np.hstack(tiles))
        if progress is not None:
            progress('previews', i + 1, total)
    for j, v in enumerate(views):
        tiles = []
        if gt is not None:
            cam = v.camera
            if cam is None:  # unanswered: still show what the query looked at
                cam = next(
                    (k.camera for k in reversed(keyframes) if k.depth is not None), keyframes[-1].camera
                )
            truth = gt.render(similarity_times_pose(align[0], v.t_wc) if align is not None else v.t_wc, cam)
            tiles.append(_label(cv2.cvtColor(truth.rgb, cv2.COLOR_RGB2BGR), 'ground truth'))
            if v.rgb is not None:
                s = score(truth.rgb, v.rgb, valid_mask=v.valid, patch=7, shift=2)
                view_rows.append({'view': j, 'stamp': v.stamp, 'auc': s.auc, 'tail': s.tail,
                                  'median': s.median, 'completeness': s.completeness})  # fmt: skip
        if v.rgb is not None:
            label = f'novel view {j}'
            if v.status is not None:
                flag = ', INCOMPLETE' if v.status.result == 'incomplete' else ''
                label += f': {v.status.valid_fraction:.0%} rendered{flag}'
            tiles.append(_label(cv2.cvtColor(v.rgb, cv2.COLOR_RGB2BGR), label))
        if tiles:
            _png(previews / f'novel_view_{j:03d}.png', np.hstack(tiles))
        if progress is not None:
            progress('previews', len(keyframes) + j + 1, total)
    if gt is None:
        return None

    def mean(rows: list[dict], key: str, f: Callable = np.mean) -> float | None:
        vals = [r[key] for r in rows if r[key] is not None]
        return float(f(vals)) if vals else None

    return {
        'depth_median_abs_rel': mean(depth_rows, 'median_abs_rel', np.median),
        'depth_mean_abs_rel': mean(depth_rows, 'mean_abs_rel'),
        'depth_coverage_mean': mean(depth_rows, 'coverage'),
        'depth_false_sky_mean': mean(depth_rows, 'false_sky'),  # ground refined as sky (+inf)
        'rephoto_auc_mean': mean(view_rows, 'auc'),
        'rephoto_tail_mean': mean(view_rows, 'tail'),
        'rephoto_completeness_mean': mean(view_rows, 'completeness'),
        'sfm_alignment': align[1] if align is not None else None,
        'per_keyframe_depth': depth_rows,
        'per_view': view_rows,
    }
