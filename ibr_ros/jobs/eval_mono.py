# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval mono``: the monocular depth + sky model on held-out synthetic views and real photos.

Synthetic views come from :func:`ibr_ros.jobs.mono_data.render_samples` with scene seeds from
:data:`~ibr_ros.jobs.mono_data.EVAL_SEED_BASE` (never used for training). For each view:

* a sparse reference emulating MVS: ``ref_fraction`` of the non-sky pixels, chosen at random,
  with their ground-truth depth (everything else unknown);
* the model's G (:class:`~ibr_ros.core.depth.mono.OnnxMonoDepth`), remapped with the paper's LUT
  (:func:`~ibr_ros.core.depth.remap.lut_remap`) using that reference;
* baselines remapped the same way: the geometric ground-plane prior
  (:class:`~ibr_ros.core.depth.mono.GroundPlanePrior` fitted to the reference points in the world frame)
  and a constant G (every pixel gets the reference median);
* Abs Rel = mean |d - gt| / gt over all ground-truth non-sky pixels; Spearman rank correlation of
  the prediction's nearness with ground-truth inverse depth over the same pixels; sky IoU of the
  model's sky mask (:class:`~ibr_ros.core.depth.sky.OnnxSkySegmenter`) against the ground-truth sky,
  per view where either has sky, and pooled over all views (sum of intersections / sum of unions).

Real photos (no ground truth; qualitative PNGs of input, G and sky): scikit-image's ``camera`` and
``rocket`` when scikit-image is installed, and the first images of a bag (e.g. brighton_beach).

Real photos with MVS depth (``real_mvs``: an npz of ``tools/real_mvs_data.py``: SfM-registered
photos with geometrically filtered MVS depth): per view with at least ``MIN_REAL_PIXELS`` MVS
pixels, a random half of them is the reference of the LUT remap (and of the ground-plane fit), the
other half is scored: Abs Rel of the model, the ground-plane prior and a constant G.

Writes ``mono_eval.md``, ``mono_eval.json`` and PNGs into the output folder.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mono import PRESETS, GroundPlanePrior, OnnxMonoDepth, nearness_to_g
from ibr_ros.core.depth.remap import lut_remap
from ibr_ros.core.depth.sky import SKY_PRESETS, OnnxSkySegmenter
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.plane import fit_ground_plane
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.mono_data import EVAL_SEED_BASE, MonoSample, render_samples

__all__ = [
    'MonoEvalOptions',
    'evaluate_mono',
    'evaluate_real_mvs',
    'evaluate_sample',
    'remapped_predictions',
    'sparse_reference',
    'spearman',
]

LOG = logging.getLogger(__name__)
METHODS = ('model', 'ground_plane', 'constant')
MIN_REAL_PIXELS = 500


@dataclass(frozen=True)
class MonoEvalOptions:
    """Held-out views (``scenes`` towns x ``views`` each, rendered at ``size`` = (width, height))."""

    scenes: int = 8
    views: int = 4
    size: tuple[int, int] = (384, 224)
    ref_fraction: float = 0.05
    seed: int = 0
    png: bool = True
    photos_bag: Path | None = None
    photos: int = 3
    real_mvs: Path | None = None


def spearman(a: NDArray[np.floating], b: NDArray[np.floating]) -> float:
    """Spearman rank correlation of two equally long 1-D arrays (average ranks for ties)."""

    def ranks(x: NDArray) -> NDArray[np.float64]:
        _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
        ends = np.cumsum(counts).astype(np.float64)
        return (ends - (counts - 1) / 2.0)[inv]

    ra, rb = ranks(np.asarray(a).ravel()), ranks(np.asarray(b).ravel())
    ra -= ra.mean()
    rb -= rb.mean()
    den = float(np.sqrt((ra * ra).sum() * (rb * rb).sum()))
    return float((ra * rb).sum() / den) if den > 0 else float('nan')


def sparse_reference(depth: NDArray[np.float32], fraction: float, seed: int) -> NDArray[np.float32]:
    """``depth`` kept at ``fraction`` of its finite pixels (random, deterministic), 0 elsewhere."""
    ref = np.zeros_like(depth, dtype=np.float32)
    ys, xs = np.nonzero(np.isfinite(depth) & (depth > 0))
    if len(xs) == 0:
        return ref
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(xs), size=max(1, round(fraction * len(xs))), replace=False)
    ref[ys[pick], xs[pick]] = depth[ys[pick], xs[pick]]
    return ref


def _iou(pred: NDArray[np.bool_], gt: NDArray[np.bool_]) -> tuple[int, int]:
    return int((pred & gt).sum()), int((pred | gt).sum())


