# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Robust plane fitting to 3-D points (world frame, metres)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ['fit_ground_plane']


def fit_ground_plane(
    points_w: NDArray[np.floating],
    *,
    iterations: int = 100,
    inlier_m: float | None = None,
    seed: int = 0,
    max_points: int = 5000,
) -> NDArray[np.float64]:
    """Robust plane ``n . p + d = 0`` (``n`` unit, pointing up: n_z > 0) through Nx3 world points.

    RANSAC on 3-point samples (on at most ``max_points`` random points), then a least-squares refit
    on the inliers. ``inlier_m`` defaults to 2% of the points' spread. Returns ``(nx, ny, nz, d)``.
    """
    p = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) > max_points:
        p = p[np.random.default_rng(seed).choice(len(p), max_points, replace=False)]
    if len(p) < 3:
        raise ValueError(f'points_w needs >= 3 finite points to fit a plane, got {len(p)}')
    spread = float(np.linalg.norm(p.std(axis=0)))
    tol = inlier_m if inlier_m is not None else max(0.02 * spread, 1e-6)
    rng = np.random.default_rng(seed)
    best = np.zeros(len(p), bool)
    for _ in range(iterations):
        a, b, c = p[rng.choice(len(p), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        inl = np.abs((p - a) @ n) < tol
        if inl.sum() > best.sum():
            best = inl
    q = p[best] if best.sum() >= 3 else p
    centre = q.mean(axis=0)
    n = np.linalg.svd(q - centre, full_matrices=False)[2][-1]
    if n[2] < 0:
        n = -n
    return np.array([*n, -float(n @ centre)])
