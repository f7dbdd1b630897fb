# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Smooth oblique drone trajectories over the synthetic town (ENU metres, optical-frame poses).

Every pose is ``rotation_from_ypr(yaw, pitch, 0)`` at a position: the camera never rolls, the
pitch stays inside ``pitch_range_deg`` and the altitude inside ``altitude_range``. Kinds:

* ``orbit``: circle around a point near the town centre, looking at it;
* ``lawnmower``: back-and-forth lanes joined by half circles, looking ahead and down;
* ``forward``: a gently curving line from the edge of the town across it, looking ahead and
  down, steering back towards the centre whenever it gets beyond the town.

All randomness comes from ``numpy.random.default_rng(seed)``; positions are C1 and angles
continuous functions of time (no jumps between frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.transforms import matrix_from_rt, rotation_from_ypr

__all__ = ['TrajectoryKind', 'TrajectorySample', 'make_trajectory']

TrajectoryKind = Literal['orbit', 'lawnmower', 'forward']


@dataclass(frozen=True, eq=False)
class TrajectorySample:
    """Time stamp (s from the start of the flight) and 4x4 camera-to-world pose."""

    t_s: float
    t_wc: NDArray[np.float64]


def _lawnmower_xy(sigma: float, lane_len: float, spacing: float, n_lanes: int) -> tuple[float, float, float]:
    """Position (along, across) and heading (rad, in the lane frame) at arc length sigma (m).

    Lanes are visited 0, 1, ..., n-1, n-2, ..., 0, 1, ... (alternating directions), joined by half
    circles of diameter ``spacing``.
    """
    period = lane_len + math.pi * spacing / 2
    m = int(sigma // period)
    rem = sigma - m * period
    direction = 1.0 if m % 2 == 0 else -1.0

    def lane(k: int) -> float:
        q = k % (2 * (n_lanes - 1))
        q = q if q < n_lanes else 2 * (n_lanes - 1) - q
        return (q - (n_lanes - 1) / 2) * spacing

    across0 = lane(m)
    if rem < lane_len:
        return direction * (rem - lane_len / 2), across0, 0.0 if direction > 0 else math.pi
    shift = lane(m + 1) - across0
    a = (rem - lane_len) / (spacing / 2)
    along = direction * (lane_len / 2 + spacing / 2 * math.sin(a))
    across = across0 + shift / 2 * (1 - math.cos(a))
    heading = math.atan2(shift / 2 * math.sin(a), direction * spacing / 2 * math.cos(a))
    return along, across, heading


def _preferred(rng: np.random.Generator, lo: float, hi: float, pref_lo: float, pref_hi: float) -> float:
    """Uniform in the overlap of [lo, hi] and the preferred [pref_lo, pref_hi]; in [lo, hi] if none."""
    a, b = max(lo, pref_lo), min(hi, pref_hi)
    return float(rng.uniform(a, b) if a <= b else rng.uniform(lo, hi))


def make_trajectory(
    kind: TrajectoryKind,
    *,
    duration_s: float = 20.0,
    fps: float = 15.0,
    seed: int = 0,
    altitude_range: tuple[float, float] = (15.0, 80.0),
    pitch_range_deg: tuple[float, float] = (-60.0, -15.0),
    extent_m: float = 150.0,
    speed_mps: float = 8.0,
) -> list[TrajectorySample]:
    """Sample a flight of ``round(duration_s * fps)`` poses at ``t = i / fps`` (see module docstring).

    ``altitude_range`` (m above ground) and ``pitch_range_deg`` (negative = looking down) bound the
    flight; ``extent_m`` is the town half-size and ``speed_mps`` the ground speed.
    """
    if kind not in ('orbit', 'lawnmower', 'forward'):
        raise ValueError(f"kind must be 'orbit', 'lawnmower' or 'forward', got {kind!r}")
    if duration_s <= 0 or fps <= 0:
        raise ValueError(f'duration_s and fps must be positive, got {duration_s}, {fps}')
    alo, ahi = sorted(float(a) for a in altitude_range)
    plo, phi = sorted(math.radians(p) for p in pitch_range_deg)
    if alo <= 0 or phi >= 0:
        raise ValueError('altitudes must be positive and pitches negative (looking down)')
    rng = np.random.default_rng(seed)
    n = max(1, round(duration_s * fps))
    ts = np.arange(n) / fps
    e = float(extent_m)
    span = ahi - alo

    def pose(x: float, y: float, z: float, yaw: float, pitch: float) -> NDArray[np.float64]:
        pitch = min(max(pitch, plo), phi)
        return matrix_from_rt(rotation_from_ypr(yaw, pitch, 0.0), [x, y, min(max(z, alo), ahi)])

    out: list[TrajectorySample] = []
    if kind == 'orbit':
        radius = e * rng.uniform(0.8, 1.2)
        alt0 = rng.uniform(alo + 0.3 * span, ahi - 0.1 * span)
        alt_amp, alt_w = 0.08 * span, rng.uniform(0.1, 0.3)
        w = speed_mps / radius * (1 if rng.random() < 0.5 else -1)
        phi0 = rng.uniform(0, 2 * math.pi)
        tx0, ty0 = rng.normal(0.0, 0.08 * e, size=2)
        for t in ts:
            ang = phi0 + w * t
            x, y = radius * math.cos(ang), radius * math.sin(ang)
            z = alt0 + alt_amp * math.sin(alt_w * t)
            gx, gy = tx0 + 6.0 * math.sin(0.13 * t), ty0 + 6.0 * math.cos(0.11 * t)
            yaw = math.atan2(gy - y, gx - x)
            pitch = -math.atan2(z, math.hypot(gx - x, gy - y))
            out.append(TrajectorySample(float(t), pose(x, y, z, yaw, pitch)))
    elif kind == 'lawnmower':
        spacing = rng.uniform(35.0, 60.0)
        n_lanes = max(2, int(1.2 * e // spacing) + 1)
        lane_len = 1.6 * e
        psi = rng.uniform(0, 2 * math.pi)
        alt0 = rng.uniform(alo + 0.3 * span, ahi - 0.1 * span)
        pitch0 = _preferred(rng, plo, phi, math.radians(-55), math.radians(-30))
        sigma0 = rng.uniform(0.0, 0.5 * lane_len)
        cp, sp = math.cos(psi), math.sin(psi)
        for t in ts:
            along, across, head = _lawnmower_xy(sigma0 + speed_mps * t, lane_len, spacing, n_lanes)
            x, y = cp * along - sp * across, sp * along + cp * across
            z = alt0 + 0.05 * span * math.sin(0.2 * t)
            pitch = pitch0 + math.radians(3.0) * math.sin(0.3 * t)
            out.append(TrajectorySample(float(t), pose(x, y, z, psi + head, pitch)))
    else:
        start_ang = rng.uniform(0, 2 * math.pi)
        x, y = 1.15 * e * math.cos(start_ang), 1.15 * e * math.sin(start_ang)
        head = start_ang + math.pi + math.radians(rng.uniform(-20.0, 20.0))
        turn = math.radians(rng.uniform(-2.5, 2.5))  # rad/s
        alt0 = rng.uniform(alo + 0.3 * span, ahi - 0.2 * span)
        alt_amp, alt_w = 0.15 * span, rng.uniform(0.05, 0.15)
        pitch0 = _preferred(rng, plo, phi, math.radians(-45), math.radians(-20))
        # Integrate the heading: a constant turn rate plus, once beyond the town, steering back
        # towards its centre (so long flights stay over the town); 20 sub-steps per frame.
        sub = 20
        dt = 1.0 / (fps * sub)
        for i, t in enumerate(ts):
            if i > 0:
                for _ in range(sub):
                    to_c = math.atan2(-y, -x) - head
                    to_c = math.atan2(math.sin(to_c), math.cos(to_c))
                    away = min(max((math.hypot(x, y) - 0.9 * e) / (0.4 * e), 0.0), 1.0)
                    head += (turn + 0.25 * away * away * (3 - 2 * away) * to_c) * dt
                    x += speed_mps * math.cos(head) * dt
                    y += speed_mps * math.sin(head) * dt
            z = alt0 + alt_amp * math.sin(alt_w * t)
            pitch = pitch0 + math.radians(4.0) * math.sin(0.25 * t)
            out.append(TrajectorySample(float(t), pose(x, y, z, head, pitch)))
    return out
