# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Randomised synthetic views for training and evaluating the monocular depth + sky model.

Each scene seed gives a random :class:`~ibr_ros.core.synth.SceneConfig` (density of buildings and
trees, facade texture, sun, sky colour, clouds, hills) and each view a random pose: either a drone
view above the rooftops (pitch -75..+8 deg, so about 40% of views show sky) or a near-ground view
from just outside the town looking in (1.5..20 m, pitch -25..+10 deg), with a random horizontal FOV and
a small roll. Training uses seeds from :data:`TRAIN_SEED_BASE`, evaluation from
:data:`EVAL_SEED_BASE`: the two ranges never overlap.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import matrix_from_rt, rotation_from_ypr
from ibr_ros.core.synth import SceneConfig, build_scene, flight_camera, render_view

__all__ = [
    'EVAL_SEED_BASE',
    'TRAIN_SEED_BASE',
    'MonoSample',
    'random_scene_config',
    'random_view',
    'render_samples',
]

#: Scene seeds ``TRAIN_SEED_BASE + i`` train the shipped model; ``EVAL_SEED_BASE + i`` evaluate it.
TRAIN_SEED_BASE = 100_000
EVAL_SEED_BASE = 900_000


@dataclass
class MonoSample:
    """One rendered view: uint8 HxWx3 RGB, float32 z-depth (m, +inf = sky), sky mask, camera, pose."""

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    sky: NDArray[np.bool_]
    camera: PinholeCamera
    t_wc: NDArray[np.float64]
    seed: int


def random_scene_config(seed: int) -> SceneConfig:
    """A random town for ``seed`` (deterministic)."""
    rng = np.random.default_rng([seed, 1])
    zen = np.clip(np.array([0.28, 0.48, 0.82]) + rng.normal(0, 0.07, 3), 0.05, 0.95)
    hor = np.clip(np.array([0.74, 0.82, 0.90]) + rng.normal(0, 0.06, 3), 0.3, 1.0)
    hmin = float(rng.uniform(4.0, 10.0))
    return SceneConfig(
        seed=int(seed),
        extent_m=float(rng.choice([100.0, 150.0, 200.0])),
        block_m=float(rng.uniform(45.0, 75.0)),
        n_buildings=int(rng.integers(0, 90)),
        building_height_m=(hmin, hmin + float(rng.uniform(5.0, 35.0))),
        low_texture_fraction=float(rng.uniform(0.0, 0.6)),
        rotated_fraction=float(rng.uniform(0.0, 0.4)),
        park_fraction=float(rng.uniform(0.0, 0.4)),
        tree_density=float(rng.uniform(0.0, 2.5)),
        sun_azimuth_deg=float(rng.uniform(0.0, 360.0)),
        sun_elevation_deg=float(rng.uniform(12.0, 75.0)),
        sky_zenith_rgb=(float(zen[0]), float(zen[1]), float(zen[2])),
        sky_horizon_rgb=(float(hor[0]), float(hor[1]), float(hor[2])),
        cloud_cover=float(rng.uniform(0.0, 1.0)),
        hills=bool(rng.random() < 0.75),
    )


def random_view(
    cfg: SceneConfig, rng: np.random.Generator, size: tuple[int, int]
) -> tuple[PinholeCamera, NDArray[np.float64]]:
    """Random camera (``size = (width, height)``, hfov 50..90 deg) and camera-to-world pose for ``cfg``."""
    camera = flight_camera(size, float(rng.uniform(50.0, 90.0)))
    yaw = float(rng.uniform(0.0, 2 * math.pi))
    roll = math.radians(float(rng.normal(0.0, 3.0)))
    e = cfg.extent_m
    if rng.random() < 0.25:  # near the ground outside the town, looking roughly at its centre
        r = e + float(rng.uniform(5.0, 80.0))
        ang = float(rng.uniform(0.0, 2 * math.pi))
        pos = [r * math.cos(ang), r * math.sin(ang), float(rng.uniform(1.5, 20.0))]
        yaw = ang + math.pi + float(rng.uniform(-0.5, 0.5))
        pitch = float(rng.uniform(-25.0, 10.0))
    else:
        lo = cfg.max_height_m + 5.0
        pos = [*(float(v) for v in rng.uniform(-0.9 * e, 0.9 * e, 2)), lo + float(rng.exponential(35.0))]
        pitch = float(rng.uniform(-75.0, 8.0))
    t_wc = matrix_from_rt(rotation_from_ypr(yaw, math.radians(pitch), roll), pos)
    return camera, t_wc


def render_samples(
    seeds: list[int],
    views_per_scene: int,
    size: tuple[int, int],
    *,
    progress: Callable[[int, int], None] | None = None,
) -> list[MonoSample]:
    """Render ``views_per_scene`` random views of each scene seed (deterministic for equal arguments)."""
    out: list[MonoSample] = []
    total = len(seeds) * views_per_scene
    for seed in seeds:
        cfg = random_scene_config(seed)
        scene = build_scene(cfg)
        rng = np.random.default_rng([seed, 2])
        for _ in range(views_per_scene):
            camera, t_wc = random_view(cfg, rng, size)
            f = render_view(scene, camera, t_wc)
            out.append(MonoSample(f.rgb, f.depth, f.sky, camera, t_wc, seed))
            if progress is not None:
                progress(len(out), total)
    return out
