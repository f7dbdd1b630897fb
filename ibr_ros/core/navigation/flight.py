# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Camera motion from key and mouse input: the pose is a 4x4 camera-to-world matrix of the REP-103
optical frame (z forward, x right, y down) in the map frame, whose ``up`` axis is given (REP-103
map frames: ENU, z up)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['Motion', 'NavigationError', 'Navigator', 'scene_speed']

#: Longest time step one input may integrate (s): a stalled page does not teleport the camera.
MAX_DT_S = 0.25
#: Largest elevation of the optical axis above or below the horizon (deg): no flipping over the pole.
MAX_ELEVATION_DEG = 89.0


class NavigationError(ValueError):
    """A malformed input message; the text names the field and the value."""


def _axis(msg: Mapping[str, object], name: str, lo: float = -1.0, hi: float = 1.0) -> float:
    value = msg.get(name, 0.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise NavigationError(f'input field {name} must be a finite number, got {value!r}')
    if not lo <= value <= hi:
        raise NavigationError(f'input field {name} must be {lo:g}..{hi:g}, got {value!r}')
    return float(value)


@dataclass(frozen=True)
class Motion:
    """One input step of the page.

    ``forward`` (W/S), ``right`` (D/A), ``up`` (E/Q), ``yaw`` (left arrow +, turn left) and ``pitch``
    (up arrow +) are key axes in -1..1 held for ``dt`` seconds; ``drag_px`` is the mouse drag since
    the last step (x right, y down, pixels: dragging right turns right, dragging down looks down);
    ``fast`` multiplies the speed (Shift).
    """

    forward: float = 0.0
    right: float = 0.0
    up: float = 0.0
    yaw: float = 0.0
    pitch: float = 0.0
    drag_px: tuple[float, float] = (0.0, 0.0)
    dt: float = 0.0
    fast: bool = False

    @classmethod
    def from_json(cls, msg: Mapping[str, object]) -> Motion:
        """The motion of a page's ``fly`` message; :class:`NavigationError` naming a bad field."""
        drag = msg.get('drag', [0.0, 0.0])
        if not isinstance(drag, (list, tuple)) or len(drag) != 2:
            raise NavigationError(f'input field drag must be [dx, dy] in pixels, got {drag!r}')
        dx, dy = (_axis({'drag': d}, 'drag', -1e4, 1e4) for d in drag)
        fast = msg.get('fast', False)
        if not isinstance(fast, bool):
            raise NavigationError(f'input field fast must be true or false, got {fast!r}')
        return cls(
            forward=_axis(msg, 'forward'),
            right=_axis(msg, 'right'),
            up=_axis(msg, 'up'),
            yaw=_axis(msg, 'yaw'),
            pitch=_axis(msg, 'pitch'),
            drag_px=(dx, dy),
            dt=_axis(msg, 'dt', 0.0, 1e6),
            fast=fast,
        )

    @property
    def still(self) -> bool:
        """Whether this step moves nothing."""
        keys = (self.forward, self.right, self.up, self.yaw, self.pitch)
        return (self.dt == 0.0 or not any(keys)) and self.drag_px == (0.0, 0.0)


def _rotation(axis: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """Right-handed rotation by ``angle`` (rad) about unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def scene_speed(positions: Sequence[ArrayLike], spacings_per_s: float, default_mps: float) -> float:
    """Flying speed (m/s): ``spacings_per_s`` times the median distance from each keyframe centre
    (map frame, m) to its nearest other one; ``default_mps`` with fewer than two distinct centres."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return default_mps
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
    d[d <= 1e-9] = np.inf  # itself and duplicates
    nearest = d.min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    if nearest.size == 0:
        return default_mps
    return float(spacings_per_s * np.median(nearest))


class Navigator:
    """The viewer's camera: applies :class:`Motion` steps to the pose.

    Translation is in the camera frame (W/S along the optical axis z, D/A along x, E/Q along -y /
    +y) at ``speed_mps`` (x ``fast_factor`` with Shift); yaw turns about the map's ``up`` axis (the
    horizon stays level), pitch about the camera x axis, keeping the optical axis within
    :data:`MAX_ELEVATION_DEG` of the horizon (a pose already beyond it may only come back).
    """

    def __init__(
        self,
        t_wc: ArrayLike,
        *,
        speed_mps: float = 1.0,
        turn_rate_deg_s: float = 60.0,
        drag_deg_per_px: float = 0.2,
        fast_factor: float = 4.0,
        up: ArrayLike = (0.0, 0.0, 1.0),
    ) -> None:
        u = np.asarray(up, dtype=np.float64)
        if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-9:
            raise NavigationError(f'up axis must be a non-zero 3-vector, got {up!r}')
        self.up = u / np.linalg.norm(u)
        self.speed_mps = float(speed_mps)
        self.turn_rate_deg_s = float(turn_rate_deg_s)
        self.drag_deg_per_px = float(drag_deg_per_px)
        self.fast_factor = float(fast_factor)
        self.t_wc = np.eye(4)
        self.jump(t_wc)

    def jump(self, t_wc: ArrayLike) -> NDArray[np.float64]:
        """Put the camera at ``t_wc`` (4x4 camera-to-world); the new pose (a copy)."""
        t = np.array(t_wc, dtype=np.float64)
        if t.shape != (4, 4) or not np.isfinite(t).all():
            raise NavigationError(f'pose must be a finite 4x4 matrix, got shape {t.shape}')
        self.t_wc = t
        return self.pose

    @property
    def pose(self) -> NDArray[np.float64]:
        """The current camera-to-world pose (a copy)."""
        return self.t_wc.copy()

    def elevation_deg(self) -> float:
        """Angle of the optical axis above the horizon (deg, negative: looking down)."""
        z = self.t_wc[:3, 2]
        return math.degrees(math.asin(float(np.clip(z @ self.up, -1.0, 1.0))))

    def step(self, m: Motion) -> NDArray[np.float64]:
        """Apply motion ``m`` (``dt`` capped at :data:`MAX_DT_S`); the new pose (a copy)."""
        dt = min(max(m.dt, 0.0), MAX_DT_S)
        r = self.t_wc[:3, :3]
        yaw = math.radians(m.yaw * self.turn_rate_deg_s * dt - m.drag_px[0] * self.drag_deg_per_px)
        pitch = math.radians(m.pitch * self.turn_rate_deg_s * dt - m.drag_px[1] * self.drag_deg_per_px)
        if pitch:
            e = self.elevation_deg()
            lo, hi = min(-MAX_ELEVATION_DEG, e), max(MAX_ELEVATION_DEG, e)
            pitch = math.radians(float(np.clip(e + math.degrees(pitch), lo, hi)) - e)
        if pitch:  # R Rx(a): the optical axis z turns towards -y (up in the image)
            c, s = math.cos(pitch), math.sin(pitch)
            r = r @ np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        if yaw:  # about the map's up axis: positive turns left
            r = _rotation(self.up, yaw) @ r
        speed = self.speed_mps * (self.fast_factor if m.fast else 1.0) * dt
        move = r @ np.array([m.right, -m.up, m.forward]) * speed
        u, _, vt = np.linalg.svd(r)  # keep it a rotation over thousands of steps
        t = np.eye(4)
        t[:3, :3] = u @ vt
        t[:3, 3] = self.t_wc[:3, 3] + move
        self.t_wc = t
        return self.pose
