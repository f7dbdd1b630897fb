# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval rephoto``: virtual rephotography of held-out views (Liu et al. 2020, IV-B, Table 3, Fig. 11).

Holdout ``every-N``: the views at positions ``N - 1, 2N - 1, ...`` of the selection (the 8th, 16th,
... view for ``every-8th``) are held out; each is rendered at its own pose from the other views and
compared with its own photo (the decoded JPEG of the bag: the paper's ground truth is the held-out
input photo). Two ways to choose the views (``views_from``; ``auto``: frames for a bag with
``synth.json``, keyframes for any other):

Keyframes (any bag, real captures): the keyframes ``ibr process`` chooses with the same node
parameters (``config/*.yaml`` + ``params``; :func:`ibr_ros.jobs.process.frames.subsample`), registered
by SfM when the bag has no poses (:func:`ibr_ros.jobs.process.sfm.register_keyframes`, GPS -> ENU
with a NavSatFix topic: all keyframes together, so SfM sees the held-out photos; the summary says
so), else with the bag's poses. The kept keyframes alone go to
:func:`ibr_ros.jobs.process.refine.refine_all` (MVS + refinement with the depth_refiner's schedule):
a held-out keyframe is nobody's MVS neighbour and not in the render set. Every held-out photo is
rendered once per method from the refined kept keyframes (``fused`` depth; ``gt`` too for a
synthetic bag with its poses), with the view_renderer's render settings, and scored against itself
(undistorted with SfM's camera in SfM mode, as the sources are).

Frames (a synthetic bag): every ``step``-th frame (at most ``max_views``), loaded as in
:mod:`ibr_ros.jobs.eval_depth`, leave-one-out: each held-out view is rendered from all the OTHER
selected views, and also compared with the exact re-rendered ground-truth frame.

Depth of the frames, computed once and reused by every holdout: MVS (CPU backend) over all selected
views, held-out ones included (their photos take part in their neighbours' MVS, as when one
reconstruction serves every holdout), then :class:`~ibr_ros.core.depth.refine.DepthRefiner`. Sources:

* ``mvs``: pruned MVS depth with its holes (with the image hole filling below: the paper's
  COLMAP_Inpainting);
* ``mvs_fmm``: pruned MVS depth inpainted by FMM (``cv2.inpaint`` Telea, radius 5);
* ``mono``: the LUT-remapped monocular depth with the sky depth of Eq. 14;
* ``fused``: the final refined depth (ours);
* ``gt``: ground-truth depth (``+inf`` sky): the upper bound.

Methods (``renderer@depth``): ``ours`` (this project's renderer: the options' ``render`` settings,
by default :class:`RenderConfig`'s on frames, the view_renderer's on keyframes) on every source;
``paper`` (the same with :meth:`RenderConfig.as_paper`: the paper's renderer exactly), ``ulr``
and ``splat`` (the baselines of :mod:`ibr_ros.core.evaluation.baselines`) on ``fused`` and ``gt``.
On keyframes only ``fused`` (and ``gt``) exist: the other sources' methods are left out.

Scores (0..255 colour units, :mod:`ibr_ros.core.evaluation.rephoto`): the holes of every render (pixels no
source covers) are filled by image inpainting (``cv2.inpaint`` Telea, radius 3) before scoring, as
the paper fills COLMAP's holes "for fairness"; ``completeness`` is the rendered fraction and the
``*_unfilled`` numbers score the holes black. Per holdout and method: the AUC (= mean error) for
every ``(patch, shift)`` window (Table 3: 5/7/15 x +-2/+-1/0), and for the main window 7x7 +-2 the
tail (mean of the worst 1 %, the paper's 99-100 % zoom), the median, PSNR (dB) and SSIM of the
scored image (:mod:`ibr_ros.core.evaluation.metrics`) and, with ground truth, AUC and tail against
the re-rendered frame. Summary: the mean over holdouts (Table 3 sums over datasets: ``auc_sum``).
Curves (Fig. 11a/b): per method the main-window errors of all holdouts pooled and sorted.

Writes ``rephoto_eval.md``, ``rephoto_eval.json``, ``rephoto_curves.png`` and ``holdout_NNN.png``
(photo | ours | ULR | splat, all on fused depth | error map of ours; ``NNN`` the frame, or the
keyframe's position) into the output folder, each atomically.
"""

from __future__ import annotations

import io
import json
import logging
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.depth.sky import apply_sky_depth
from ibr_ros.core.evaluation import (
    SplatRenderer,
    UlrRenderer,
    depth_vs_points,
    psnr,
    shiftable_l1,
    split_observed,
    ssim,
)
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.eval_depth import load_views, sparse_points
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

if TYPE_CHECKING:
    from ibr_ros.jobs.process.options import Progress

__all__ = [
    'DEFAULT_HOLDOUT',
    'DEPTH_SOURCES',
    'MAIN_WINDOW',
    'METHODS',
    'TABLE3_WINDOWS',
    'Method',
    'RephotoEvalOptions',
    'evaluate_rephoto',
    'holdout_indices',
    'parse_holdout',
    'resolve_views_from',
]

LOG = logging.getLogger(__name__)

TABLE3_WINDOWS: tuple[tuple[int, int], ...] = tuple((p, s) for p in (5, 7, 15) for s in (2, 1, 0))
MAIN_WINDOW = (7, 2)
DEPTH_SOURCES = ('mvs', 'mvs_fmm', 'mono', 'fused', 'gt')
DEPTH_LABELS = {
    'mvs': 'MVS + image inpainting',
    'mvs_fmm': 'MVS + FMM depth',
    'mono': 'mono (remapped)',
    'fused': 'fused (ours)',
    'gt': 'GT depth',
}
ERROR_MAP_MAX = 64.0  # colour units at the top of the error-map colour scale
ViewsFrom = Literal['auto', 'frames', 'keyframes']
#: ``holdout_every`` when not given: every 8th of the frames of a synthetic bag, every 4th keyframe.
DEFAULT_HOLDOUT = {'frames': 8, 'keyframes': 4}

#: Fraction of each keyframe's own SfM points held back from its depth seeds to check its depth.
CHECK_FRACTION = 0.2


@dataclass(frozen=True)
class Method:
    """A renderer on a depth source; ``key`` is ``name@depth``."""

    name: Literal['ours', 'paper', 'ulr', 'splat']
    depth: str

    @property
    def key(self) -> str:
        return f'{self.name}@{self.depth}'

    def renderer(self, views: Sequence[SourceView], base: RenderConfig) -> NovelViewRenderer:
        """This method's renderer of ``views`` with the base settings ``base``."""
        if self.name == 'splat':
            return SplatRenderer(views, base)
        if self.name == 'ulr':
            return UlrRenderer(views, base)
        return NovelViewRenderer(views, base.as_paper() if self.name == 'paper' else base)


METHODS: tuple[Method, ...] = (
    *(Method('ours', d) for d in DEPTH_SOURCES),
    *(Method(r, d) for d in ('fused', 'gt') for r in ('paper', 'ulr', 'splat')),
)
_BY_KEY = {m.key: m for m in METHODS}

# (name, metric, method a, method b): "a < b" is checked and reported.
BARS = (
    ('ours beats ULR in the tail (fused depth)', 'tail', 'ours@fused', 'ulr@fused'),
    ('ours beats splat in the tail (fused depth)', 'tail', 'ours@fused', 'splat@fused'),
    ('fused beats MVS + FMM depth in AUC', 'auc', 'ours@fused', 'ours@mvs_fmm'),
    ('fused beats mono in AUC', 'auc', 'ours@fused', 'ours@mono'),
    ('fused beats MVS + image inpainting in AUC', 'auc', 'ours@fused', 'ours@mvs'),
    ('ours beats ULR in the tail (GT depth)', 'tail', 'ours@gt', 'ulr@gt'),
    ('ours beats splat in the tail (GT depth)', 'tail', 'ours@gt', 'splat@gt'),
    ("ours beats the paper's renderer in the tail (fused depth)", 'tail', 'ours@fused', 'paper@fused'),
)


def parse_holdout(text: str) -> int:
    """``N`` of ``'every-Nth'`` (also ``every-1st``, ``every-2nd``, ``every-3rd``, ``every-N``)."""
    m = re.fullmatch(r'every-(\d+)(st|nd|rd|th)?', str(text).strip().lower())
    if not m or int(m[1]) < 1:
        raise UserError(f"--holdout must look like 'every-8th' (every N-th view, N >= 1), got {text!r}")
    return int(m[1])


def holdout_indices(n_views: int, every: int) -> list[int]:
    """Positions ``every - 1, 2 * every - 1, ...`` below ``n_views`` (the every-th, 2 every-th, ... view)."""
    return list(range(every - 1, n_views, every))


def _window_key(patch: int, shift: int) -> str:
    return f'p{patch}_s{shift}'


@dataclass(frozen=True)
class RephotoEvalOptions:
    """Which views, holdouts, methods and windows to evaluate (see the module docstring).

    ``views_from``: ``frames`` (every ``step``-th frame of a synthetic bag, from ``first``, at most
    ``max_views``), ``keyframes`` (as ``ibr process`` chooses and registers them: ``params``,
    ``max_keyframes``, ``sfm``, ``gps`` as there) or ``auto`` (``frames`` when the bag has a
    ``synth.json``). ``holdout_every``: hold out every N-th view (None: :data:`DEFAULT_HOLDOUT`).
    ``windows``: ``(patch, shift)`` pairs of the Table 3 analogue (the main window 7x7 +-2 is
    always scored); ``methods``: keys of :data:`METHODS` (on keyframes those whose depth exists:
    ``fused``, and ``gt`` on a synthetic bag with its poses); ``render``: base renderer settings
    (``paper`` switches the additions off; the baselines use its view selection; None: the
    defaults on frames, the view_renderer's parameters on keyframes); ``fill_holes``: inpaint render
    holes before scoring; ``png``: write ``holdout_NNN.png``.
    """

    step: int = 5
    max_views: int = 40
    first: int = 0
    holdout_every: int | None = None
    windows: tuple[tuple[int, int], ...] = TABLE3_WINDOWS
    methods: tuple[str, ...] = tuple(m.key for m in METHODS)
    fill_holes: bool = True
    render: RenderConfig | None = None
    refiner: RefinerConfig = field(default_factory=RefinerConfig)
    mvs: MvsOptions = field(default_factory=MvsOptions)
    seed: int = 0
    png: bool = True
    views_from: ViewsFrom = 'auto'
    params: Path | None = None
    max_keyframes: int | None = None
    sfm: bool = False
    gps: bool = True

    def __post_init__(self) -> None:
        every = self.holdout_every
        if self.step < 1 or self.max_views < 2 or self.first < 0 or (every is not None and every < 1):
            raise UserError(
                f'need step >= 1, max_views >= 2, first >= 0 and holdout every >= 1, got step={self.step}, '
                f'max_views={self.max_views}, first={self.first}, every={every}'
            )
        if self.views_from not in ('auto', 'frames', 'keyframes'):
            raise UserError(f"views_from must be 'auto', 'frames' or 'keyframes', got {self.views_from!r}")
        if self.max_keyframes is not None and self.max_keyframes < 2:
            raise UserError(f'max_keyframes (--max-keyframes) must be >= 2, got {self.max_keyframes}')
        unknown = [k for k in self.methods if k not in _BY_KEY]
        if unknown or not self.methods:
            raise UserError(f'unknown or no methods {unknown}; known: {", ".join(_BY_KEY)}')
        for p, s in self.windows:
            if p < 1 or p % 2 == 0 or s < 0:
                raise UserError(f'windows need an odd patch >= 1 and a shift >= 0, got ({p}, {s})')


# ------------------------------------------------------------------------------------ depth maps


def _depth_sources(
    views: list, gts: list, o: RephotoEvalOptions, progress: Callable[[int], None] | None
) -> tuple[dict[str, list[NDArray[np.float32] | None]], list[dict]]:
    """Every depth source of every view (None where refinement failed) and per-view notes."""
    points = sparse_points(gts, views, o.seed)
    mvs = compute_depth_maps(
        views, options=o.mvs, points_w=points, progress=(lambda d, n: progress(d)) if progress else None
    )
    refiner = DepthRefiner(o.refiner)
    out: dict[str, list[NDArray[np.float32] | None]] = {d: [] for d in DEPTH_SOURCES}
    notes = []
    for view, frame, res in zip(views, gts, mvs, strict=True):
        note: dict = {'mvs_reason': res.reason}
        out['gt'].append(np.ascontiguousarray(frame.depth, dtype=np.float32))
        try:
            r = refiner.refine_from_mvs(view, res.depth)
        except RefineError as e:
            LOG.warning('a view has no refined depth (only its ground truth is used): %s', e)
            note['skipped'] = str(e)
            for d in DEPTH_SOURCES[:-1]:
                out[d].append(None)
            notes.append(note)
            continue
        pruned = r.mvs_pruned
        out['mvs'].append(pruned)
        holes = (pruned == 0).astype(np.uint8)
        out['mvs_fmm'].append(np.asarray(cv2.inpaint(pruned, holes, 5, cv2.INPAINT_TELEA), np.float32))
        out['mono'].append(apply_sky_depth(r.mono_remapped, r.sky, pruned)[0])
        out['fused'].append(r.depth)
        note['mvs_completeness'] = r.mvs_completeness
        notes.append(note)
    return out, notes


# --------------------------------------------------------------------------------------- scoring


def _curve_stats(errors: NDArray[np.floating]) -> tuple[float, float, float, NDArray[np.float32]]:
    """AUC (mean), tail (mean of the worst 1 %), median and the sorted finite errors.

    The definitions of :func:`ibr_ros.core.evaluation.rephoto.score` (tested to agree with it).
    """
    e = np.asarray(errors, dtype=np.float32).ravel()
    e = np.sort(e[np.isfinite(e)])
    n_tail = max(1, int(np.ceil(0.01 * e.size)))
    return (
        float(np.mean(e, dtype=np.float64)),
        float(np.mean(e[-n_tail:], dtype=np.float64)),
        float(np.median(e)),
        e,
    )


def _fill(rgb: NDArray[np.uint8], valid: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """Image inpainting (Telea, radius 3) of the pixels that were not rendered."""
    if valid.all() or not valid.any():
        return rgb
    return np.asarray(cv2.inpaint(rgb, (~valid).astype(np.uint8), 3, cv2.INPAINT_TELEA), np.uint8)


def _score_render(
    photo: NDArray[np.uint8],
    gt_frame: NDArray[np.uint8] | None,
    rgb: NDArray[np.uint8],
    valid: NDArray[np.bool_],
    o: RephotoEvalOptions,
) -> tuple[dict, NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.uint8]]:
    """Scores of one render (``gt_frame``: the exact frame of a synthetic bag, if any), its main-window
    error map, the sorted errors (filled, holes black) and the scored image."""
    img = _fill(rgb, valid) if o.fill_holes else rgb
    main = shiftable_l1(photo, img, *MAIN_WINDOW)
    auc, tail, median, curve = _curve_stats(main)
    row: dict = {'auc': {}, 'tail': tail, 'median': median, 'completeness': float(valid.mean())}
    for p, s in o.windows:
        e = main if (p, s) == MAIN_WINDOW else shiftable_l1(photo, img, p, s)
        row['auc'][_window_key(p, s)] = float(np.nanmean(e, dtype=np.float64))
    row['auc_main'] = auc
    if img is rgb:
        raw_curve = curve
        row['auc_unfilled'], row['tail_unfilled'] = auc, tail
    else:
        row['auc_unfilled'], row['tail_unfilled'], _, raw_curve = _curve_stats(
            shiftable_l1(photo, rgb, *MAIN_WINDOW)
        )
    row['psnr'], row['ssim'] = psnr(photo, img), ssim(photo, img)
    if gt_frame is not None:
        vs_gt = _curve_stats(shiftable_l1(gt_frame, img, *MAIN_WINDOW))
        row['auc_vs_gt_frame'], row['tail_vs_gt_frame'] = vs_gt[0], vs_gt[1]
    return row, main, curve, raw_curve, img


# ------------------------------------------------------------------------------------ evaluation


def evaluate_rephoto(
    bag: Path,
    out: Path,
    options: RephotoEvalOptions | None = None,
    progress: Progress | None = None,
) -> dict:
    """Run the evaluation (see module docstring); returns the JSON summary.

    ``progress(stage, done, total)``: stage ``rephoto`` (frames), or ``frames``, ``sfm``,
    ``keyframes`` and ``holdouts`` (keyframes).

    Raises:
        UserError: Unreadable bag, no synth.json with ``views_from`` ``frames``, no holdout left,
            bad parameters, a failed SfM registration.

    """
    o = options or RephotoEvalOptions()
    bag, out = Path(bag), Path(out)
    if resolve_views_from(bag, o.views_from) == 'frames':
        return _evaluate_frames(bag, out, o, progress)
    return _evaluate_keyframes(bag, out, o, progress)


def resolve_views_from(bag: Path, views_from: ViewsFrom) -> Literal['frames', 'keyframes']:
    """``auto``: ``frames`` for a synthetic bag (with ``synth.json``), else ``keyframes``."""
    if views_from == 'auto':
        return 'frames' if (Path(bag) / 'synth.json').is_file() else 'keyframes'
    return views_from


def _render_holdout(
    photo: NDArray[np.uint8],
    gt_rgb: NDArray[np.uint8] | None,
    t_wc: NDArray[np.float64],
    camera: PinholeCamera,
    renderers: dict[str, NovelViewRenderer],
    o: RephotoEvalOptions,
    timings: dict[str, float],
) -> tuple[dict[str, dict], dict[str, tuple[NDArray[np.uint8], NDArray[np.float32]]], dict, NDArray | None]:
    """Every method's render of one held-out view, scored against its photo: per-method scores, the
    (image, error map) shown in the PNG, the sorted errors and the holes-black errors of ``ours@mvs``."""
    scores_by: dict[str, dict] = {}
    shown: dict[str, tuple[NDArray[np.uint8], NDArray[np.float32]]] = {}
    curves: dict[str, NDArray[np.float32]] = {}
    raw: NDArray[np.float32] | None = None
    for key, renderer in renderers.items():
        tick = time.perf_counter()
        r = renderer.render(t_wc, camera)
        timings['render'] += time.perf_counter() - tick
        tick = time.perf_counter()
        scores, main, curve, raw_curve, img = _score_render(photo, gt_rgb, r.rgb, r.valid, o)
        timings['score'] += time.perf_counter() - tick
        scores['used_frames'] = [int(renderer.views[i].name) for i in r.used_views]
        scores['reason'] = r.reason
        scores_by[key], shown[key], curves[key] = scores, (img, main), curve
        if key == 'ours@mvs':
            raw = raw_curve
    return scores_by, shown, curves, raw


def _evaluate_frames(bag: Path, out: Path, o: RephotoEvalOptions, progress: Progress | None) -> dict:
    """Every ``step``-th frame of a synthetic bag, leave-one-out (module docstring: Frames)."""
    timings: dict[str, float] = {}
    tick = time.perf_counter()
    gt_renderer = GroundTruthRenderer(bag)
    picked = load_views(bag, o.step, o.max_views, o.first)
    views = [v for _, v in picked]
    frames = [i for i, _ in picked]
    every = o.holdout_every or DEFAULT_HOLDOUT['frames']
    hold = holdout_indices(len(views), every)
    if not hold:
        raise UserError(
            f'{bag}: {len(views)} views selected, holding out every {every}th leaves none: '
            'select more views (--step, --max-views) or hold out more often'
        )
    gts = [gt_renderer.render(v.t_wc, v.camera) for v in views]
    out.mkdir(parents=True, exist_ok=True)
    timings['load'] = time.perf_counter() - tick
    total = len(views) + len(hold)
    tick = time.perf_counter()
    depths, notes = _depth_sources(
        views, gts, o, (lambda d: progress('rephoto', d, total)) if progress else None
    )
    timings['depth'] = time.perf_counter() - tick
    methods = [_BY_KEY[k] for k in o.methods]
    base = o.render or RenderConfig()
    pooled: dict[str, list[NDArray[np.float32]]] = {m.key: [] for m in methods}
    pooled_raw: list[NDArray[np.float32]] = []
    per_holdout = []
    timings['render'] = timings['score'] = 0.0
    for n_done, h in enumerate(hold):
        view = views[h]
        renderers = {
            m.key: m.renderer(
                [
                    SourceView(v.rgb, depths[m.depth][k], v.camera, v.t_wc, name=str(frames[k]))
                    for k, v in enumerate(views)
                    if k != h
                ],
                base,
            )
            for m in methods
        }
        scores, shown, curves, raw = _render_holdout(
            view.rgb, gts[h].rgb, view.t_wc, view.camera, renderers, o, timings
        )
        row: dict = {'frame': frames[h], 'view': h, 'methods': scores}
        for k, c in curves.items():
            pooled[k].append(c)
        if raw is not None:
            pooled_raw.append(raw)
        per_holdout.append(row)
        if o.png:
            _holdout_png(out / f'holdout_{frames[h]:03d}.png', view.rgb, shown, row['methods'])
        if progress is not None:
            progress('rephoto', len(views) + n_done + 1, total)
    summary = _summarise(bag, o, frames, hold, per_holdout, methods)
    summary['views'] = [{'frame': f, **n} for f, n in zip(frames, notes, strict=True)]
    return _write_outputs(out, bag, summary, pooled, pooled_raw, timings)


def _write_outputs(
    out: Path,
    bag: Path,
    summary: dict,
    pooled: dict[str, list[NDArray[np.float32]]],
    pooled_raw: list[NDArray[np.float32]],
    timings: dict[str, float],
) -> dict:
    """Curves into ``summary``; ``rephoto_curves.png``, ``rephoto_eval.json`` and ``.md`` (atomic)."""
    curves = {k: np.sort(np.concatenate(v)) for k, v in pooled.items() if v}
    if pooled_raw:
        curves['ours@mvs (holes black)'] = np.sort(np.concatenate(pooled_raw))
    summary['curves'] = {k: _curve_points(e) for k, e in curves.items()}
    summary['timings_s'] = timings
    from ibr_ros.jobs.process.output import json_default

    write_atomic(out / 'rephoto_curves.png', _curves_png(curves, bag))
    write_atomic(out / 'rephoto_eval.json', json.dumps(summary, indent=2, default=json_default) + '\n')
    write_atomic(out / 'rephoto_eval.md', _markdown(summary))
    return summary


def _evaluate_keyframes(bag: Path, out: Path, o: RephotoEvalOptions, progress: Progress | None) -> dict:
    """Keyframes as ``ibr process`` chooses and registers them (module docstring: Keyframes)."""
    from ibr_ros.jobs.process import ProcessOptions
    from ibr_ros.jobs.process.frames import subsample
    from ibr_ros.jobs.process.params import load_params, process_configs
    from ibr_ros.jobs.process.refine import refine_all
    from ibr_ros.jobs.process.sfm import register_keyframes

    timings: dict[str, float] = {}
    tick = time.perf_counter()
    popts = ProcessOptions(sfm=o.sfm, gps=o.gps, params=o.params, views=0, max_keyframes=o.max_keyframes)
    params = load_params(o.params)
    cfg = process_configs(params, popts)
    sub = subsample(bag, cfg, popts, progress)
    timings['subsample'] = time.perf_counter() - tick
    tick = time.perf_counter()
    sfm_info: dict[str, object] | None = None
    sparse = None
    keyframes = sub.keyframes
    if sub.sfm_why is not None:
        keyframes, cfg, sfm_info, sparse = register_keyframes(sub, cfg, None, progress)
    timings['sfm'] = time.perf_counter() - tick
    every = o.holdout_every or DEFAULT_HOLDOUT['keyframes']
    hold = holdout_indices(len(keyframes), every)
    if not hold:
        raise UserError(
            f'{bag}: {len(keyframes)} keyframes, holding out every {every}th leaves none: hold out more '
            'often (--holdout) or choose more keyframes (--max-keyframes, --params)'
        )
    held = set(hold)
    kept = [k for i, k in enumerate(keyframes) if i not in held]
    # ground truth of a synthetic bag, where its poses are used (SfM poses are in another frame)
    gt_renderer = GroundTruthRenderer(bag) if sfm_info is None and (bag / 'synth.json').is_file() else None
    out.mkdir(parents=True, exist_ok=True)
    tick = time.perf_counter()
    checks: dict[int, NDArray[np.float64]] = {}
    if sparse is not None:  # a fifth of each keyframe's own SfM points checks its depth, the rest seed it
        seeds, checks = split_observed(sparse.observed, CHECK_FRACTION, o.seed)
        sparse = replace(sparse, observed=seeds)
    refine_info = refine_all(kept, cfg, progress, sparse)  # the held-out keyframes are nobody's neighbour
    timings['refine'] = time.perf_counter() - tick
    position = {k.stamp: i for i, k in enumerate(keyframes)}
    model = [k for k in kept if k.depth is not None]
    if not model:
        raise UserError(f'{bag}: none of the {len(kept)} kept keyframes was refined: nothing to render from')
    depths: dict[str, list[NDArray[np.float32]]] = {'fused': [np.asarray(k.depth, np.float32) for k in model]}
    gts = {}
    if gt_renderer is not None:
        gts = {i: gt_renderer.render(keyframes[i].t_wc, keyframes[i].camera) for i in hold}
        depths['gt'] = [
            np.ascontiguousarray(gt_renderer.render(k.t_wc, k.camera).depth, np.float32) for k in model
        ]
    methods = [_BY_KEY[k] for k in o.methods if _BY_KEY[k].depth in depths]
    if not methods:
        raise UserError(
            f'none of the methods {list(o.methods)} can be evaluated on keyframes: they need depth '
            f'{sorted({_BY_KEY[k].depth for k in o.methods})}, here only {sorted(depths)}'
        )
    base = o.render or cfg.viewing.render
    tick = time.perf_counter()
    renderers = {
        m.key: m.renderer(
            [
                SourceView(
                    k.rgb,
                    d,
                    k.camera,
                    k.t_wc,
                    name=str(position[k.stamp]),
                    stamp=k.stamp * 1e-9,
                    confidence=k.confidence if m.depth == 'fused' else None,
                )
                for k, d in zip(model, depths[m.depth], strict=True)
            ],
            base,
        )
        for m in methods
    }
    timings['render'], timings['score'] = time.perf_counter() - tick, 0.0
    pooled: dict[str, list[NDArray[np.float32]]] = {m.key: [] for m in methods}
    per_holdout = []
    if progress is not None:
        progress('holdouts', 0, len(hold))
    for n_done, h in enumerate(hold):
        k = keyframes[h]
        gt_rgb = gts[h].rgb if h in gts else None
        scores, shown, curves, _ = _render_holdout(k.rgb, gt_rgb, k.t_wc, k.camera, renderers, o, timings)
        for key, c in curves.items():
            pooled[key].append(c)
        per_holdout.append({'frame': h, 'view': h, 'stamp': k.stamp, 'methods': scores})
        if o.png:
            _holdout_png(out / f'holdout_{h:03d}.png', k.rgb, shown, scores)
        if progress is not None:
            progress('holdouts', n_done + 1, len(hold))
    frames = list(range(len(keyframes)))
    summary = _summarise(bag, o, frames, hold, per_holdout, methods)
    summary['options'].update(
        {
            'holdout_every': every,
            'params': None if o.params is None else str(o.params),
            'max_keyframes': o.max_keyframes,
            'sfm': o.sfm,
            'gps': o.gps,
            'render': 'view_renderer parameters' if o.render is None else 'given',
        }
    )
    for key in ('step', 'max_views', 'first'):
        summary['options'].pop(key)
    summary['stamps'] = [k.stamp for k in keyframes]
    summary['holdout_stamps'] = [keyframes[h].stamp for h in hold]
    summary['keyframe_selection'] = sub.selection
    summary['bag_frames'] = {
        'images': sub.counts['image'],
        'complete': sub.counts['frames'],
        'decisions': dict(sorted(sub.decisions.items())),
        'stopped_at_max_keyframes': sub.stopped,
    }
    summary['registration'] = _registration(sub.sfm_why, sfm_info, len(sub.keyframes))
    summary['refine'] = refine_info
    not_refined = cast(dict[str, str], refine_info['not_refined'])
    summary['views'] = []
    for i, k in enumerate(keyframes):
        note: dict[str, object] = {'frame': i, 'stamp': k.stamp, 'reason': k.reason, 'held_out': i in held}
        note.update({'refined': k.depth is not None, 'neighbours': [int(s) for s in k.neighbours]})
        if str(k.stamp) in not_refined:
            note['skipped'] = not_refined[str(k.stamp)]
        summary['views'].append(note)
    unusable: dict[str, dict[str, str]] = {}
    for key, r in renderers.items():
        why = {r.views[i].name: r.skip_reason(i) for i in range(len(r.views))}
        unusable[key] = {name: w for name, w in why.items() if w is not None}
    summary['render'] = {'sources': len(model), 'unusable': unusable}
    if checks:
        summary['depth_vs_sparse'] = {
            str(position[k.stamp]): depth_vs_points(d, k.confidence, k.camera, k.t_wc, checks[k.stamp])
            for k, d in zip(model, depths['fused'], strict=True)
            if k.stamp in checks
        }
    return _write_outputs(out, bag, summary, pooled, [], timings)


def _registration(sfm_why: str | None, sfm: dict[str, object] | None, n: int) -> dict[str, object]:
    """Where the poses come from and whether SfM saw the held-out photos, for the summary."""
    if sfm is None:
        return {
            'poses': 'bag',
            'sfm_saw_holdouts': False,
            'note': "the bag's poses: no SfM; the held-out photos took part in nothing but their own scoring",
        }
    return {
        'poses': 'sfm',
        'sfm_saw_holdouts': True,
        'note': (
            f'SfM ({sfm_why}) registered all {n} keyframes together, the held-out ones included: SfM '
            'saw every held-out photo (that is what gives it a pose); it took no part in any other '
            "keyframe's MVS nor in the render set"
        ),
        'sfm': sfm,
    }


def _curve_points(e: NDArray[np.float32]) -> dict[str, list[float]]:
    """The pooled error curve at 0, 1, ..., 100 % and at 99.00, 99.05, ..., 100 %."""
    if e.size == 0:
        return {'percent': [], 'error': [], 'tail_percent': [], 'tail_error': []}
    pct = np.arange(101, dtype=np.float64)
    tail_pct = np.round(np.linspace(99.0, 100.0, 21), 2)

    def at(p: NDArray) -> list[float]:
        idx = np.clip(np.ceil(p / 100.0 * e.size).astype(int) - 1, 0, e.size - 1)
        return [round(float(x), 3) for x in e[idx]]

    return {
        'percent': pct.tolist(),
        'error': at(pct),
        'tail_percent': tail_pct.tolist(),
        'tail_error': at(tail_pct),
    }


def _mean(values: list[float | None]) -> float:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(vals)) if vals else float('nan')


def _summarise(
    bag: Path,
    o: RephotoEvalOptions,
    frames: list[int],
    hold: list[int],
    per_holdout: list[dict],
    methods: list[Method],
) -> dict:
    table: dict[str, dict] = {}
    scalars: tuple[str, ...] = ('auc_main', 'tail', 'median', 'completeness', 'auc_unfilled', 'tail_unfilled')
    scalars += ('psnr', 'ssim', 'auc_vs_gt_frame', 'tail_vs_gt_frame')
    for m in methods:
        rows = [h['methods'][m.key] for h in per_holdout]
        present = [k for k in scalars if any(k in r for r in rows)]
        entry: dict = {'depth': m.depth, 'renderer': m.name}
        entry['auc'] = {
            _window_key(p, s): _mean([r['auc'][_window_key(p, s)] for r in rows]) for p, s in o.windows
        }
        entry['auc_sum'] = {
            _window_key(p, s): float(np.sum([r['auc'][_window_key(p, s)] for r in rows]))
            for p, s in o.windows
        }
        entry.update({k: _mean([r.get(k) for r in rows]) for k in present})
        entry['failed_renders'] = sum(r['reason'] is not None for r in rows)
        table[m.key] = entry
    bars = []
    for name, metric, a, b in BARS:
        if a in table and b in table:
            col = 'auc_main' if metric == 'auc' else 'tail'
            va, vb = table[a][col], table[b][col]
            bars.append({'name': name, 'metric': metric, 'a': a, 'b': b, 'a_value': va, 'b_value': vb})
            bars[-1]['holds'] = bool(va < vb)
    return {
        'bag': str(bag),
        'views_from': resolve_views_from(bag, o.views_from),
        'options': {
            'step': o.step,
            'max_views': o.max_views,
            'first': o.first,
            'holdout_every': o.holdout_every,
            'fill_holes': o.fill_holes,
            'main_window': list(MAIN_WINDOW),
            'windows': [list(w) for w in o.windows],
        },
        'frames': frames,
        'holdout_frames': [frames[h] for h in hold],
        'methods': table,
        'bars': bars,
        'per_holdout': per_holdout,
    }


# ---------------------------------------------------------------------------------------- output


def _label(img: NDArray[np.uint8], *lines: str) -> NDArray[np.uint8]:
    img = np.ascontiguousarray(img)
    for i, text in enumerate(lines):
        for colour, thick in (((0, 0, 0), 4), ((255, 255, 255), 1)):
            org = (8, 22 + 22 * i)
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, thick, cv2.LINE_AA)
    return img


def _error_map(e: NDArray[np.float32]) -> NDArray[np.uint8]:
    """BGR inferno map of shiftable-L1 errors, 0..ERROR_MAP_MAX colour units; NaN (border) black."""
    ok = np.isfinite(e)
    v = np.clip(np.where(ok, e, 0) * (255.0 / ERROR_MAP_MAX), 0, 255).astype(np.uint8)
    img = np.asarray(cv2.applyColorMap(v, cv2.COLORMAP_INFERNO), np.uint8)
    img[~ok] = 0
    return img


def _holdout_png(path: Path, photo: NDArray[np.uint8], shown: dict, scores: dict) -> None:
    """photo | ours | ULR | splat (fused depth) | error map of ours, labelled with AUC / tail."""
    tiles = [_label(np.asarray(cv2.cvtColor(photo, cv2.COLOR_RGB2BGR), np.uint8), 'held-out photo')]
    for key, name in (('ours@fused', 'ours'), ('ulr@fused', 'ULR'), ('splat@fused', 'splat')):
        if key in shown:
            s = scores[key]
            text = f'AUC {s["auc_main"]:.2f}, tail {s["tail"]:.1f}'
            tiles.append(_label(cv2.cvtColor(shown[key][0], cv2.COLOR_RGB2BGR), f'{name}, fused depth', text))
        else:
            tiles.append(_label(np.zeros_like(tiles[0]), f'{name}: not evaluated'))
    if 'ours@fused' in shown:
        tiles.append(
            _label(
                _error_map(shown['ours@fused'][1]),
                'ours: error 7x7 +-2',
                f'colour scale 0..{ERROR_MAP_MAX:.0f}',
            )
        )
    else:
        tiles.append(_label(np.zeros_like(tiles[0]), 'error map: not evaluated'))
    write_atomic(path, cv2.imencode('.png', np.hstack(tiles))[1].tobytes())


_STYLE = {
    'ours@mvs': ('tab:gray', '-'),
    'ours@mvs (holes black)': ('tab:gray', ':'),
    'ours@mvs_fmm': ('tab:orange', '-'),
    'ours@mono': ('tab:green', '-'),
    'ours@fused': ('tab:red', '-'),
    'ours@gt': ('black', '-'),
    'paper@fused': ('tab:purple', '--'),
    'ulr@fused': ('tab:blue', '--'),
    'splat@fused': ('tab:brown', '--'),
    'paper@gt': ('tab:purple', ':'),
    'ulr@gt': ('tab:blue', ':'),
    'splat@gt': ('tab:brown', ':'),
}


def _curves_png(curves: dict[str, NDArray[np.float32]], bag: Path) -> bytes:
    """Fig. 11a/b analogue: sorted per-pixel error against the percentage of pixels, and its 99-100 %."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 5.5), dpi=100)
    FigureCanvasAgg(fig)
    ax_all, ax_tail = fig.subplots(1, 2)
    for key, e in curves.items():
        if e.size == 0:
            continue
        colour, ls = _STYLE.get(key, (None, '-'))
        pct = 100.0 * np.arange(1, e.size + 1) / e.size
        step = max(1, e.size // 2000)
        width = 2.2 if key == 'ours@fused' else 1.3
        ax_all.plot(pct[::step], e[::step], color=colour, ls=ls, lw=width, label=key)
        first = int(np.searchsorted(pct, 99.0))
        tstep = max(1, (e.size - first) // 2000)
        ax_tail.plot(pct[first::tstep], e[first::tstep], color=colour, ls=ls, lw=width, label=key)
    at99 = [e[int(0.99 * (e.size - 1))] for e in curves.values() if e.size]
    if at99:
        ax_all.set_ylim(0, 1.15 * max(at99))
    ax_all.set(xlim=(0, 100), xlabel='pixels (%)', ylabel='shiftable L1 error 7x7 +-2 (0..255)')
    ax_all.set_title(f'(a) rephotography error curves, {bag.name}')
    ax_tail.set(xlim=(99, 100), xlabel='pixels (%)', ylabel='shiftable L1 error 7x7 +-2 (0..255)')
    ax_tail.set_title('(b) high-error part: 99-100 %')
    for ax in (ax_all, ax_tail):
        ax.grid(True, alpha=0.3)
    ax_tail.legend(fontsize=8, loc='upper left')
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format='png')
    return buf.getvalue()


def _fmt(v: float | None, digits: int = 3) -> str:
    return f'{v:.{digits}f}' if v is not None and np.isfinite(v) else 'n/a'


def _markdown(s: dict) -> str:
    t = s['methods']
    n = len(s['holdout_frames'])
    windows = [tuple(w) for w in s['options']['windows']]
    holes = (
        'render holes filled by image inpainting before scoring'
        if s['options']['fill_holes']
        else 'render holes scored as rendered'
    )
    lines = [f'# Rephotography evaluation: `{s["bag"]}`', '']
    if s.get('views_from') == 'keyframes':
        lines += _keyframes_intro(s, holes)
    else:
        lines += [
            f'{len(s["frames"])} views (frames {s["frames"][0]}..{s["frames"][-1]}, every '
            f'{s["options"]["step"]}th); held out every {s["options"]["holdout_every"]}th view: frames '
            f'{", ".join(map(str, s["holdout_frames"]))}, each rendered from all other views (leave-one-out) '
            f'and compared with its photo. Errors: shiftable L1 in 0..255 colour units; {holes}.',
            '',
        ]
    gt_frame = any('auc_vs_gt_frame' in v for v in t.values())
    head = '| method | AUC | worst 1 % | PSNR (dB) | SSIM | completeness | median | AUC holes black | '
    head += 'worst 1 % holes black |'
    lines += [
        '## Main window 7x7 +-2 (mean over holdouts)',
        '',
        head + (' AUC vs GT frame | worst 1 % vs GT frame |' if gt_frame else ''),
        '| --- ' * (9 + 2 * gt_frame) + '|',
    ]
    for k, v in t.items():
        lines.append(
            f'| {k} | {_fmt(v["auc_main"])} | {_fmt(v["tail"], 2)} | {_fmt(v.get("psnr"), 2)} | '
            f'{_fmt(v.get("ssim"))} | {_fmt(v["completeness"], 4)} | {_fmt(v["median"])} | '
            f'{_fmt(v["auc_unfilled"])} | {_fmt(v["tail_unfilled"], 2)} |'
            + (f' {_fmt(v["auc_vs_gt_frame"])} | {_fmt(v["tail_vs_gt_frame"], 2)} |' if gt_frame else '')
        )
    lines.append('')

    def table3(title: str, keys: list[str], labels: list[str]) -> None:
        keys_here = [k for k in keys if k in t]
        if not keys_here or not windows:
            return
        lines.extend([f'## {title}', '', f'Mean AUC over {n} holdout(s) (the paper sums over datasets).', ''])
        lines.append('| patch | shift | ' + ' | '.join(labels[keys.index(k)] for k in keys_here) + ' |')
        lines.append('| --- | --- |' + ' --- |' * len(keys_here))
        for p, sh in windows:
            w = _window_key(p, sh)
            cells = ' | '.join(_fmt(t[k]['auc'][w]) for k in keys_here)
            lines.append(f'| {p}x{p} | +-{sh} | {cells} |')
        lines.append('')

    sources = [d for d in DEPTH_SOURCES if f'ours@{d}' in t]
    if len(sources) > 1:
        table3(
            'Table 3 analogue: depth sources (our renderer)',
            [f'ours@{d}' for d in DEPTH_SOURCES],
            [DEPTH_LABELS[d] for d in DEPTH_SOURCES],
        )
    rkeys = [f'{r}@{d}' for d in ('fused', 'gt') for r in ('ours', 'paper', 'ulr', 'splat')]
    table3(
        'Table 3 analogue: renderers'
        + (' on fused and on GT depth' if 'ours@gt' in t else ' on fused depth'),
        rkeys,
        rkeys,
    )
    lines += _per_holdout_lines(s)
    if s.get('depth_vs_sparse'):
        lines += _depth_check_lines(s['depth_vs_sparse'])
    if s['bars']:
        lines += ['', '## Quality bars (a < b)', '', '| bar | a | b | holds |', '| --- | --- | --- | --- |']
        for b in s['bars']:
            lines.append(
                f'| {b["name"]} | {b["a"]} {_fmt(b["a_value"])} | {b["b"]} {_fmt(b["b_value"])} | '
                f'{"yes" if b["holds"] else "NO"} |'
            )
    skipped = [v for v in s['views'] if 'skipped' in v]
    if skipped:
        lines += [
            '',
            f'{len(skipped)} view(s) without refined depth: frames {[v["frame"] for v in skipped]}.',
        ]
    return '\n'.join(lines) + '\n'


def _keyframes_intro(s: dict, holes: str) -> list[str]:
    """What was evaluated on keyframes: selection, registration (did SfM see the holdouts), holdouts."""
    from ibr_ros.jobs.process.output import refine_warnings, selection_line

    reg, bf, o = s['registration'], s['bag_frames'], s['options']
    n, hold = len(s['frames']), s['holdout_frames']
    refined = sum(v['refined'] for v in s['views'])
    lines = [
        f'- keyframes: {n}, chosen as `ibr process` does ({selection_line(s["keyframe_selection"])}) from '
        f'{bf["complete"]} frames (decisions {bf["decisions"]})'
        + (f'; stopped at --max-keyframes {o["max_keyframes"]}' if bf['stopped_at_max_keyframes'] else ''),
    ]
    if reg['poses'] == 'sfm':
        sfm = reg['sfm']
        gps = sfm['gps']
        align = 'no GPS alignment'
        if gps is not None and gps['alignment_rms_m'] is not None:
            align = (
                f'GPS alignment RMS {_fmt(gps["alignment_rms_m"], 2)} m over {gps["alignment_inliers"]}/'
                f'{gps["keyframes_with_gps"]} inliers'
            )
        lines.append(
            f'- poses: SfM, {sfm["registered"]}/{sfm["keyframes"]} keyframes registered, frame '
            f'`{sfm["frame_id"]}` (unit {sfm["unit"]}), reprojection error '
            f'{_fmt(sfm["mean_reprojection_error_px"], 2)} px, {align}'
        )
        lines.append(f'- **SfM saw the held-out photos: yes.** {reg["note"]}.')
    else:
        lines.append("- poses: the bag's; SfM saw the held-out photos: no (no SfM).")
    lines += [
        f'- held out every {o["holdout_every"]}th keyframe: {", ".join(map(str, hold))} (of 0..{n - 1}); '
        f'the other {n - len(hold)} were refined without them (MVS neighbours only among themselves): '
        f'{refined}/{n - len(hold)} refined; each held-out photo rendered at its pose from the '
        f'{s["render"]["sources"]} refined ones and compared with its own photo',
        f'- errors: shiftable L1 in 0..255 colour units, PSNR and SSIM against the photo; {holes}; '
        f'renderer settings: {o["render"]}',
    ]
    warnings = refine_warnings(s['refine'])
    if reg['poses'] == 'sfm':
        warnings += [f'keyframe {st} ns dropped: {why}' for st, why in reg['sfm']['dropped'].items()]
    warnings += [
        f'{key}: source {name} unusable: {why}'
        for key, u in s['render']['unusable'].items()
        for name, why in u.items()
    ]
    if warnings:
        lines += ['- warnings:', *(f'  - {w}' for w in warnings)]
    return [*lines, '']


def _depth_check_lines(rows: dict[str, dict[str, float]]) -> list[str]:
    """Refined depth against the SfM points held back from its seeds, per keyframe."""
    lines = [
        f"## Refined depth against held-back SfM points ({CHECK_FRACTION:.0%} of each keyframe's own)",
        '',
        "confident = confidence >= 0.5; off = more than 20 % from the point's depth; deeper than 2x: "
        'fraction of the image deeper than twice the median point depth (the height above ground of a '
        'nadir view).',
        '',
        '| keyframe | points | confident off (max rel) | filled off | unknown at points | deeper than 2x |',
        '| --- | --- | --- | --- | --- | --- |',
    ]
    for name, r in rows.items():
        if not r.get('confident_points', 0) and not r.get('filled_points', 0):
            lines.append(f'| {name} | {int(r["points"])} | - | - | - | - |')
            continue
        lines.append(
            f'| {name} | {int(r["points"])} | {_fmt(r["confident_off"], 4)} of {int(r["confident_points"])} '
            f'({_fmt(r["max_rel"], 2)}) | {_fmt(r["filled_off"], 3)} of {int(r["filled_points"])} | '
            f'{_fmt(r["unknown_at_points"], 3)} | {_fmt(r["deeper_than_2x"], 4)} |'
        )
    return [*lines, '']


def _per_holdout_lines(s: dict) -> list[str]:
    """Per held-out view: AUC / worst 1 % / PSNR of each method (7x7 +-2)."""
    keys = list(s['methods'])
    lines = [
        '## Per held-out view (7x7 +-2: AUC / worst 1 % / PSNR dB / completeness)',
        '',
        '| view | ' + ' | '.join(keys) + ' |',
        '| --- ' * (1 + len(keys)) + '|',
    ]
    for h in s['per_holdout']:
        cells = []
        for k in keys:
            r = h['methods'][k]
            cell = f'{_fmt(r["auc_main"], 2)} / {_fmt(r["tail"], 1)} / {_fmt(r["psnr"], 1)}'
            cell += f' / {_fmt(r["completeness"], 2)}' + (f' ({r["reason"]})' if r['reason'] else '')
            cells.append(cell)
        lines.append(f'| {h["frame"]} | ' + ' | '.join(cells) + ' |')
    return [*lines, '']
