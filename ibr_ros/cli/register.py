# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr register BAG``: register the bag's camera images by SfM (COLMAP), metric with GPS."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ibr_ros.errors import UserError


def run(args: argparse.Namespace) -> int:
    """Register, print a one-line summary, write the JSON document (``--out``) and arrays (``--npz``)."""
    import numpy as np

    from ibr_ros.core.registration.sfm import SfmError, SfmOptions
    from ibr_ros.jobs.register_bag import register_bag, registration_to_dict

    options = SfmOptions(
        max_image_size=args.max_image_size,
        max_num_features=args.max_features,
        first_octave=0 if args.fast else -1,
        camera_model=args.camera_model,
        verbose=getattr(args, 'verbose', False),
    )
    try:
        reg = register_bag(
            Path(args.bag),
            max_images=args.max_images,
            image_topic=args.image_topic,
            use_gps=args.gps,
            options=options,
            workdir=Path(args.workdir) if args.workdir else None,
        )
    except (SfmError, ValueError) as exc:
        raise UserError(f'{args.bag}: {exc}') from exc
    res = reg.result
    doc = registration_to_dict(reg)
    line = (
        f'registered {res.num_registered}/{len(res.registered)} images, {len(res.points)} points, '
        f'mean reprojection error {res.mean_reprojection_error_px:.3f} px, f = {res.camera.fx:.1f} px, '
    )
    a = res.alignment
    line += (
        f'metric ENU (GPS RMS {a.rms_m:.2f} m, scale {a.scale:.4g})' if a else 'not metric (no usable GPS)'
    )
    print(line + f', {res.timing["total"]:.1f} s')
    if args.out:
        Path(args.out).write_text(json.dumps(doc, indent=2) + '\n', encoding='utf-8')
    elif not args.npz:
        json.dump(doc, sys.stdout, indent=2)
        print()
    if args.npz:
        obs = [
            np.column_stack([np.full(len(o), i), o, ids])
            for i, (o, ids) in enumerate(zip(res.observations, res.observation_ids))
        ]
        np.savez_compressed(
            args.npz,
            poses=res.poses,
            registered=res.registered,
            stamps_ns=reg.stamps_ns,
            k=res.camera.k,
            d=res.camera.d,
            image_size=np.array([res.camera.width, res.camera.height]),
            points=res.points,
            colors=res.colors,
            track_lengths=res.track_lengths,
            point_errors=res.point_errors,
            observations=np.concatenate(obs) if obs else np.zeros((0, 5)),
        )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'register',
        help='register the camera images of a bag by SfM (COLMAP, CPU); metric ENU when it has GPS',
        description='Camera registration with one shared camera; with NavSatFix the model is aligned '
        'to ENU metres (origin: the first fix). --npz observations rows are '
        '(image, u, v, z-depth, point index).',
    )
    p.add_argument('bag', metavar='BAG', help='rosbag2 directory, .mcap, .db3 or ROS 1 .bag')
    p.add_argument('--out', metavar='JSON', help='write the result document here (default: stdout)')
    p.add_argument('--npz', metavar='FILE', help='also write poses, camera, points and observations (.npz)')
    p.add_argument('--max-images', type=int, default=None, help='use at most N images, evenly spread')
    p.add_argument('--image-topic', default=None, help='camera image topic (default: detected)')
    p.add_argument('--gps', action=argparse.BooleanOptionalAction, default=True, help='align to GPS')
    p.add_argument(
        '--camera-model',
        default='SIMPLE_RADIAL',
        choices=['SIMPLE_PINHOLE', 'PINHOLE', 'SIMPLE_RADIAL', 'RADIAL', 'OPENCV'],
    )
    p.add_argument('--max-image-size', type=int, default=1600, help='longest side (px) for SIFT')
    p.add_argument('--max-features', type=int, default=4096, help='SIFT features per image')
    p.add_argument('--fast', action='store_true', help='no 2x upsampling for SIFT: ~3x faster, fewer points')
    p.add_argument('--workdir', default=None, help='keep COLMAP images, database and models here')
    p.set_defaults(func=run)
