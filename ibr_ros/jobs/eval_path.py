# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval path``: flicker of continuous navigation on a synthetic bag (Liu et al. 2020's stated
limitation: views jump when the rendering switches between source views).

Source views: every ``step``-th frame of the bag (at most ``max_views``), decoded from its JPEG
images with the bag's exact poses and intrinsics (as :mod:`ibr_ros.jobs.eval_depth`), with
ground-truth depth (``depth='gt'``: isolates the blend) or the refined depth (``'fused'``: MVS + the
:class:`~ibr_ros.core.depth.refine.DepthRefiner`, as ``ibr eval rephoto``). Path:
:func:`~ibr_ros.core.evaluation.flicker.smooth_path` through ``segments + 1`` consecutive source
poses from the middle of the selection, ``per_segment`` poses between two of them, moved off them
by ``offset_m`` (optical frame, metres). Every path pose is rendered once per blend mode
(:class:`RenderConfig` defaults with ``blend`` changed) and once as exact ground truth.

Flicker (:mod:`ibr_ros.core.evaluation.flicker`): per frame, the excess of the render's temporal
change over the ground truth's, per ``block_px`` square block (the main number; a block lets the
render be a little out of register with the truth without that counting as flicker) and per pixel
(``block_px`` 1, reported beside it: it has a floor of misregistration on textured surfaces shared by
every mode); the mean over frames and the worst 1 % of frames, and the ratio to ``paper``.

Writes ``path_eval.md``, ``path_eval.json``, ``path_flicker.png`` (per-frame excess per mode) and
``path.gif`` (ground truth | each mode) into the output folder, each atomically.
"""

from __future__ import annotations

import io
import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mvs import MvsOptions, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.evaluation.flicker import block_excess, smooth_path, summarise_flicker
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.eval_depth import load_views, sparse_points
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

__all__ = ['BLENDS', 'PathEvalOptions', 'evaluate_path']

LOG = logging.getLogger(__name__)

BLENDS = ('paper', 'soft', 'ulr', 'stable')
_GIF_WIDTH = 240  # px per panel of path.gif


@dataclass(frozen=True)
class PathEvalOptions:
    """Which views, path, modes and outputs (module docstring). ``size``: render ``(width, height)``
    px, None: the bag's; ``gif_every``: every n-th path frame goes into the GIF (0: no GIF)."""

    step: int = 10
    max_views: int = 40
    first: int = 0
    segments: int = 4
    per_segment: int = 60
    offset_m: tuple[float, float, float] = (1.5, -1.0, 0.0)
    blends: tuple[str, ...] = ('paper', 'ulr', 'stable')
    depth: Literal['gt', 'fused'] = 'gt'
    size: tuple[int, int] | None = None
    block_px: int = 16
    render: RenderConfig = field(default_factory=RenderConfig)
    gif_every: int = 3
    seed: int = 0

    def __post_init__(self) -> None:
        if self.step < 1 or self.max_views < 2 or self.first < 0:
            raise UserError(
                f'need step >= 1, max_views >= 2, first >= 0, got {self.step}, {self.max_views}, {self.first}'
            )
        if self.segments < 1 or self.per_segment < 2:
            raise UserError(
                f'need segments >= 1 and per_segment >= 2, got {self.segments}, {self.per_segment}'
            )
        unknown = [b for b in self.blends if b not in BLENDS]
        if unknown or not self.blends:
            raise UserError(f'unknown or no blend modes {unknown}; known: {", ".join(BLENDS)}')
        if self.depth not in ('gt', 'fused'):
            raise UserError(f"depth must be 'gt' or 'fused', got {self.depth!r}")
        if self.size is not None and (self.size[0] < 8 or self.size[1] < 8):
            raise UserError(f'size must be at least 8x8 px, got {self.size[0]}x{self.size[1]}')
        if self.block_px < 1 or self.gif_every < 0:
            raise UserError(f'need block_px >= 1 and gif_every >= 0, got {self.block_px}, {self.gif_every}')


def _fused_depths(views: list, gts: list, seed: int) -> list[NDArray[np.float32] | None]:
    """Refined depth per view (MVS seeded by ground-truth points, then the refiner); None on failure."""
    mvs = compute_depth_maps(views, options=MvsOptions(), points_w=sparse_points(gts, views, seed))
    refiner = DepthRefiner(RefinerConfig())
    out: list[NDArray[np.float32] | None] = []
    for view, res in zip(views, mvs, strict=True):
        try:
            out.append(refiner.refine_from_mvs(view, res.depth).depth)
        except RefineError as e:
            LOG.warning('a view has no refined depth and is left out: %s', e)
            out.append(None)
    return out


