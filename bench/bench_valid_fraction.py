# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Valid fraction against rephotography error: where do novel views become torn?

Measures what the view_renderer's ``min_valid_fraction`` should be. Keyframes are chosen, registered
(SfM for a bag without poses) and refined exactly as ``ibr eval rephoto BAG --holdout every-Nth``
does (:mod:`ibr_ros.jobs.eval_rephoto`, keyframes): every N-th keyframe is held out and the others
are refined without it. Each held-out photo is then rendered at its pose with the view_renderer's
parameters from the refined keyframes ``--drop`` times: with all of them, and without the ``k``
nearest ones (camera centres) for each ``k`` of ``--drop``, so that the same photo is rendered from
ever weaker overlap (as a sparser survey would give it). On a synthetic bag (``synth.json``),
``--pan`` also renders each held-out pose turned by each angle about the camera's y axis (from all
refined keyframes), scored against the exact ground-truth image of that pose: views that look
partly off the captured area. Per render: the valid fraction (rendered
pixels) and the shiftable-L1 error 7x7 +-2 (0..255 colour units, :func:`shiftable_l1`) of the
rendered pixels alone (``valid``: holes inpainted as ``ibr eval rephoto`` does, so that windows at a
hole's edge compare like with like, then the mean over the rendered pixels), of the whole image
with the holes inpainted (``filled``: ``ibr eval rephoto``'s AUC) and of the image a client gets
(``black``: holes black, as the view_renderer publishes it). Baseline (``nearest_photo``): the
error of the photo of the nearest keyframe the render could use, shown as it is (the answer a
client gets without any rendering); a render whose ``black`` error exceeds it is worse than no
rendering at all.

Writes ``valid_fraction.json`` (every render) into ``--out`` and prints the renders binned by valid
fraction (median errors per bin, and how many renders are worse than the baseline);
``--png``: photo | render (holes black) of each render into ``--out/png``. The refined keyframes
are kept in ``--out/model.pkl``: a second run with the same bag, ``--holdout`` and
``--max-keyframes`` reuses them (``--refresh`` refines again). ``--report A.json B.json ...``
prints the table of earlier runs' ``valid_fraction.json`` together and, per file, the highest
valid fraction of a render worse than the baseline. No target: the numbers go to
``bench/README.md`` (section Valid fraction). Run:
``.venv/bin/python bench/bench_valid_fraction.py bags/brighton_beach --out out/vf_brighton``.
"""

from __future__ import annotations

import argparse
import json
import pickle
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # measure this checkout

import cv2
import numpy as np

from ibr_ros.core.evaluation import shiftable_l1
from ibr_ros.core.render import NovelViewRenderer, SourceView
from ibr_ros.jobs.eval_rephoto import holdout_indices, parse_holdout
from ibr_ros.jobs.process import ProcessOptions
from ibr_ros.jobs.process.frames import subsample
from ibr_ros.jobs.process.params import load_params, process_configs
from ibr_ros.jobs.process.refine import refine_all
from ibr_ros.jobs.process.sfm import register_keyframes
from ibr_ros.jobs.synth_bag import GroundTruthRenderer

#: Valid-fraction bins (lower edges, descending) of the printed table.
BINS = (0.98, 0.9, 0.8, 0.7, 0.6, 0.5, 0.3, 0.0)


def model(bag: Path, every: int, max_keyframes: int | None, out: Path, refresh: bool) -> dict:
    """Keyframes (registered), the held-out positions and the refined kept keyframes, cached in ``out``."""
    cache = out / 'model.pkl'
    if cache.is_file() and not refresh:
        with cache.open('rb') as f:
            cached = pickle.load(f)
        if (cached['bag'], cached['every'], cached['max_keyframes']) == (str(bag), every, max_keyframes):
            print(f'reusing the refined keyframes of {cache}')
            return cached
    options = ProcessOptions(views=0, max_keyframes=max_keyframes)
    cfg = process_configs(load_params(None), options)
    sub = subsample(bag, cfg, options, None)
    keyframes = sub.keyframes
    if sub.sfm_why is not None:
        keyframes, cfg, _ = register_keyframes(sub, cfg, None, None)
    hold = holdout_indices(len(keyframes), every)
    kept = [k for i, k in enumerate(keyframes) if i not in set(hold)]
    t0 = time.perf_counter()
    refine_all(kept, cfg, None)
    print(f'{len(kept)} kept keyframes refined in {time.perf_counter() - t0:.0f} s')
    data = {
        'bag': str(bag),
        'every': every,
        'max_keyframes': max_keyframes,
        'keyframes': keyframes,
        'hold': hold,
        'model': [k for k in kept if k.depth is not None],
        'render': cfg.viewing.render,
        'position': {k.stamp: i for i, k in enumerate(keyframes)},
    }
    out.mkdir(parents=True, exist_ok=True)
    with cache.open('wb') as f:
        pickle.dump(data, f)
    return data


def score(photo: np.ndarray, rgb: np.ndarray, valid: np.ndarray) -> dict[str, float]:
    """Valid fraction and the mean shiftable-L1 error 7x7 +-2 of the rendered pixels, of the image
    with its holes inpainted and of the image with its holes black."""
    filled = rgb
    if valid.any() and not valid.all():
        filled = np.asarray(cv2.inpaint(rgb, (~valid).astype(np.uint8), 3, cv2.INPAINT_TELEA), np.uint8)
    e_filled = shiftable_l1(photo, filled)
    e_black = shiftable_l1(photo, rgb)
    return {
        'valid_fraction': float(valid.mean()),
        'valid': float(np.nanmean(e_filled[valid])) if valid.any() else float('nan'),
        'filled': float(np.nanmean(e_filled)),
        'black': float(np.nanmean(e_black)),
    }


def panned(t_wc: np.ndarray, deg: float) -> np.ndarray:
    """``t_wc`` turned by ``deg`` about the camera's y axis."""
    a = np.radians(deg)
    r = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    out = np.array(t_wc, dtype=np.float64)
    out[:3, :3] = out[:3, :3] @ r
    return out


def measure(
    data: dict, drops: list[int], pans: list[float], gt: GroundTruthRenderer | None, png: Path | None
) -> list[dict]:
    """Every held-out photo rendered without its ``k`` nearest refined keyframes, for each ``k``,
    and (``gt``: a synthetic bag) at its pose panned by each of ``pans`` (``png``: a folder for
    photo | render images)."""
    rows = []
    keyframes, position = data['keyframes'], data['position']
    for h in data['hold']:
        target = keyframes[h]
        near = sorted(data['model'], key=lambda k: float(np.linalg.norm(k.t_wc[:3, 3] - target.t_wc[:3, 3])))
        jobs = [(k, 0.0) for k in drops if k < len(near)] + [(0, a) for a in pans if a and gt is not None]
        for k, pan in jobs:
            views = [
                SourceView(
                    m.rgb, m.depth, m.camera, m.t_wc, name=str(position[m.stamp]), stamp=m.stamp * 1e-9
                )
                for m in near[k:]
            ]
            t_wc = panned(target.t_wc, pan)
            photo = target.rgb if gt is None or not pan else gt.render(t_wc, target.camera).rgb
            t0 = time.perf_counter()
            out = NovelViewRenderer(views, data['render']).render(t_wc, target.camera)
            row = {'holdout': h, 'drop': k, 'pan_deg': pan, 'render_s': time.perf_counter() - t0}
            row['reason'] = out.reason
            row['nearest_m'] = float(np.linalg.norm(near[k].t_wc[:3, 3] - target.t_wc[:3, 3]))
            row['used'] = [int(views[i].name) for i in out.used_views]
            row.update(score(photo, out.rgb, out.valid))
            row['nearest_photo'] = float(np.nanmean(shiftable_l1(photo, near[k].rgb)))
            rows.append(row)
            name = f'holdout_{h:03d}_drop_{k}' + (f'_pan_{pan:g}' if pan else '')
            if png is not None:
                png.mkdir(parents=True, exist_ok=True)
                pair = cv2.cvtColor(np.hstack([photo, out.rgb]), cv2.COLOR_RGB2BGR)
                cv2.imwrite(str(png / f'{name}_valid_{row["valid_fraction"]:.2f}.png'), pair)
            print(
                f'{name}: valid {row["valid_fraction"]:.3f}, error valid {row["valid"]:.2f} filled '
                f'{row["filled"]:.2f} black {row["black"]:.2f} nearest photo {row["nearest_photo"]:.2f}'
                f'{"  (" + out.reason + ")" if out.reason else ""}',
                flush=True,
            )
    return rows


def table(rows: list[dict]) -> str:
    """Markdown table: renders binned by valid fraction (``[lo, hi)``, the top bin up to 1 inclusive),
    median errors per bin and the renders whose view as published is worse than the nearest photo."""
    lines = [
        '| valid fraction | renders | rendered pixels | holes inpainted | holes black (published) '
        '| nearest photo | published worse than nearest photo |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for hi, lo in zip((1.0 + 1e-9, *BINS), BINS):
        rs = [r for r in rows if lo <= r['valid_fraction'] < hi]
        if not rs:
            continue
        med = {}
        for key in ('valid', 'filled', 'black', 'nearest_photo'):
            vals = [r[key] for r in rs if np.isfinite(r[key])]
            med[key] = statistics.median(vals) if vals else float('nan')
        worse = sum(r['black'] > r['nearest_photo'] for r in rs)
        lines.append(
            f'| {lo:.2f}-{min(hi, 1.0):.2f} | {len(rs)} | {med["valid"]:.2f} | {med["filled"]:.2f} '
            f'| {med["black"]:.2f} | {med["nearest_photo"]:.2f} | {worse} |'
        )
    return '\n'.join(lines)


def worst_answer(rows: list[dict]) -> str:
    """Range of valid fractions, the highest one of a render worse (holes black) than the nearest
    photo and the lowest one of a render better than it."""
    fracs = [r['valid_fraction'] for r in rows]
    worse = [r['valid_fraction'] for r in rows if r['black'] > r['nearest_photo']]
    better = [r['valid_fraction'] for r in rows if r['black'] <= r['nearest_photo']]
    return (
        f'{len(rows)} renders, valid fraction {min(fracs):.3f} .. {max(fracs):.3f}; worse than the nearest '
        f'photo: {len(worse)}, the highest at {max(worse) if worse else float("nan"):.3f}; lowest better: '
        f'{min(better) if better else float("nan"):.3f}'
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('bag', type=Path, nargs='?', help='the bag to measure (not with --report)')
    p.add_argument('--out', type=Path, help='folder for valid_fraction.json and model.pkl')
    p.add_argument('--holdout', default='every-4th', help="held-out keyframes (default 'every-4th')")
    p.add_argument(
        '--drop', default='0,1,2,3,4,6', help='numbers of nearest keyframes left out (default 0,1,2,3,4,6)'
    )
    p.add_argument('--pan', default='', help='synthetic bags: pan angles (deg) of the held-out poses')
    p.add_argument('--max-keyframes', type=int, help='stop after this many keyframes (as ibr process)')
    p.add_argument('--png', action='store_true', help='write photo | render PNGs into OUT/png')
    p.add_argument('--refresh', action='store_true', help='refine again even when model.pkl exists')
    p.add_argument('--report', type=Path, nargs='+', help='valid_fraction.json files: their table together')
    args = p.parse_args()
    if args.report:
        runs = {path: json.loads(path.read_text())['renders'] for path in args.report}
        print(table([r for rows in runs.values() for r in rows]))
        for path, rows in runs.items():
            print(f'{path}: {worst_answer(rows)}')
        return 0
    if args.bag is None or args.out is None:
        p.error('give a bag and --out (or --report)')
    data = model(args.bag, parse_holdout(args.holdout), args.max_keyframes, args.out, args.refresh)
    pans = [float(x) for x in args.pan.split(',') if x]
    gt = GroundTruthRenderer(args.bag) if (args.bag / 'synth.json').is_file() else None
    if pans and gt is None:
        p.error('--pan needs a synthetic bag (synth.json): the ground truth of a panned view')
    drops = [int(x) for x in args.drop.split(',')]
    rows = measure(data, drops, pans, gt, args.out / 'png' if args.png else None)
    (args.out / 'valid_fraction.json').write_text(
        json.dumps({'bag': str(args.bag), 'holdout': args.holdout, 'renders': rows}, indent=1) + '\n'
    )
    print(table(rows))
    print(worst_answer(rows))
    return 0


if __name__ == '__main__':
    sys.exit(main())
