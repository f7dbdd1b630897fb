# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag from-images DIR --out BAG``: photos (EXIF time order) to a ROS 2 bag."""

from __future__ import annotations

import argparse
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.jobs.images_to_bag import images_to_bag

    with progress_bar('photos', unit='photo', enabled=args.progress) as progress:
        result = images_to_bag(
            Path(args.folder),
            Path(args.out),
            max_width=args.max_width,
            jpeg_quality=args.jpeg_quality,
            fallback_hfov_deg=args.fov,
            overwrite=args.overwrite,
            progress=progress,
        )
    print(
        f'wrote {result.path}: {result.photos} photos, {result.with_gps} with GPS, '
        f'{result.with_attitude} with gimbal attitude; intrinsics from {result.camera_source}'
        + (f'; license copied to {result.license_copied}' if result.license_copied else '')
    )
    return 0


def register(bag_sub: argparse._SubParsersAction) -> None:
    p = bag_sub.add_parser(
        'from-images',
        help='convert a folder of photos to a bag (CompressedImage, CameraInfo, NavSatFix, gimbal attitude)',
    )
    p.add_argument('folder', metavar='DIR', help='folder of photos (or a folder with images/ inside)')
    p.add_argument('--out', required=True, metavar='BAG', help='bag folder to create')
    p.add_argument('--max-width', type=int, default=None, help='downscale wider photos to this width (px)')
    p.add_argument('--jpeg-quality', type=int, default=92, help='JPEG quality of the written images')
    p.add_argument(
        '--fov', type=float, default=70.0, help='horizontal field of view (deg) for photos without EXIF focal'
    )
    p.add_argument('--overwrite', action='store_true', help='replace an existing bag')
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    p.set_defaults(func=run)