def remapped_predictions(
    g_model: NDArray[np.uint16], ref: NDArray[np.float32], camera: PinholeCamera, t_wc: NDArray, seed: int
) -> tuple[dict[str, NDArray[np.float32]], GroundPlanePrior]:
    """The model's G, the ground-plane prior (plane fitted to the reference points in the world frame)
    and a constant G, each remapped with the LUT from the sparse reference depth ``ref`` (0 = none)."""
    ys, xs = np.nonzero(ref > 0)
    pts_c = camera.backproject(np.c_[xs, ys], ref[ys, xs])
    prior = GroundPlanePrior(fit_ground_plane(pts_c @ t_wc[:3, :3].T + t_wc[:3, 3], seed=seed))
    preds = {
        'model': lut_remap(g_model, ref),
        'ground_plane': lut_remap(prior.predict_g(camera, t_wc), ref),
        'constant': lut_remap(np.full_like(g_model, 32768), ref),
    }
    return preds, prior


def evaluate_sample(
    s: MonoSample, depth_model: OnnxMonoDepth, sky_model: OnnxSkySegmenter, ref_fraction: float, seed: int
) -> tuple[dict[str, float], dict[str, NDArray]]:
    """Metrics of one synthetic view (see module docstring) and the maps for its PNG."""
    gt = s.depth
    mask = np.isfinite(gt) & (gt > 0)
    ref = sparse_reference(gt, ref_fraction, seed)
    t0 = time.perf_counter()
    near = depth_model.predict_nearness(s.rgb)
    sky = sky_model.predict(s.rgb)
    ms = 1000.0 * (time.perf_counter() - t0)
    g_model = nearness_to_g(near)
    preds, prior = remapped_predictions(g_model, ref, s.camera, s.t_wc, seed)
    row: dict[str, float] = {'seed': s.seed, 'sky_fraction': float(s.sky.mean()), 'ms_model': ms}
    g = gt[mask].astype(np.float64)
    for name, d in preds.items():
        row[f'abs_rel_{name}'] = float(np.mean(np.abs(d[mask] - g) / g))
    row['spearman_model'] = spearman(near[mask], -g)
    with np.errstate(divide='ignore'):
        row['spearman_ground_plane'] = spearman(-prior.depth(s.camera, s.t_wc)[mask], -g)
    inter, union = _iou(sky, s.sky)
    row['sky_inter'], row['sky_union'] = inter, union
    row['sky_iou'] = inter / union if union else float('nan')
    maps = {'g': g_model, 'sky': sky, **preds}
    return row, maps


