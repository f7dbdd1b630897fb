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


def _rephoto(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.jobs.eval_rephoto import RephotoEvalOptions, evaluate_rephoto, parse_holdout

    options = RephotoEvalOptions(
        step=args.step,
        max_views=args.max_views,
        first=args.first,
        holdout_every=parse_holdout(args.holdout),
        png=args.png,
    )
    with progress_bar('rephoto eval', unit='step', enabled=args.progress) as progress:
        summary = evaluate_rephoto(Path(args.bag), Path(args.out), options, progress)
    print((Path(args.out) / 'rephoto_eval.md').read_text())
    failed = all(m['failed_renders'] == len(summary['holdout_frames']) for m in summary['methods'].values())
    return 1 if failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('eval', help='evaluate against ground truth (tables and plots)')
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

    r = ev.add_parser(
        'rephoto', help='leave-one-out rephotography of held-out views on a synthetic bag (Table 3, Fig. 11)'
    )
    r.add_argument('bag', metavar='BAG', help='synthetic bag made by `ibr bag synth`')
    r.add_argument(
        '--holdout',
        default='every-8th',
        help="held-out views: 'every-Nth' of the selection (default: every-8th)",
    )
    r.add_argument('--out', default='out/rephoto_eval', help='output folder (default: out/rephoto_eval)')
    r.add_argument('--step', type=int, default=5, help='use every Nth frame of the bag (default: 5)')
    r.add_argument('--max-views', type=int, default=40, help='at most this many views (default: 40)')
    r.add_argument('--first', type=int, default=0, help='index of the first frame')
    r.add_argument(
        '--png',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='write holdout_NNN.png side by sides',
    )
    r.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    r.set_defaults(func=_rephoto)
