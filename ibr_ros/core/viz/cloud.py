# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""A keyframe's refined depth as a decimated, coloured world point cloud."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import validate_pose

__all__ = ['CloudConfig', 'grid', 'keyframe_points']


@dataclass(frozen=True)
class CloudConfig:
    """Which pixels of a keyframe become points.

    ``stride``: every ``stride``-th pixel in x and y (the centre of each ``stride`` x ``stride``
    block); ``min_confidence``: pixels whose depth confidence is below are left out (no confidence
    map: every known depth counts as sure); ``max_points``: an upper bound per keyframe (the pixels
    left are thinned evenly), 0 = none.
    """

    stride: int = 2
    min_confidence: float = 0.5
    max_points: int = 50000

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ValueError(f'stride must be >= 1, got {self.stride}')
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f'min_confidence must be in [0, 1], got {self.min_confidence}')
        if self.max_points < 0:
            raise ValueError(f'max_points must be >= 0, got {self.max_points}')


def grid(image: ArrayLike, stride: int) -> NDArray[np.generic]:
    """The pixels of ``image`` (HxW or HxWxC) that :func:`keyframe_points` samples: the centre of
    every ``stride`` x ``stride`` block, a copy (what a node keeps of a keyframe)."""
    a = np.asarray(image)
    return np.ascontiguousarray(a[stride // 2 :: stride, stride // 2 :: stride])


def _on_grid(name: str, a: NDArray[np.generic], shape: tuple[int, int], s: int) -> NDArray[np.generic]:
    """``a`` on the stride grid: taken from a full-size image, or as is when already decimated."""
    full = a.shape[:2] == shape
    if not full and a.shape[:2] != ((shape[0] - s // 2 + s - 1) // s, (shape[1] - s // 2 + s - 1) // s):
        raise ValueError(f'{name} is {a.shape[:2]} (HxW): neither the camera {shape} nor its stride-{s} grid')
    return a[s // 2 :: s, s // 2 :: s] if full else a


def keyframe_points(
    depth: ArrayLike,
    rgb: ArrayLike,
    camera: PinholeCamera,
    t_wc: ArrayLike,
    confidence: ArrayLike | None = None,
    config: CloudConfig | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """``(xyz, rgb)``: Nx3 float32 world points (metres, the frame of ``t_wc``) and their Nx3 uint8
    colours, of the confident pixels of a keyframe on a ``config.stride`` grid.

    ``depth``: HxW z-depth in metres along the REP-103 optical axis (z forward, x right, y down);
    unknown (0, NaN, negative) and sky / far (+inf) pixels are left out. ``rgb``: HxWx3 uint8.
    Each of ``depth``, ``rgb`` and ``confidence`` is the full image or its :func:`grid` with
    ``config.stride``.
    ``t_wc``: 4x4 camera-to-world pose of the optical frame. Distortion is ignored (the camera's K
    only, as :meth:`PinholeCamera.backproject`). Pixels are taken in row-major order.

    Raises:
        ValueError: Shapes that do not match the camera, or a pose that is not rigid.

    """
    cfg = config or CloudConfig()
    s = cfg.stride
    shape = (camera.height, camera.width)
    d = np.asarray(_on_grid('depth', np.asarray(depth, dtype=np.float32), shape, s), dtype=np.float32)
    colour = np.asarray(rgb)
    if colour.ndim != 3 or colour.shape[2] != 3:
        raise ValueError(f'rgb must be HxWx3, got {colour.shape}')
    colour = _on_grid('rgb', colour, shape, s)
    pose = validate_pose(t_wc, field='t_wc')
    v, u = np.mgrid[s // 2 : camera.height : s, s // 2 : camera.width : s]
    if d.shape != u.shape or colour.shape[:2] != u.shape:
        raise ValueError(f'depth and rgb grids {d.shape} {colour.shape[:2]} differ from {u.shape}')
    with np.errstate(invalid='ignore'):
        keep = np.isfinite(d) & (d > 0)
    if confidence is not None:
        c = np.asarray(
            _on_grid('confidence', np.asarray(confidence, dtype=np.float32), shape, s), dtype=np.float32
        )
        keep &= c >= cfg.min_confidence
    z = d[keep]
    colour = colour[keep]
    u, v = u[keep], v[keep]
    if cfg.max_points and u.size > cfg.max_points:
        pick = np.linspace(0, u.size - 1, cfg.max_points).round().astype(np.int64)
        u, v, z, colour = u[pick], v[pick], z[pick], colour[pick]
    pc = camera.backproject(np.stack([u, v], axis=1), z)
    pw = pc @ pose[:3, :3].T + pose[:3, 3]
    return pw.astype(np.float32), np.ascontiguousarray(colour, dtype=np.uint8)
