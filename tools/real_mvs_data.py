#!/usr/bin/env python3
# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Real photos with MVS depth for the monocular model: register a bag, compute MVS depth, save an npz.

MegaDepth's idea on a small scale: multi-view reconstructions of real photos supervise single-view
depth. The bag's images are registered with SfM (:func:`ibr_ros.jobs.register_bag.register_bag`,
GPS-aligned when the bag has fixes), undistorted, resized to ``--width`` and given geometrically
filtered MVS depth (:func:`ibr_ros.core.depth.mvs.compute_depth_maps`, depth range from the sparse points).
Output ``--out`` (npz): ``rgb`` NxHxWx3 uint8, ``depth`` NxHxW float32 z-depth in metres (0 =
unknown), ``k`` Nx3x3 intrinsics and ``t_wc`` Nx4x4 camera-to-world poses of the registered images.
Used by ``tools/train_mono.py --real`` (sparse supervision) and ``ibr eval mono --real-mvs``.

Example (brighton_beach, about 2 minutes here)::

    .venv/bin/python tools/real_mvs_data.py bags/brighton_beach --out /tmp/ibr_mono_train/real_brighton.npz
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

LOG = logging.getLogger('real_mvs_data')


def main(argv: list[str] | None = None) -> int:
    from ibr_ros.core.depth.mvs import MvsOptions, MvsView, compute_depth_maps
    from ibr_ros.core.geometry.undistort import undistort_image
    from ibr_ros.jobs.register_bag import register_bag

    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('bag', type=Path)
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--width', type=int, default=640, help='MVS and output image width (px)')
    p.add_argument('--max-images', type=int, default=None)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format='%(asctime)s %(message)s')
    t0 = time.monotonic()
    reg = register_bag(args.bag, max_images=args.max_images)
    res = reg.result
    LOG.info('SfM: %d/%d registered, %.2f px (%.0f s)', res.num_registered, len(res.registered),
             res.mean_reprojection_error_px, time.monotonic() - t0)  # fmt: skip
    import msg_utils
    from ibr_ros.bag import open_bag

    wanted = set(reg.indices.tolist())
    with open_bag(args.bag) as reader:
        messages = enumerate(reader.messages([reg.topics.image]))
        images = [msg_utils.camera_image_to_rgb(m.msg) for i, m in messages if i in wanted]
    views = []
    for rgb, ok, t_wc in zip(images, res.registered, res.poses, strict=True):
        if not ok:
            continue
        und, cam = undistort_image(rgb, res.camera)
        small_cam = cam.scaled(args.width / cam.width)
        small = cv2.resize(und, (small_cam.width, small_cam.height), interpolation=cv2.INTER_AREA)
        views.append(MvsView(small, small_cam, t_wc))
    t1 = time.monotonic()
    maps = compute_depth_maps(
        views,
        options=MvsOptions(),
        points_w=res.points,
        progress=lambda d, n: LOG.info('MVS %d/%d (%.0f s)', d, n, time.monotonic() - t1),
    )
    depth = np.stack([np.where(m.depth > 0, m.depth, 0).astype(np.float32) for m in maps])
    LOG.info('MVS completeness: mean %.2f', float((depth > 0).mean()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix('.tmp.npz')
    np.savez_compressed(
        tmp,
        rgb=np.stack([v.rgb for v in views]),
        depth=depth,
        k=np.stack([v.camera.k for v in views]),
        t_wc=np.stack([v.t_wc for v in views]),
    )
    tmp.replace(args.out)
    LOG.info('wrote %s: %d views in %.0f s', args.out, len(views), time.monotonic() - t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
