# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval rephoto``: virtual rephotography of held-out views (Liu et al. 2020, IV-B, Table 3, Fig. 11).

Views: every ``step``-th frame of a synthetic bag (at most ``max_views``), loaded as in
:mod:`ibr_ros.jobs.eval_depth`. Holdout ``every-N``: the views at positions ``N - 1, 2N - 1, ...`` of
that selection (the 8th, 16th, ... view for ``every-8th``) are held out one at a time: each is
rendered at its own pose from all the OTHER selected views (leave-one-out) and compared with its
own photo (the decoded JPEG of the bag: the paper's ground truth is the held-out input photo) and,
as a second reference, with the exact re-rendered ground-truth frame.

Depth of the views, computed once and reused by every holdout: MVS (CPU backend) over all selected
views, held-out ones included (their photos take part in their neighbours' MVS, as when one
reconstruction serves every holdout), then :class:`~ibr_ros.core.depth.refine.DepthRefiner`. Sources:

* ``mvs``: pruned MVS depth with its holes (with the image hole filling below: the paper's
  COLMAP_Inpainting);
* ``mvs_fmm``: pruned MVS depth inpainted by FMM (``cv2.inpaint`` Telea, radius 5);
* ``mono``: the LUT-remapped monocular depth with the sky depth of Eq. 14;
* ``fused``: the final refined depth (ours);
* ``gt``: ground-truth depth (``+inf`` sky): the upper bound.

Methods (``renderer@depth``): ``ours`` (this project's renderer: the options' ``render`` settings,
by default :class:`RenderConfig`'s) on every source; ``paper`` (the same with
:meth:`RenderConfig.as_paper`: the paper's renderer exactly), ``ulr`` and ``splat`` (the baselines
of :mod:`ibr_ros.core.evaluation.baselines`) on ``fused`` and ``gt``.

Scores (0..255 colour units, :mod:`ibr_ros.core.evaluation.rephoto`): the holes of every render (pixels no
source covers) are filled by image inpainting (``cv2.inpaint`` Telea, radius 3) before scoring, as
the paper fills COLMAP's holes "for fairness"; ``completeness`` is the rendered fraction and the
``*_unfilled`` numbers score the holes black. Per holdout and method: the AUC (= mean error) for
every ``(patch, shift)`` window (Table 3: 5/7/15 x +-2/+-1/0), and for the main window 7x7 +-2 the
tail (mean of the worst 1 %, the paper's 99-100 % zoom), the median and the same against the
re-rendered frame. Summary: the mean over holdouts (Table 3 sums over datasets: ``auc_sum``).
Curves (Fig. 11a/b): per method the main-window errors of all holdouts pooled and sorted.

Writes ``rephoto_eval.md``, ``rephoto_eval.json``, ``rephoto_curves.png`` and ``holdout_NNN.png``
(photo | ours | ULR | splat, all on fused depth | error map of ours) into the output folder.
"""

from __future__ import annotations

import io
import json
import logging
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.depth.sky import apply_sky_depth
from ibr_ros.core.evaluation import SplatRenderer, UlrRenderer, shiftable_l1
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView
from ibr_ros.errors import UserError
from ibr_ros.jobs.eval_depth import load_views, sparse_points, write_atomic
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

__all__ = [
    'DEPTH_SOURCES',
    'MAIN_WINDOW',
    'METHODS',
    'TABLE3_WINDOWS',
    'Method',
    'RephotoEvalOptions',
    'evaluate_rephoto',
    'holdout_indices',
    'parse_holdout',
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

    ``windows``: ``(patch, shift)`` pairs of the Table 3 analogue (the main window 7x7 +-2 is
    always scored); ``methods``: keys of :data:`METHODS`; ``render``: base renderer settings
    (``paper`` switches the additions off; the baselines use its view selection); ``fill_holes``:
    inpaint render holes before scoring; ``png``: write ``holdout_NNN.png``.
    """

    step: int = 5
    max_views: int = 40
    first: int = 0
    holdout_every: int = 8
    windows: tuple[tuple[int, int], ...] = TABLE3_WINDOWS
    methods: tuple[str, ...] = tuple(m.key for m in METHODS)
    fill_holes: bool = True
    render: RenderConfig = field(default_factory=RenderConfig)
    refiner: RefinerConfig = field(default_factory=RefinerConfig)
    mvs: MvsOptions = field(default_factory=MvsOptions)
    seed: int = 0
    png: bool = True

    def __post_init__(self) -> None:
        if self.step < 1 or self.max_views < 2 or self.first < 0 or self.holdout_every < 1:
            raise UserError(
                f'need step >= 1, max_views >= 2, first >= 0 and holdout every >= 1, got step={self.step}, '
                f'max_views={self.max_views}, first={self.first}, every={self.holdout_every}'
            )
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
    gt_frame: NDArray[np.uint8],
    rgb: NDArray[np.uint8],
    valid: NDArray[np.bool_],
    o: RephotoEvalOptions,
) -> tuple[dict, NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.uint8]]:
    """Scores of one render, its main-window error map, the sorted errors (filled, holes black), the image."""
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
    vs_gt = _curve_stats(shiftable_l1(gt_frame, img, *MAIN_WINDOW))
    row['auc_vs_gt_frame'], row['tail_vs_gt_frame'] = vs_gt[0], vs_gt[1]
    return row, main, curve, raw_curve, img


