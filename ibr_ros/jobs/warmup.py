# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Compile (or load from numba's cache) the kernels the nodes run, before they report ready.

``python -m ibr_ros.jobs.warmup`` runs once at ``make install`` from the installed package, so that
numba's cache next to the installed modules holds every kernel and each node's first start loads
them instead of compiling (tens of seconds on 2 cores). The nodes call :func:`warm_up_refiner` and
:func:`warm_up_renderer` themselves at start-up (a few tenths of a second once cached).

The scene: a textured ground plane seen by three cameras 20 m above it, 1.5 m apart (exact
geometry, so MVS, refinement and rendering all run their normal paths).
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import replace

import cv2
import numpy as np

from ibr_ros.core.depth.mvs import MvsOptions, MvsView, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView

__all__ = ['main', 'plane_views', 'warm_up_refiner', 'warm_up_renderer']


def plane_views(n: int = 3, size: tuple[int, int] = (96, 64)) -> list[MvsView]:
    """``n`` views (``size`` = width, height) of a random-textured plane z = 0, from 20 m up."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (512, 512, 3), dtype=np.uint8), (0, 0), 1.0)
    tex_to_plane = np.array([[0.1, 0.0, -25.6], [0.0, 0.1, -25.6], [0.0, 0.0, 1.0]])  # 0.1 m per texel
    cam = PinholeCamera.from_fov(size[0], size[1], 60.0)
    views = []
    for i in range(n):
        t_wc = look_at([1.5 * i, -6.0, 20.0], [1.5 * i, 0.0, 0.0])
        t_cw = np.linalg.inv(t_wc)
        plane_to_img = cam.k @ np.column_stack([t_cw[:3, 0], t_cw[:3, 1], t_cw[:3, 3]])
        rgb = cv2.warpPerspective(texture, plane_to_img @ tex_to_plane, size, flags=cv2.INTER_LINEAR)
        views.append(MvsView(np.ascontiguousarray(rgb), cam, t_wc))
    return views


def warm_up_refiner(mvs: MvsOptions, refiner: DepthRefiner) -> float:
    """One MVS + refinement of :func:`plane_views` with these settings; the seconds it took."""
    t0 = time.perf_counter()
    views = plane_views()
    depth = compute_depth_maps(views, options=replace(mvs, max_neighbours=2), depth_range=(10.0, 60.0))[0]
    with contextlib.suppress(RefineError):  # too little MVS depth: the kernels ran all the same
        refiner.refine_from_mvs(views[0], depth.depth)
    return time.perf_counter() - t0


def warm_up_renderer(config: RenderConfig) -> float:
    """One render with ``config`` from :func:`plane_views` (exact plane depth); the seconds it took."""
    t0 = time.perf_counter()
    views = plane_views()
    sources = []
    for v in views:
        h, w = v.rgb.shape[:2]
        rays = np.linalg.inv(v.camera.k) @ np.stack(
            [*np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), np.ones((h, w))]
        ).reshape(3, -1)
        r, c = v.t_wc[:3, :3], v.t_wc[:3, 3]
        z = -c[2] / (r[2] @ rays)  # z-depth where each pixel's ray meets the plane z = 0
        sources.append(SourceView(v.rgb, z.reshape(h, w).astype(np.float32), v.camera, v.t_wc))
    query = look_at([2.0, -6.0, 20.0], [2.0, 0.0, 0.0])
    NovelViewRenderer(sources, replace(config, n_segments=40)).render(query, views[0].camera)
    return time.perf_counter() - t0


def main() -> int:
    """Warm every kernel of the nodes up (the default configurations); one line of timings."""
    t_ref = warm_up_refiner(MvsOptions(), DepthRefiner(RefinerConfig()))
    t_ren = warm_up_renderer(RenderConfig())
    print(f'ibr_ros warm-up: refiner kernels {t_ref:.1f} s, renderer kernels {t_ren:.1f} s', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
