# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr eval ...``: evaluations against ground truth that write Markdown + JSON tables and PNGs."""

from __future__ import annotations

import argparse
from pathlib import Path


def _depth(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.jobs.eval_depth import DepthEvalOptions, evaluate_depth

    options = DepthEvalOptions(step=args.step, max_views=args.max_views, first=args.first, png=args.png)
    with progress_bar('depth eval', unit='step', enabled=args.progress) as progress:
        summary = evaluate_depth(Path(args.bag), Path(args.out), options, progress)
    print((Path(args.out) / 'depth_eval.md').read_text())
    return 0 if summary['evaluated'] else 1


def _mono(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.errors import UserError
    from ibr_ros.jobs.eval_mono import MonoEvalOptions, evaluate_mono
    from ibr_ros.models import SHIPPED_MONO_MODEL

    try:
        w, h = (int(v) for v in args.size.lower().split('x'))
    except ValueError as exc:
        raise UserError(f'--size must be WIDTHxHEIGHT, got {args.size!r}') from exc
    bag = Path(args.photos_bag) if args.photos_bag else None
    options = MonoEvalOptions(
        scenes=args.scenes, views=args.views, size=(w, h), ref_fraction=args.ref_fraction,
        seed=args.seed, png=args.png, photos_bag=bag,
        real_mvs=Path(args.real_mvs) if args.real_mvs else None,
    )  # fmt: skip
    with progress_bar('mono eval', unit='view', enabled=args.progress) as progress:
        evaluate_mono(Path(args.model or SHIPPED_MONO_MODEL), Path(args.out), options, progress)
    print((Path(args.out) / 'mono_eval.md').read_text())
    return 0


def _rephoto(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import staged_progress
    from ibr_ros.jobs.eval_rephoto import RephotoEvalOptions, evaluate_rephoto, parse_holdout

    options = RephotoEvalOptions(
        step=args.step,
        max_views=args.max_views,
        first=args.first,
        holdout_every=parse_holdout(args.holdout) if args.holdout is not None else None,
        png=args.png,
        views_from=args.views_from,
        params=Path(args.params) if args.params else None,
        max_keyframes=args.max_keyframes,
        sfm=args.sfm,
        gps=args.gps,
    )
    units = {'rephoto': 'step', 'frames': 'frame', 'sfm': 'registration', 'keyframes': 'keyframe'}
    with staged_progress({**units, 'holdouts': 'holdout'}, enabled=args.progress) as progress:
        summary = evaluate_rephoto(Path(args.bag), Path(args.out), options, progress)
    print((Path(args.out) / 'rephoto_eval.md').read_text())
    failed = all(m['failed_renders'] == len(summary['holdout_frames']) for m in summary['methods'].values())
    return 1 if failed else 0


def _path(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.errors import UserError
    from ibr_ros.jobs.eval_path import PathEvalOptions, evaluate_path

    size = None
    if args.size:
        try:
            w, h = (int(v) for v in args.size.lower().split('x'))
        except ValueError as exc:
            raise UserError(f'--size must be WIDTHxHEIGHT, got {args.size!r}') from exc
        size = (w, h)
    try:
        offset = tuple(float(v) for v in args.offset.split(','))
    except ValueError as exc:
        raise UserError(f'--offset must be X,Y,Z in metres, got {args.offset!r}') from exc
    if len(offset) != 3:
        raise UserError(f'--offset must be X,Y,Z in metres, got {args.offset!r}')
    options = PathEvalOptions(
        step=args.step, max_views=args.max_views, first=args.first, segments=args.segments,
        per_segment=args.per_segment, offset_m=(offset[0], offset[1], offset[2]),
        blends=tuple(b.strip() for b in args.blends.split(',')), depth=args.depth, size=size,
        block_px=args.block, gif_every=args.gif_every,
    )  # fmt: skip
    with progress_bar('path eval', unit='pose', enabled=args.progress) as progress:
        summary = evaluate_path(Path(args.bag), Path(args.out), options, progress)
    print((Path(args.out) / 'path_eval.md').read_text())
    return 1 if any(m['failed_renders'] == summary['path_frames'] for m in summary['modes'].values()) else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('eval', help='evaluate against ground truth or held-out photos (tables and plots)')
    ev = p.add_subparsers(dest='eval_command', metavar='EVAL_COMMAND', required=True)
    d = ev.add_parser('depth', help='depth refinement vs ground truth on a synthetic bag (Tables 1-2)')
    d.add_argument('bag', metavar='BAG', help='synthetic bag made by `ibr bag synth`')
    d.add_argument('--out', default='out/depth_eval', help='output folder (default: out/depth_eval)')
    d.add_argument('--step', type=int, default=10, help='evaluate every Nth frame')
    d.add_argument('--max-views', type=int, default=20, help='at most this many views')
    d.add_argument('--first', type=int, default=0, help='index of the first frame')
    d.add_argument(
        '--png', action=argparse.BooleanOptionalAction, default=True, help='write per-view PNG grids'
    )
    d.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    d.set_defaults(func=_depth)
    m = ev.add_parser('mono', help='monocular depth + sky model on held-out synthetic views and real photos')
    m.add_argument('--model', help='ONNX model in the ibr_mono convention (default: the shipped one)')
    m.add_argument('--out', default='out/mono_eval', help='output folder (default: out/mono_eval)')
    m.add_argument('--scenes', type=int, default=8, help='held-out towns')
    m.add_argument('--views', type=int, default=4, help='views per town')
    m.add_argument('--size', default='384x224', help='rendered view size WIDTHxHEIGHT')
    m.add_argument('--ref-fraction', type=float, default=0.05, help='share of GT pixels used as reference')
    m.add_argument('--seed', type=int, default=0, help='held-out seed block')
    m.add_argument(
        '--photos-bag', default='bags/brighton_beach', help='bag of real photos for PNGs ("" = none)'
    )
    m.add_argument(
        '--real-mvs', help='npz of real photos with MVS depth (tools/real_mvs_data.py): Abs Rel after the LUT'
    )
    m.add_argument('--png', action=argparse.BooleanOptionalAction, default=True, help='write PNGs')
    m.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    m.set_defaults(func=_mono)

    r = ev.add_parser(
        'rephoto',
        help='rephotography of held-out photos rendered from the other views (Table 3, Fig. 11); any bag',
        description='Holds out every Nth view, renders it at its pose from the other views and scores it '
        'against its own photo (shiftable L1 on the Table 3 grid, PSNR, SSIM, completeness). Views: every '
        '--step-th frame of a synthetic bag (leave-one-out, with ground truth), or keyframes chosen, '
        'registered (SfM when the bag has no poses) and refined as `ibr process` does, the held-out ones '
        "left out of every other keyframe's MVS and of the render set.",
    )
    r.add_argument(
        'bag', metavar='BAG', help='any bag `ibr process` reads (a synthetic one has ground truth)'
    )
    r.add_argument(
        '--views-from',
        choices=('auto', 'frames', 'keyframes'),
        default='auto',
        help="'frames': every --step-th frame (synthetic bags); 'keyframes': as `ibr process` chooses them; "
        "'auto' (default): frames when the bag has synth.json, else keyframes",
    )
    r.add_argument(
        '--holdout',
        default=None,
        help="held-out views: 'every-Nth' of the selection (default: every-8th frame, every-4th keyframe)",
    )
    r.add_argument('--out', default='out/rephoto_eval', help='output folder (default: out/rephoto_eval)')
    r.add_argument('--step', type=int, default=5, help='frames: every Nth frame of the bag (default: 5)')
    r.add_argument('--max-views', type=int, default=40, help='frames: at most this many (default: 40)')
    r.add_argument('--first', type=int, default=0, help='index of the first frame')
    r.add_argument('--params', metavar='FILE', help='keyframes: a ROS 2 params file over config/<node>.yaml')
    r.add_argument('--max-keyframes', type=int, help='keyframes: stop reading the bag after this many')
    r.add_argument('--sfm', action='store_true', help='keyframes: SfM mode even if the bag has poses')
    r.add_argument(
        '--gps',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='keyframes, SfM mode: use NavSatFix',
    )
    r.add_argument(
        '--png',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='write holdout_NNN.png side by sides',
    )
    r.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    r.set_defaults(func=_rephoto)

    f = ev.add_parser(
        'path',
        help='flicker along a smooth novel path per blend mode vs exact ground truth (synthetic bag)',
        description='Renders a smooth path through consecutive source poses (moved off them by --offset) '
        "with each blend mode and as exact ground truth, and measures the excess of the render's "
        "frame-to-frame change over the ground truth's (mean and worst 1 %% of frames; Markdown, JSON, "
        'a plot and a GIF).',
    )
    f.add_argument('bag', metavar='BAG', help='synthetic bag made by `ibr bag synth`')
    f.add_argument('--out', default='out/path_eval', help='output folder (default: out/path_eval)')
    f.add_argument('--step', type=int, default=10, help='source views: every Nth frame (default: 10)')
    f.add_argument('--max-views', type=int, default=40, help='at most this many source views (default: 40)')
    f.add_argument('--first', type=int, default=0, help='index of the first frame')
    f.add_argument('--segments', type=int, default=4, help='path segments between source poses (default: 4)')
    f.add_argument('--per-segment', type=int, default=60, help='path poses per segment (default: 60)')
    f.add_argument(
        '--offset',
        default='1.5,-1.0,0.0',
        help='path offset from the source poses, X,Y,Z m in their optical frame',
    )
    f.add_argument(
        '--blends', default='paper,ulr,stable', help='blend modes, comma-separated (paper,soft,ulr,stable)'
    )
    f.add_argument('--depth', choices=('gt', 'fused'), default='gt', help='source depth (default: gt)')
    f.add_argument('--size', help="render size WIDTHxHEIGHT (default: the bag's)")
    f.add_argument(
        '--block', type=int, default=16, help='flicker block size in px (default: 16; 1 = per pixel)'
    )
    f.add_argument(
        '--gif-every', type=int, default=3, help='every Nth path pose into path.gif (default: 3; 0: no GIF)'
    )
    f.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    f.set_defaults(func=_path)