# ------------------------------------------------------------------------------------ evaluation


def evaluate_rephoto(
    bag: Path,
    out: Path,
    options: RephotoEvalOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Run the evaluation (see module docstring); returns the JSON summary."""
    o = options or RephotoEvalOptions()
    bag, out = Path(bag), Path(out)
    timings: dict[str, float] = {}
    tick = time.perf_counter()
    gt_renderer = GroundTruthRenderer(bag)
    picked = load_views(bag, o.step, o.max_views, o.first)
    views = [v for _, v in picked]
    frames = [i for i, _ in picked]
    hold = holdout_indices(len(views), o.holdout_every)
    if not hold:
        raise UserError(
            f'{bag}: {len(views)} views selected, holding out every {o.holdout_every}th leaves none: '
            'select more views (--step, --max-views) or hold out more often'
        )
    gts = [gt_renderer.render(v.t_wc, v.camera) for v in views]
    out.mkdir(parents=True, exist_ok=True)
    timings['load'] = time.perf_counter() - tick
    total = len(views) + len(hold)
    tick = time.perf_counter()
    depths, notes = _depth_sources(views, gts, o, (lambda d: progress(d, total)) if progress else None)
    timings['depth'] = time.perf_counter() - tick
    methods = [_BY_KEY[k] for k in o.methods]
    pooled: dict[str, list[NDArray[np.float32]]] = {m.key: [] for m in methods}
    pooled_raw: list[NDArray[np.float32]] = []
    per_holdout = []
    timings['render'] = timings['score'] = 0.0
    for n_done, h in enumerate(hold):
        view = views[h]
        row: dict = {'frame': frames[h], 'view': h, 'methods': {}}
        shown: dict[str, tuple[NDArray[np.uint8], NDArray[np.float32] | None]] = {}
        for m in methods:
            sources = [
                SourceView(v.rgb, depths[m.depth][k], v.camera, v.t_wc, name=str(frames[k]))
                for k, v in enumerate(views)
                if k != h
            ]
            tick = time.perf_counter()
            r = m.renderer(sources, o.render).render(view.t_wc, view.camera)
            timings['render'] += time.perf_counter() - tick
            tick = time.perf_counter()
            scores, main, curve, raw_curve, img = _score_render(view.rgb, gts[h].rgb, r.rgb, r.valid, o)
            timings['score'] += time.perf_counter() - tick
            scores['used_frames'] = [int(sources[i].name) for i in r.used_views]
            scores['reason'] = r.reason
            row['methods'][m.key] = scores
            pooled[m.key].append(curve)
            if m.key == 'ours@mvs':
                pooled_raw.append(raw_curve)
            shown[m.key] = (img, main)
        per_holdout.append(row)
        if o.png:
            _holdout_png(out / f'holdout_{frames[h]:03d}.png', view.rgb, shown, row['methods'])
        if progress is not None:
            progress(len(views) + n_done + 1, total)
    summary = _summarise(bag, o, frames, hold, notes, per_holdout, methods)
    curves = {k: np.sort(np.concatenate(v)) for k, v in pooled.items()}
    if pooled_raw:
        curves['ours@mvs (holes black)'] = np.sort(np.concatenate(pooled_raw))
    summary['curves'] = {k: _curve_points(e) for k, e in curves.items()}
    summary['timings_s'] = timings
    write_atomic(out / 'rephoto_curves.png', _curves_png(curves, bag))
    write_atomic(out / 'rephoto_eval.json', json.dumps(summary, indent=2) + '\n')
    write_atomic(out / 'rephoto_eval.md', _markdown(summary))
    return summary


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


def _mean(values: list[float]) -> float:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(vals)) if vals else float('nan')


def _summarise(
    bag: Path,
    o: RephotoEvalOptions,
    frames: list[int],
    hold: list[int],
    notes: list[dict],
    per_holdout: list[dict],
    methods: list[Method],
) -> dict:
    table: dict[str, dict] = {}
    scalars: tuple[str, ...] = ('auc_main', 'tail', 'median', 'completeness', 'auc_unfilled', 'tail_unfilled')
    scalars += ('auc_vs_gt_frame', 'tail_vs_gt_frame')
    for m in methods:
        rows = [h['methods'][m.key] for h in per_holdout]
        entry: dict = {'depth': m.depth, 'renderer': m.name}
        entry['auc'] = {
            _window_key(p, s): _mean([r['auc'][_window_key(p, s)] for r in rows]) for p, s in o.windows
        }
        entry['auc_sum'] = {
            _window_key(p, s): float(np.sum([r['auc'][_window_key(p, s)] for r in rows]))
            for p, s in o.windows
        }
        entry.update({k: _mean([r[k] for r in rows]) for k in scalars})
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
        'views': [{'frame': f, **n} for f, n in zip(frames, notes, strict=True)],
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


def _fmt(v: float, digits: int = 3) -> str:
    return f'{v:.{digits}f}' if v is not None and np.isfinite(v) else 'n/a'


def _markdown(s: dict) -> str:
    t = s['methods']
    n = len(s['holdout_frames'])
    windows = [tuple(w) for w in s['options']['windows']]
    lines = [
        f'# Rephotography evaluation: `{s["bag"]}`',
        '',
        f'{len(s["frames"])} views (frames {s["frames"][0]}..{s["frames"][-1]}, every '
        f'{s["options"]["step"]}th); held out every {s["options"]["holdout_every"]}th view: frames '
        f'{", ".join(map(str, s["holdout_frames"]))}, each rendered from all other views (leave-one-out) '
        'and compared with its photo. Errors: shiftable L1 in 0..255 colour units; render holes '
        + (
            'filled by image inpainting before scoring.'
            if s['options']['fill_holes']
            else 'scored as rendered.'
        ),
        '',
    ]

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

    table3(
        'Table 3 analogue: depth sources (our renderer)',
        [f'ours@{d}' for d in DEPTH_SOURCES],
        [DEPTH_LABELS[d] for d in DEPTH_SOURCES],
    )
    rkeys = [f'{r}@{d}' for d in ('fused', 'gt') for r in ('ours', 'paper', 'ulr', 'splat')]
    table3('Renderers on fused and on GT depth', rkeys, rkeys)
    lines += [
        '## Main window 7x7 +-2 (mean over holdouts)',
        '',
        '| method | AUC | tail 99-100 % | median | completeness | AUC holes black | tail holes black | '
        'AUC vs GT frame | tail vs GT frame |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for k, v in t.items():
        lines.append(
            f'| {k} | {_fmt(v["auc_main"])} | {_fmt(v["tail"], 2)} | {_fmt(v["median"])} | '
            f'{_fmt(v["completeness"], 4)} | {_fmt(v["auc_unfilled"])} | {_fmt(v["tail_unfilled"], 2)} | '
            f'{_fmt(v["auc_vs_gt_frame"])} | {_fmt(v["tail_vs_gt_frame"], 2)} |'
        )
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
