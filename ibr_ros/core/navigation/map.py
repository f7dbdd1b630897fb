# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The top-down map of the keyframe cameras: keyframe centres projected along the map's up axis
onto a ``size`` x ``size`` pixel canvas (u right, v down; the map's first horizontal axis, east
for ENU, to the right, the second, north, up), fitted to the keyframes with a margin."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['MapKeyframe', 'TopDownMap']


@dataclass(frozen=True)
class MapKeyframe:
    """A keyframe on the map: its stamp (ns), canvas position (px) and heading (rad, canvas angle of
    its optical axis: 0 = right, positive = clockwise as v grows down)."""

    stamp: int
    u: float
    v: float
    heading: float

    def to_json(self) -> dict[str, float | int]:
        return {
            'stamp': self.stamp,
            'u': round(self.u, 2),
            'v': round(self.v, 2),
            'heading': round(self.heading, 4),
        }


class TopDownMap:
    """Keyframe poses (camera-to-world, map frame) and their projection on the map canvas."""

    def __init__(self, size_px: int = 256, margin_px: int = 16, up: ArrayLike = (0.0, 0.0, 1.0)) -> None:
        u = np.asarray(up, dtype=np.float64)
        self.up = u / np.linalg.norm(u)
        seed = np.eye(3)[int(np.argmin(np.abs(self.up)))]  # the map axis least along up
        e1 = seed - (seed @ self.up) * self.up
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.up, self.e1)  # e1, e2, up right-handed: east, north, up for ENU
        self.size = int(size_px)
        self.margin = int(margin_px)
        self.poses: dict[int, NDArray[np.float64]] = {}
        self._centre = np.zeros(2)
        self._scale = 1.0

    def add(self, stamp: int, t_wc: ArrayLike) -> bool:
        """Add (or move) keyframe ``stamp``; whether the map changed (the fit is redone)."""
        t = np.asarray(t_wc, dtype=np.float64)
        old = self.poses.get(stamp)
        if old is not None and np.array_equal(old, t):
            return False
        self.poses[stamp] = t.copy()
        xy = np.array([[p[:3, 3] @ self.e1, p[:3, 3] @ self.e2] for p in self.poses.values()])
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        self._centre = (lo + hi) / 2
        span = float(max(hi[0] - lo[0], hi[1] - lo[1]))
        self._scale = (self.size - 2 * self.margin) / span if span > 1e-9 else 1.0
        return True

    def project(self, t_wc: ArrayLike) -> tuple[float, float, float]:
        """Canvas ``(u, v, heading)`` of camera pose ``t_wc`` (see :class:`MapKeyframe`)."""
        t = np.asarray(t_wc, dtype=np.float64)
        p, z = t[:3, 3], t[:3, 2]
        u = self.size / 2 + (p @ self.e1 - self._centre[0]) * self._scale
        v = self.size / 2 - (p @ self.e2 - self._centre[1]) * self._scale
        return float(u), float(v), math.atan2(-float(z @ self.e2), float(z @ self.e1))

    def keyframes(self) -> list[MapKeyframe]:
        """Every keyframe on the canvas, oldest first."""
        return [MapKeyframe(s, *self.project(self.poses[s])) for s in sorted(self.poses)]

    def pick(self, u: float, v: float, radius_px: float = 12.0) -> int | None:
        """Stamp of the keyframe nearest canvas point ``(u, v)`` within ``radius_px``, or None."""
        best, best_d = None, radius_px
        for k in self.keyframes():
            d = math.hypot(k.u - u, k.v - v)
            if d <= best_d:
                best, best_d = k.stamp, d
        return best
