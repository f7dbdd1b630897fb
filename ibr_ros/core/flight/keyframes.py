# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe selection for a drone video: reject blurred frames, keep frames that moved enough.

The paper subsamples 20-30 images per flight. A frame becomes a keyframe when it is sharp and,
relative to the last keyframe, its camera moved by at least ``baseline_ratio`` x the scene depth
(or ``min_baseline_m`` when the depth is unknown), turned by ``max_rotation_deg``, or
``max_interval_s`` passed. Poses are 4x4 camera-to-world matrices (metres); stamps are nanoseconds.

Without poses (SfM mode), :class:`IntervalSelector` keeps the sharpest frame of every
``interval_s`` window instead.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Generic, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.transforms import rotation_angle_deg

__all__ = [
    'Decision',
    'IntervalSelector',
    'KeyframeConfig',
    'KeyframeSelector',
    'TargetSelection',
    'blur_score',
    'select_keyframes',
    'select_keyframes_for_target',
    'target_baseline',
]

T = TypeVar('T')


def blur_score(image: NDArray[np.uint8], *, max_side: int = 480) -> float:
    """Sharpness as the variance of the Laplacian of the gray image (higher = sharper).

    Colour images are converted to gray; images larger than ``max_side`` are downscaled first (by
    an integer factor with INTER_AREA) so the score costs about the same at any resolution and is
    comparable between frames of one camera.
    """
    img = np.asarray(image)
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    step = max(1, math.ceil(max(gray.shape) / max_side))
    if step > 1:
        gray = cv2.resize(gray, (gray.shape[1] // step, gray.shape[0] // step), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(gray, cv2.CV_32F).var())


@dataclass(frozen=True)
class KeyframeConfig:
    """Thresholds of :class:`KeyframeSelector` (see the module docstring).

    ``blur_ratio``: a frame is blurred when its :func:`blur_score` is below ``blur_ratio`` x the
    median score of the last ``blur_window`` frames (and below ``min_blur_score`` absolutely).
    """

    baseline_ratio: float = 0.08
    min_baseline_m: float = 2.0
    max_rotation_deg: float = 15.0
    max_interval_s: float = 0.0
    min_interval_s: float = 0.0
    blur_ratio: float = 0.6
    min_blur_score: float = 0.0
    blur_window: int = 15

    def __post_init__(self) -> None:
        for name in (
            'baseline_ratio',
            'min_baseline_m',
            'max_rotation_deg',
            'max_interval_s',
            'min_interval_s',
        ):
            if getattr(self, name) < 0:
                raise ValueError(f'KeyframeConfig.{name} must be >= 0, got {getattr(self, name)}')
        if not 0 <= self.blur_ratio <= 1:
            raise ValueError(f'KeyframeConfig.blur_ratio must be in [0, 1], got {self.blur_ratio}')
        if self.blur_window < 1:
            raise ValueError(f'KeyframeConfig.blur_window must be >= 1, got {self.blur_window}')


def target_baseline(target_keyframes: int, expected_path_m: float) -> float | None:
    """The live keyframe baseline (m) for about ``target_keyframes`` over ``expected_path_m`` metres of
    flight path: ``expected_path_m / target_keyframes``; None when ``target_keyframes`` is 0 (off).

    Live, the flight's length is unknown: this ONE threshold replaces ``baseline_ratio`` x the scene
    depth and ``min_baseline_m``. Offline, :func:`select_keyframes_for_target` meets the target over
    the known flight instead.

    Raises:
        ValueError: ``target_keyframes`` < 0, or > 0 without ``expected_path_m`` > 0.

    """
    if target_keyframes < 0:
        raise ValueError(f'parameter target_keyframes must be >= 0 (0 = off), got {target_keyframes}')
    if not target_keyframes:
        return None
    if not expected_path_m > 0:
        raise ValueError(
            f'parameter target_keyframes {target_keyframes} needs expected_path_m > 0, the planned flight '
            f'path length in metres (the live node cannot know the flight length), got {expected_path_m}'
        )
    return float(expected_path_m) / target_keyframes


@dataclass(frozen=True)
class Decision:
    """Whether a frame became a keyframe, and why (``first``, ``baseline``, ``rotation``,
    ``interval``, ``blurred``, ``too_soon``, ``not_moved``)."""

    keep: bool
    reason: str
    baseline_m: float = 0.0
    rotation_deg: float = 0.0
    blur: float = 0.0


class KeyframeSelector:
    """Online keyframe decisions, one frame at a time (state: the last keyframe and recent blur)."""

    def __init__(self, config: KeyframeConfig | None = None) -> None:
        self.config = config or KeyframeConfig()
        self._blur: deque[float] = deque(maxlen=self.config.blur_window)
        self._last_pose: NDArray[np.float64] | None = None
        self._last_stamp: int | None = None
        self.count = 0

    def decide(
        self, stamp_ns: int, t_wc: NDArray[np.float64], blur: float, scene_depth_m: float | None = None
    ) -> Decision:
        """Decide for one frame; ``scene_depth_m`` is e.g. the median depth seen (None = unknown)."""
        c = self.config
        median_blur = float(np.median(self._blur)) if self._blur else blur
        self._blur.append(blur)
        if blur < c.min_blur_score or (len(self._blur) > 1 and blur < c.blur_ratio * median_blur):
            return Decision(False, 'blurred', blur=blur)
        if self._last_pose is None or self._last_stamp is None:
            return self._keep(stamp_ns, t_wc, Decision(True, 'first', blur=blur))
        dt = (stamp_ns - self._last_stamp) * 1e-9
        base = float(np.linalg.norm(t_wc[:3, 3] - self._last_pose[:3, 3]))
        rot = rotation_angle_deg(self._last_pose[:3, :3], t_wc[:3, :3])
        if dt < c.min_interval_s:
            return Decision(False, 'too_soon', base, rot, blur)
        need = c.baseline_ratio * scene_depth_m if scene_depth_m and scene_depth_m > 0 else c.min_baseline_m
        if base >= max(need, 1e-9):
            return self._keep(stamp_ns, t_wc, Decision(True, 'baseline', base, rot, blur))
        if c.max_rotation_deg and rot >= c.max_rotation_deg:
            return self._keep(stamp_ns, t_wc, Decision(True, 'rotation', base, rot, blur))
        if c.max_interval_s and dt >= c.max_interval_s:
            return self._keep(stamp_ns, t_wc, Decision(True, 'interval', base, rot, blur))
        return Decision(False, 'not_moved', base, rot, blur)

    def _keep(self, stamp_ns: int, t_wc: NDArray[np.float64], d: Decision) -> Decision:
        self._last_pose = np.array(t_wc, dtype=np.float64)
        self._last_stamp = stamp_ns
        self.count += 1
        return d


class IntervalSelector(Generic[T]):
    """Keyframes without poses: the sharpest frame of each ``interval_s`` window of stamps.

    Windows are consecutive intervals of ``interval_s`` seconds from the first frame's stamp. A frame
    is a candidate unless it is blurred by the rule of :class:`KeyframeSelector` (below
    ``blur_ratio`` x the median :func:`blur_score` of the last ``blur_window`` frames, or below
    ``min_blur_score``); frames older than the current window are ignored. A window's choice is
    known when a frame of a later window arrives (:meth:`push`) or at the end (:meth:`flush`), so
    keyframes come up to one interval late. ``item`` is any payload returned with the choice.
    """

    def __init__(self, interval_s: float, config: KeyframeConfig | None = None) -> None:
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValueError(f'interval_s must be > 0, got {interval_s}')
        self.interval_ns = round(interval_s * 1e9)
        self.config = config or KeyframeConfig()
        self._blur: deque[float] = deque(maxlen=self.config.blur_window)
        self._t0: int | None = None
        self._window = -1
        self._best: tuple[int, float, T] | None = None
        self.count = 0
        self.rejected: dict[str, int] = {'blurred': 0, 'late': 0}

    def push(self, stamp_ns: int, blur: float, item: T) -> list[tuple[int, T]]:
        """Offer one frame; return the keyframes (stamp, item) decided by it (0 or 1)."""
        c = self.config
        if self._t0 is None:
            self._t0 = int(stamp_ns)
        window = (int(stamp_ns) - self._t0) // self.interval_ns
        if window < self._window:
            self.rejected['late'] += 1
            return []
        out = self.flush() if window > self._window else []
        self._window = window
        median_blur = float(np.median(self._blur)) if self._blur else blur
        self._blur.append(blur)
        if blur < c.min_blur_score or (len(self._blur) > 1 and blur < c.blur_ratio * median_blur):
            self.rejected['blurred'] += 1
        elif self._best is None or blur > self._best[1]:
            self._best = (int(stamp_ns), blur, item)
        return out

    def flush(self) -> list[tuple[int, T]]:
        """The choice of the current window, if it has a candidate (then the window is closed)."""
        if self._best is None:
            return []
        stamp, _, item = self._best
        self._best = None
        self.count += 1
        return [(stamp, item)]


@dataclass(frozen=True)
class TargetSelection:
    """Result of :func:`select_keyframes_for_target`: the kept frame ``indices`` (in order), the
    common baseline ``scale`` applied to ``baseline_ratio`` and ``min_baseline_m``, and the
    selector's decision for every frame at that scale."""

    indices: list[int]
    scale: float
    decisions: list[Decision]


def select_keyframes_for_target(
    stamps_ns: Sequence[int],
    poses: Sequence[NDArray[np.float64]],
    blur: Sequence[float],
    *,
    target: int = 25,
    scene_depth_m: Sequence[float | None] | None = None,
    config: KeyframeConfig | None = None,
) -> TargetSelection:
    """Offline selection of about ``target`` keyframes from a whole flight.

    Runs :class:`KeyframeSelector` with its ``baseline_ratio`` (and ``min_baseline_m``) scaled by a
    common factor found by bisection (log scale, 1e-3..1e3) so that the count is as close to
    ``target`` as possible.
    """
    n = len(stamps_ns)
    if not (len(poses) == len(blur) == n):
        raise ValueError(
            f'stamps_ns, poses and blur must have one entry per frame, got {n}, {len(poses)}, {len(blur)}'
        )
    if target < 1:
        raise ValueError(f'target must be >= 1, got {target}')
    base = config or KeyframeConfig()
    depths = list(scene_depth_m) if scene_depth_m is not None else [None] * n

    def run(scale: float) -> list[Decision]:
        cfg = replace(
            base, baseline_ratio=base.baseline_ratio * scale, min_baseline_m=base.min_baseline_m * scale
        )
        sel = KeyframeSelector(cfg)
        return [sel.decide(stamps_ns[i], poses[i], blur[i], depths[i]) for i in range(n)]

    def miss(ds: list[Decision]) -> int:
        return abs(sum(d.keep for d in ds) - target)

    lo, hi = 1e-3, 1e3
    best_scale, best = 1.0, run(1.0)
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        picked = run(mid)
        if miss(picked) < miss(best):
            best_scale, best = mid, picked
        count = sum(d.keep for d in picked)
        if count == target:
            break
        if count > target:
            lo = mid
        else:
            hi = mid
    return TargetSelection([i for i, d in enumerate(best) if d.keep], best_scale, best)


def select_keyframes(
    stamps_ns: Sequence[int],
    poses: Sequence[NDArray[np.float64]],
    blur: Sequence[float],
    *,
    target: int = 25,
    scene_depth_m: Sequence[float | None] | None = None,
    config: KeyframeConfig | None = None,
) -> list[int]:
    """Indices of about ``target`` keyframes of a whole flight (:func:`select_keyframes_for_target`)."""
    return select_keyframes_for_target(
        stamps_ns, poses, blur, target=target, scene_depth_m=scene_depth_m, config=config
    ).indices
