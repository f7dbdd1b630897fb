# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Synthetic oblique drone flights over a procedural town with exact ground truth.

Our stand-in for the paper's GTAV set: :func:`build_scene` makes the town, :func:`make_trajectory`
a flight, :func:`render_view` one frame (uint8 rgb, float32 z-depth with +inf sky, sky mask,
class labels). :func:`render_flight` chains the three.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.synth.render import (
    LABEL_BUILDING_WALL,
    LABEL_GROUND,
    LABEL_HILL,
    LABEL_NAMES,
    LABEL_ROAD,
    LABEL_ROOF,
    LABEL_SKY,
    LABEL_TREE,
    SynthFrame,
    render_view,
    shade_rays,
)
from ibr_ros.core.synth.scene import Scene, SceneConfig, build_scene
from ibr_ros.core.synth.trajectory import TrajectoryKind, TrajectorySample, make_trajectory

__all__ = [
    'LABEL_BUILDING_WALL',
    'LABEL_GROUND',
    'LABEL_HILL',
    'LABEL_NAMES',
    'LABEL_ROAD',
    'LABEL_ROOF',
    'LABEL_SKY',
    'LABEL_TREE',
    'Scene',
    'SceneConfig',
    'SynthFrame',
    'TrajectoryKind',
    'TrajectorySample',
    'build_scene',
    'flight_camera',
    'make_trajectory',
    'render_flight',
    'render_view',
    'safe_altitude_range',
    'shade_rays',
]


def flight_camera(size: tuple[int, int] = (640, 360), hfov_deg: float = 70.0) -> PinholeCamera:
    """Ideal pinhole camera of ``size = (width, height)`` pixels and horizontal FOV in degrees."""
    return PinholeCamera.from_fov(int(size[0]), int(size[1]), hfov_deg)


def safe_altitude_range(
    cfg: SceneConfig, altitude_range: tuple[float, float] = (15.0, 80.0)
) -> tuple[float, float]:
    """``altitude_range`` (m) with its floor raised to clear every building and tree by 5 m."""
    lo, hi = sorted(altitude_range)
    lo = max(lo, cfg.max_height_m + 5.0)
    return lo, max(hi, lo + 10.0)


def render_flight(
    cfg: SceneConfig,
    kind: TrajectoryKind,
    duration_s: float = 20.0,
    fps: float = 15.0,
    size: tuple[int, int] = (640, 360),
    hfov_deg: float = 70.0,
    progress: Callable[[int, int], None] | None = None,
    *,
    altitude_range: tuple[float, float] = (15.0, 80.0),
    pitch_range_deg: tuple[float, float] = (-60.0, -15.0),
    antialias: bool = True,
) -> Iterator[tuple[TrajectorySample, SynthFrame]]:
    """Build the scene of ``cfg``, fly ``kind`` over it and yield (pose sample, frame) per frame.

    The trajectory uses ``cfg.seed``, ``cfg.extent_m`` and ``pitch_range_deg`` (degrees, negative =
    looking down; a view whose pitch is above minus half its vertical FOV sees the horizon); its
    altitude floor is raised by :func:`safe_altitude_range` so the drone never flies through a
    building. ``progress(done, total)`` is called after every frame.
    """
    scene = build_scene(cfg)
    camera = flight_camera(size, hfov_deg)
    samples = make_trajectory(
        kind,
        duration_s=duration_s,
        fps=fps,
        seed=cfg.seed,
        altitude_range=safe_altitude_range(cfg, altitude_range),
        pitch_range_deg=pitch_range_deg,
        extent_m=cfg.extent_m,
    )
    for i, s in enumerate(samples):
        frame = render_view(scene, camera, s.t_wc, antialias=antialias)
        if progress is not None:
            progress(i + 1, len(samples))
        yield s, frame