def evaluate_real_mvs(path: Path, depth_model: OnnxMonoDepth, seed: int = 0) -> list[dict[str, float]]:
    """Abs Rel on held-out MVS pixels of real photos (see the module docstring), one row per view."""
    try:
        with np.load(path) as z:
            rgbs, depths, ks, poses = z['rgb'], z['depth'], z['k'], z['t_wc']
    except (OSError, KeyError, ValueError) as exc:
        raise UserError(f'{path}: not a real-MVS npz of tools/real_mvs_data.py ({exc})') from exc
    rows = []
    for i, (rgb, d, k, t_wc) in enumerate(zip(rgbs, depths, ks, poses, strict=True)):
        ys, xs = np.nonzero(d > 0)
        if len(xs) < MIN_REAL_PIXELS:
            continue
        pick = np.random.default_rng([seed, i]).permutation(len(xs))
        ref_i, test_i = pick[: len(xs) // 2], pick[len(xs) // 2 :]
        ref = np.zeros_like(d, dtype=np.float32)
        ref[ys[ref_i], xs[ref_i]] = d[ys[ref_i], xs[ref_i]]
        camera = PinholeCamera(d.shape[1], d.shape[0], k)
        preds, _ = remapped_predictions(depth_model.predict_g(rgb), ref, camera, t_wc, seed)
        gt = d[ys[test_i], xs[test_i]].astype(np.float64)
        row: dict[str, float] = {'view': i, 'mvs_pixels': len(xs)}
        for name, pred in preds.items():
            row[f'abs_rel_{name}'] = float(np.mean(np.abs(pred[ys[test_i], xs[test_i]] - gt) / gt))
        rows.append(row)
    return rows


def _turbo(x: NDArray, valid: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """BGR turbo colouring of ``x`` (larger = warmer) from its 1st to 99th percentile; black = invalid."""
    img = np.zeros((*x.shape, 3), np.uint8)
    if valid.any():
        lo, hi = np.percentile(x[valid], [1, 99])
        u = np.clip((x - lo) / max(hi - lo, 1e-12) * 255, 0, 255).astype(np.uint8)
        img = cv2.applyColorMap(u, cv2.COLORMAP_TURBO)
        img[~valid] = 0
    return img


def _bgr(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return cast('NDArray[np.uint8]', cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))  # cv2's stubs give no dtypes


def _label(tiles: list[NDArray[np.uint8]], names: list[str]) -> NDArray[np.uint8]:
    for t, name in zip(tiles, names, strict=True):
        cv2.putText(t, name, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return np.hstack(tiles)


def _sample_png(path: Path, s: MonoSample, maps: dict[str, NDArray]) -> None:
    mask = np.isfinite(s.depth)
    inv = lambda d: np.where(d > 0, 1.0 / np.maximum(d, 1e-6), 0.0)  # noqa: E731
    sky = _bgr(s.rgb)
    sky[maps['sky']] = (0.5 * sky[maps['sky']] + (127, 0, 127)).astype(np.uint8)
    tiles = [
        _bgr(s.rgb),
        _turbo(maps['g'].astype(np.float64), np.ones_like(mask)),
        sky,
        _turbo(inv(s.depth), mask),
        _turbo(inv(maps['model']), mask),
        _turbo(inv(maps['ground_plane']), mask),
    ]
    names = ['input', 'model G', 'model sky', 'GT 1/depth', 'model LUT', 'ground plane LUT']
    write_atomic(path, cv2.imencode('.png', _label(tiles, names))[1].tobytes())


def _photo_png(
    path: Path, rgb: NDArray[np.uint8], depth_model: OnnxMonoDepth, sky_model: OnnxSkySegmenter
) -> None:
    g = depth_model.predict_g(rgb)
    sky = sky_model.predict(rgb)
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    over = bgr.copy()
    over[sky] = (0.5 * over[sky] + (127, 0, 127)).astype(np.uint8)
    tiles = [bgr, _turbo(g.astype(np.float64), np.ones(g.shape, bool)), over]
    write_atomic(path, cv2.imencode('.png', _label(tiles, ['input', 'model G', 'model sky']))[1].tobytes())


def _photos(bag: Path | None, n: int) -> tuple[dict[str, NDArray[np.uint8]], list[str]]:
    """Real photos by name, and notes on the ones that could not be loaded."""
    photos: dict[str, NDArray[np.uint8]] = {}
    notes = []
    try:
        from skimage import data as skdata

        photos['skimage_camera'] = np.repeat(skdata.camera()[..., None], 3, axis=2)
        photos['skimage_rocket'] = np.ascontiguousarray(skdata.rocket())
    except Exception as exc:  # not installed (a test/eval extra) or its data missing
        notes.append(f'scikit-image photos skipped ({exc})')
    if bag is not None:
        import msg_utils
        from ibr_ros.bag import open_bag

        try:
            with open_bag(bag) as reader:
                topics = [t for t in reader.topics if t.endswith('/compressed')]
                if not topics:
                    raise UserError(f'{bag}: no CompressedImage topic')
                for i, m in enumerate(reader.messages(topics[:1])):
                    if i >= n:
                        break
                    photos[f'{bag.name}_{i:02d}'] = msg_utils.camera_image_to_rgb(m.msg)
        except UserError as exc:
            notes.append(f'bag photos skipped ({exc})')
    return photos, notes


def _nanmean(vals: list[float]) -> float:
    finite = [v for v in vals if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float('nan')


def _fmt(x: float) -> str:
    return f'{x:.3f}' if np.isfinite(x) else 'n/a'


def _markdown(s: dict) -> str:
    m = s['mean']
    lines = [
        '# Monocular depth + sky model: held-out evaluation',
        '',
        f'Model: `{s["model"]}`. {s["views"]} synthetic views ({s["options"]["scenes"]} towns never used '
        f'for training, {s["options"]["size"][0]}x{s["options"]["size"][1]} px); reference = '
        f'{100 * s["options"]["ref_fraction"]:.0f}% random GT pixels (emulating MVS), LUT remap (Eq. 1-4).',
        '',
        '| metric | model | ground-plane prior | constant |',
        '| --- | --- | --- | --- |',
        f'| Abs Rel (mean over views, non-sky GT pixels) | {_fmt(m["abs_rel_model"])} | '
        f'{_fmt(m["abs_rel_ground_plane"])} | {_fmt(m["abs_rel_constant"])} |',
        f'| Abs Rel (median over views) | {_fmt(s["median"]["abs_rel_model"])} | '
        f'{_fmt(s["median"]["abs_rel_ground_plane"])} | {_fmt(s["median"]["abs_rel_constant"])} |',
        f'| Spearman vs GT inverse depth (mean) | {_fmt(m["spearman_model"])} | '
        f'{_fmt(m["spearman_ground_plane"])} | - |',
        f'| views where the model beats the prior (Abs Rel) | {s["model_beats_prior"]}/{s["views"]} | | |',
        '',
        f'Sky IoU: pooled {_fmt(s["sky_iou_pooled"])}, mean over views with sky {_fmt(m["sky_iou"])}.',
        '',
        f'Inference time (one thread, depth + sky passes, mean per view): {m["ms_model"]:.0f} ms.',
        '',
        '## Per view',
        '',
        '| view | seed | sky % | Abs Rel model | Abs Rel plane | Abs Rel const | Spearman model | sky IoU |',
        '| --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for i, r in enumerate(s['per_view']):
        lines.append(
            f'| {i} | {r["seed"]} | {100 * r["sky_fraction"]:.0f} | {_fmt(r["abs_rel_model"])} | '
            f'{_fmt(r["abs_rel_ground_plane"])} | {_fmt(r["abs_rel_constant"])} | '
            f'{_fmt(r["spearman_model"])} | {_fmt(r["sky_iou"])} |'
        )
    real = s['real_mvs']
    if real['views']:
        rm = real['mean']
        lines += [
            '',
            '## Real photos with MVS depth',
            '',
            f'`{real["file"]}`: {len(real["views"])} views; per view half of the MVS pixels are the LUT '
            'reference, the other half are scored.',
            '',
            '| metric | model | ground-plane prior | constant |',
            '| --- | --- | --- | --- |',
            f'| Abs Rel (mean over views) | {_fmt(rm["abs_rel_model"])} | '
            f'{_fmt(rm["abs_rel_ground_plane"])} | {_fmt(rm["abs_rel_constant"])} |',
        ]
    if s['photos']:
        lines += ['', '## Real photos (qualitative)', '']
        lines += [f'- `{p}`' for p in s['photos']]
    lines += [f'- {n}' for n in s['notes']]
    return '\n'.join(lines) + '\n'


def evaluate_mono(
    model: Path,
    out: Path,
    options: MonoEvalOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Run the evaluation of ``model`` (an ONNX file in the ``ibr_mono`` convention) into ``out``."""
    o = options or MonoEvalOptions()
    if not Path(model).is_file():
        raise UserError(f'{model}: no such model file')
    if o.scenes < 1 or o.views < 1 or not 0 < o.ref_fraction <= 1:
        raise UserError('need scenes >= 1, views >= 1 and 0 < ref_fraction <= 1')
    out.mkdir(parents=True, exist_ok=True)
    depth_model = OnnxMonoDepth(replace(PRESETS['ibr_mono'], path=Path(model)))
    sky_model = OnnxSkySegmenter(replace(SKY_PRESETS['ibr_mono'], path=Path(model)))
    seeds = [EVAL_SEED_BASE + o.seed * 1000 + i for i in range(o.scenes)]
    samples = render_samples(seeds, o.views, o.size)
    rows = []
    for i, s in enumerate(samples):
        row, maps = evaluate_sample(s, depth_model, sky_model, o.ref_fraction, o.seed * 1000 + i)
        rows.append(row)
        if o.png:
            _sample_png(out / f'view_{i:03d}.png', s, maps)
        if progress is not None:
            progress(i + 1, len(samples))
    keys = [k for k in rows[0] if k not in ('seed', 'sky_inter', 'sky_union')]
    mean = {k: _nanmean([r[k] for r in rows]) for k in keys}
    median = {k: float(np.nanmedian([r[k] for r in rows])) for k in keys if k.startswith('abs_rel')}
    union = sum(r['sky_union'] for r in rows)
    photos, notes = _photos(o.photos_bag, o.photos)
    real = evaluate_real_mvs(o.real_mvs, depth_model, o.seed) if o.real_mvs is not None else []
    if o.real_mvs is not None and not real:
        notes.append(f'{o.real_mvs}: no view has {MIN_REAL_PIXELS} MVS pixels')
    names = []
    for name, rgb in photos.items():
        _photo_png(out / f'photo_{name}.png', rgb, depth_model, sky_model)
        names.append(f'photo_{name}.png')
    summary = {
        'model': str(model),
        'options': {
            **asdict(o),
            'photos_bag': str(o.photos_bag) if o.photos_bag else None,
            'real_mvs': str(o.real_mvs) if o.real_mvs else None,
        },
        'views': len(rows),
        'mean': mean,
        'median': median,
        'sky_iou_pooled': sum(r['sky_inter'] for r in rows) / union if union else float('nan'),
        'model_beats_prior': sum(r['abs_rel_model'] < r['abs_rel_ground_plane'] for r in rows),
        'per_view': rows,
        'real_mvs': {
            'file': str(o.real_mvs) if o.real_mvs else None,
            'views': real,
            'mean': {k: _nanmean([r[k] for r in real]) for k in real[0] if k.startswith('abs_rel')}
            if real
            else {},
        },
        'photos': names,
        'notes': notes,
    }
    write_atomic(out / 'mono_eval.json', json.dumps(summary, indent=2, default=float))
    write_atomic(out / 'mono_eval.md', _markdown(summary))
    return summary
