# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr process``: a whole bag through the node pipeline offline (see :mod:`ibr_ros.jobs.process`)."""

from __future__ import annotations

import argparse
from pathlib import Path

UNITS = {
    'frames': 'frame',
    'reread': 'frame',
    'sfm': 'registration',
    'keyframes': 'keyframe',
    'model': 'keyframe',
    'views': 'view',
    'write': 'message group',
    'previews': 'image',
}


def run(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import staged_progress
    from ibr_ros.jobs.process import ProcessOptions, process_bag

    options = ProcessOptions(
        image_topic=args.image_topic,
        info_topic=args.info_topic,
        pose_topic=args.pose_topic,
        navsat_topic=args.navsat_topic,
        sfm=args.sfm,
        gps=args.gps,
        params=Path(args.params) if args.params else None,
        views=args.views,
        width=args.width,
        height=args.height,
        hfov_deg=args.hfov_deg,
        max_keyframes=args.max_keyframes,
        target_keyframes=args.target_keyframes,
        threads=args.threads,
        overwrite=args.overwrite,
    )
    with staged_progress(UNITS, enabled=args.progress) as progress:
        summary = process_bag(Path(args.bag), Path(args.out), options, progress)
    print((Path(args.out) / 'summary.md').read_text(), end='')
    return 0 if summary['refined'] else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'process',
        help='process a whole bag offline with the node pipeline into an output bag (keyframes, '
        'refined depth, novel views), PNG previews and a summary',
        description='Keyframe selection, MVS + depth refinement and novel views along the keyframe path, '
        'with the parameters of config/<node>.yaml (frame_subsampler, depth_refiner, view_renderer), '
        'synchronously in bag-time order: the same input gives the same output. A bag without poses '
        "is registered with SfM (the depth_refiner's sfm_mode; GPS from a NavSatFix topic gives ENU "
        'metres).',
    )
    p.add_argument('bag', help='input bag: ROS 2 bag folder, .mcap, .db3 or ROS 1 .bag')
    p.add_argument('--out', required=True, help='output folder (bag/, previews/, summary.json, summary.md)')
    p.add_argument('--image-topic', help='camera image topic, Image or CompressedImage (default: detected)')
    p.add_argument('--info-topic', help='CameraInfo topic (default: detected)')
    p.add_argument('--pose-topic', help='PoseStamped or Odometry topic (default: detected)')
    p.add_argument(
        '--navsat-topic',
        help='NavSatFix topic: GPS for SfM mode, and passed through to the output bag as /gps/fix '
        '(default: detected)',
    )
    p.add_argument(
        '--sfm',
        action='store_true',
        help='SfM mode even if the bag has poses: they are ignored (keyframes every poseless_interval_s, '
        'poses from SfM; a synthetic bag is then evaluated against them)',
    )
    p.add_argument(
        '--gps',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='SfM mode: align to the NavSatFix positions (default: yes); --no-gps still passes the fixes '
        'through to the output bag',
    )
    p.add_argument(
        '--params', metavar='FILE', help='ROS 2 params file overriding config/<node>.yaml of the three nodes'
    )
    p.add_argument('--views', type=int, default=16, help='novel views along the keyframe path (default: 16)')
    p.add_argument(
        '--width', type=int, help="novel view width (px); default: view_renderer's (0 = keyframe's)"
    )
    p.add_argument('--height', type=int, help='novel view height (px)')
    p.add_argument('--hfov-deg', type=float, help='novel view horizontal field of view (deg)')
    p.add_argument(
        '--max-keyframes',
        type=int,
        help='stop reading the bag after this many keyframes (with a target: the first this many chosen)',
    )
    p.add_argument(
        '--target-keyframes',
        type=int,
        metavar='N',
        help='about N keyframes over the whole flight (bags with poses: the baseline thresholds scaled by '
        "bisection; default: the frame_subsampler's target_keyframes, 0 = off: frame by frame as live)",
    )
    p.add_argument('--threads', type=int, help='compute threads (default: all cores)')
    p.add_argument('--overwrite', action='store_true', help='replace an existing OUT/bag')
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bars')
    p.set_defaults(func=run)
