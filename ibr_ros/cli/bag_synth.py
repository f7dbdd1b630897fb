# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag synth``: render a synthetic drone flight with ground truth into a bag."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from ibr_ros.errors import UserError


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r'(\d+)x(\d+)', text)
    if not m or int(m[1]) < 16 or int(m[2]) < 16:
        raise argparse.ArgumentTypeError(f'size must be WIDTHxHEIGHT with both >= 16, got {text!r}')
    return int(m[1]), int(m[2])


def _pitch(text: str) -> tuple[float, float]:
    try:
        lo, hi = sorted(float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'pitch must be LO,HI in degrees, got {text!r}') from None
    if lo < -90.0 or hi >= 0.0:
        raise argparse.ArgumentTypeError(f'pitch must lie in [-90, 0) degrees (looking down), got {text!r}')
    return lo, hi


def run(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.jobs.synth_bag import write_synth_bag

    if args.duration <= 0 or args.fps <= 0:
        raise UserError(f'--duration and --fps must be positive, got {args.duration} and {args.fps}')
    with progress_bar('frames', unit='frame', enabled=args.progress) as progress:
        result = write_synth_bag(
            Path(args.out),
            seed=args.seed,
            trajectory=args.trajectory,
            duration_s=args.duration,
            fps=args.fps,
            size=args.size,
            hfov_deg=args.hfov,
            pitch_range_deg=args.pitch,
            jpeg_quality=args.jpeg_quality,
            depth_every=args.depth_every,
            depth_mantissa_bits=args.depth_mantissa_bits,
            labels=args.labels,
            overwrite=args.overwrite,
            progress=progress,
        )
    print(
        f'wrote {result.path}: {result.frames} frames, ground truth on {result.depth_frames}; '
        f'max depth quantisation error {result.max_depth_rel_error:.2e} (relative)'
    )
    return 0


def register(bag_sub: argparse._SubParsersAction) -> None:
    p = bag_sub.add_parser('synth', help='render a synthetic drone flight with ground-truth depth into a bag')
    p.add_argument('--seed', type=int, default=0, help='scene and flight seed')
    p.add_argument('--trajectory', choices=('orbit', 'lawnmower', 'forward'), default='orbit')
    p.add_argument('--duration', type=float, default=20.0, help='flight duration (s)')
    p.add_argument('--fps', type=float, default=12.0, help='frames per second')
    p.add_argument('--size', type=_size, default=(640, 360), metavar='WxH', help='image size (px)')
    p.add_argument('--hfov', type=float, default=70.0, help='horizontal field of view (deg)')
    p.add_argument(
        '--pitch',
        type=_pitch,
        default=(-60.0, -15.0),
        metavar='LO,HI',
        help='camera pitch range (deg, negative = down); --pitch=-12,-6 sees the horizon',
    )
    p.add_argument('--jpeg-quality', type=int, default=90)
    p.add_argument('--depth-every', type=int, default=1, help='write ground truth every Nth frame')
    p.add_argument(
        '--depth-mantissa-bits',
        type=int,
        default=23,
        help='float32 mantissa bits kept in GT depth (23 = lossless; 10 = rel. error <= 4.9e-4)',
    )
    p.add_argument('--labels', action=argparse.BooleanOptionalAction, default=True, help='write class labels')
    p.add_argument('--out', required=True, metavar='BAG', help='bag folder to create')
    p.add_argument('--overwrite', action='store_true', help='replace an existing bag')
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    p.set_defaults(func=run)