def _small(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    import cv2

    h, w = rgb.shape[:2]
    if w <= _GIF_WIDTH:
        return rgb
    return np.asarray(cv2.resize(rgb, (_GIF_WIDTH, round(h * _GIF_WIDTH / w)), interpolation=cv2.INTER_AREA))


def evaluate_path(
    bag: Path,
    out: Path,
    options: PathEvalOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Render the path per blend mode and ground truth, measure flicker, write the outputs; returns
    the summary (the JSON). Raises UserError for a bag that is not synthetic or too few views."""
    o = options or PathEvalOptions()
    if not (Path(bag) / 'synth.json').is_file():
        raise UserError(f'{bag}: no synth.json: `ibr eval path` needs a synthetic bag (`ibr bag synth`)')
    tick = time.perf_counter()
    gt_renderer = GroundTruthRenderer(bag)
    picked = load_views(bag, o.step, o.max_views, o.first)
    if len(picked) < o.segments + 1:
        raise UserError(
            f'{bag}: {len(picked)} views selected, a path of {o.segments} segments needs {o.segments + 1} '
            '(lower --segments or --step)'
        )
    views = [v for _, v in picked]
    frames = [i for i, _ in picked]
    gts = [gt_renderer.render(v.t_wc, v.camera) for v in views]
    depths: Sequence[NDArray[np.float32] | None] = (
        [g.depth for g in gts] if o.depth == 'gt' else _fused_depths(views, gts, o.seed)
    )
    sources = [
        SourceView(v.rgb, d, v.camera, v.t_wc, name=str(f))
        for v, d, f in zip(views, depths, frames, strict=True)
        if d is not None
    ]
    first_key = (len(views) - o.segments - 1) // 2
    keys = list(range(first_key, first_key + o.segments + 1))
    path = smooth_path([views[k].t_wc for k in keys], o.per_segment, o.offset_m)
    cam0 = views[0].camera
    w, h = o.size or (cam0.width, cam0.height)
    camera = PinholeCamera.from_fov(w, h, gt_renderer.hfov_deg)
    renderers = {b: NovelViewRenderer(sources, replace(o.render, blend=b)) for b in o.blends}  # type: ignore[arg-type]
    timings = {'load': time.perf_counter() - tick, 'truth': 0.0, **{b: 0.0 for b in o.blends}}
    excess: dict[str, dict[str, list[float]]] = {b: {'block': [], 'pixel': []} for b in o.blends}
    valid_frac: dict[str, list[float]] = {b: [] for b in o.blends}
    failed: dict[str, int] = {b: 0 for b in o.blends}
    prev: dict[str, tuple[NDArray[np.uint8], NDArray[np.bool_]]] = {}
    gif: list[NDArray[np.uint8]] = []
    for t, pose in enumerate(path):
        tick = time.perf_counter()
        truth = gt_renderer.render(pose, camera).rgb
        timings['truth'] += time.perf_counter() - tick
        panels = [_small(truth)]
        for b, r in renderers.items():
            tick = time.perf_counter()
            res = r.render(pose, camera)
            timings[b] += time.perf_counter() - tick
            if res.reason is not None:
                failed[b] += 1
                LOG.warning('%s: path frame %d not rendered: %s', b, t, res.reason)
            valid_frac[b].append(float(res.valid.mean()))
            if t > 0:
                r_prev, v_prev = prev[b]
                both = v_prev & res.valid
                g_prev = prev['truth'][0]
                excess[b]['block'].append(block_excess(r_prev, res.rgb, g_prev, truth, both, o.block_px))
                excess[b]['pixel'].append(block_excess(r_prev, res.rgb, g_prev, truth, both, 1))
            prev[b] = (res.rgb, res.valid)
            panels.append(_small(res.rgb))
        prev['truth'] = (truth, np.ones(truth.shape[:2], np.bool_))
        if o.gif_every and t % o.gif_every == 0:
            gif.append(np.concatenate(panels, axis=1))
        if progress is not None:
            progress(t + 1, len(path))
    summary = _summary(bag, o, frames, keys, len(path), excess, valid_frac, failed, timings, (w, h))
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / 'path_flicker.png', _plot(excess, o, bag))
    if gif:
        write_atomic(out / 'path.gif', _gif(gif, ['truth', *o.blends]))
    write_atomic(out / 'path_eval.json', json.dumps(summary, indent=2) + '\n')
    write_atomic(out / 'path_eval.md', _markdown(summary))
    return summary


def _summary(
    bag: Path,
    o: PathEvalOptions,
    frames: list[int],
    keys: list[int],
    n_path: int,
    excess: dict[str, dict[str, list[float]]],
    valid_frac: dict[str, list[float]],
    failed: dict[str, int],
    timings: dict[str, float],
    size: tuple[int, int],
) -> dict:
    modes: dict[str, dict] = {}
    for b in o.blends:
        modes[b] = {
            'block': summarise_flicker(excess[b]['block']),
            'pixel': summarise_flicker(excess[b]['pixel']),
            'valid_fraction': float(np.mean(valid_frac[b])),
            'failed_renders': failed[b],
            'ms_per_render': 1000.0 * timings[b] / max(n_path, 1),
            'per_frame_block': excess[b]['block'],
        }
    if 'paper' in modes:
        ref = modes['paper']['block']['mean']
        for b in modes:
            m = modes[b]['block']['mean']
            modes[b]['vs_paper'] = m / ref if ref > 0 else math.nan
    return {
        'bag': str(bag),
        'options': {
            'step': o.step,
            'max_views': o.max_views,
            'first': o.first,
            'segments': o.segments,
            'per_segment': o.per_segment,
            'offset_m': list(o.offset_m),
            'depth': o.depth,
            'size': list(size),
            'block_px': o.block_px,
            'stable_sigma_deg': o.render.stable_sigma_deg,
            'stable_fade': o.render.stable_fade,
        },
        'source_frames': frames,
        'path_through_frames': [frames[k] for k in keys],
        'path_frames': n_path,
        'modes': modes,
        'timings_s': timings,
    }


def _markdown(s: dict) -> str:
    o = s['options']
    lines = [
        f'# Path flicker: {Path(s["bag"]).name}',
        '',
        f'{s["path_frames"]} poses on a smooth path through source frames {s["path_through_frames"]} '
        f'({o["per_segment"]} per segment, {o["offset_m"]} m off them in the optical frame), rendered at '
        f'{o["size"][0]}x{o["size"][1]} from {len(s["source_frames"])} source views (every {o["step"]}th '
        f'frame, {o["depth"]} depth) and compared with the exact ground truth.',
        '',
        'Excess flicker per frame (0..255 colour units): the mean over blocks of max(0, change of the '
        f'render - change of the ground truth) between consecutive frames, in {o["block_px"]}x'
        f'{o["block_px"]} px blocks; per pixel beside it. Worst 1 % = mean of the worst 1 % of frames.',
        '',
        f'| blend | mean ({o["block_px"]} px) | worst 1 % | vs paper | mean per pixel | worst 1 % per pixel '
        '| valid | failed | ms / render |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for b, m in s['modes'].items():
        bl, px = m['block'], m['pixel']
        vs = m.get('vs_paper', math.nan)
        lines.append(
            f'| {b} | {bl["mean"]:.4f} | {bl["worst_1pct"]:.4f} | {vs:.2f} | {px["mean"]:.3f} | '
            f'{px["worst_1pct"]:.3f} | {m["valid_fraction"]:.4f} | {m["failed_renders"]} | '
            f'{m["ms_per_render"]:.0f} |'
        )
    lines += ['', 'Plot: `path_flicker.png`; video: `path.gif` (ground truth | each blend).', '']
    return '\n'.join(lines)


def _plot(excess: dict[str, dict[str, list[float]]], o: PathEvalOptions, bag: Path) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for b, e in excess.items():
        ax.plot(np.arange(1, len(e['block']) + 1), e['block'], lw=1.2, label=b)
    for k in range(1, o.segments):
        ax.axvline(k * o.per_segment, color='0.6', lw=0.8, ls=':')
    ax.set(
        xlabel='path frame (dotted: nearest to a source view)',
        ylabel=f'excess flicker, {o.block_px} px blocks (0..255)',
        title=f'excess temporal change over the ground truth along the path, {bag.name}',
    )
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format='png')
    return buf.getvalue()


def _gif(frames: list[NDArray[np.uint8]], labels: list[str]) -> bytes:
    """An animated GIF of the panels, labelled, on one palette (from the first frame) without
    dithering: a palette or dither pattern of its own per frame would flicker by itself."""
    from PIL import Image, ImageDraw

    panel = frames[0].shape[1] // len(labels)
    images: list[Image.Image] = []
    palette: Image.Image | None = None
    for f in frames:
        im = Image.fromarray(f)
        draw = ImageDraw.Draw(im)
        for i, text in enumerate(labels):
            draw.text((i * panel + 4, 2), text, fill=(255, 255, 255))
        if palette is None:
            palette = im.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
        images.append(im.quantize(palette=palette, dither=Image.Dither.NONE))
    buf = io.BytesIO()
    images[0].save(buf, format='GIF', save_all=True, append_images=images[1:], duration=66, loop=0)
    return buf.getvalue()
