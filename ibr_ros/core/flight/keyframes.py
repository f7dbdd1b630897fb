# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe selection for a drone flight (video or survey stills): reject blurred frames, keep frames
that moved enough, never open a gap in the overlap.

The paper subsamples 20-30 images per flight. A frame becomes a keyframe when it is sharp and,
relative to the last keyframe, its camera moved by at least ``baseline_ratio`` x the scene depth
(or ``min_baseline_m`` when the depth is unknown), turned by ``max_rotation_deg``, or
``max_interval_s`` passed. Poses are 4x4 camera-to-world matrices (metres); stamps are nanoseconds.

Without poses (SfM mode), :class:`IntervalSelector` keeps the sharpest frame of every
``interval_s`` window instead.

Blur (:func:`blur_px`) is the width in pixels of the image's strong edges, measured the same way
on every frame: it does not depend on how much texture the scene has, so one absolute threshold,
``max_blur_px``, serves video (consecutive frames share content) and survey stills (seconds apart,
different content) alike; no frame is compared with its neighbours. Measured at the working
resolution on the shipped bags (brighton_beach, sheffield_cross, synthetic synth_orbit_s0): sharp
frames 1.9-2.4 px; the same frames after a Gaussian blur of sigma 1 px 3.3-3.9 px, after a linear
motion blur of 5 px 3.8-5.0 px (of 3 px: 2.7-3.6 px); hence ``max_blur_px`` 3.

A blurred frame that would have been a keyframe (without poses: the least blurred frame of a
window with no sharp one) is decided with the next frame: kept anyway (reason ``overlap``) when
that next frame is already more than ``overlap_gap`` keyframe spacings from the last keyframe, as
without it the gap between keyframes would exceed that (survey stills seconds apart: each is
needed for its neighbours' overlap); else dropped (video: a sharp frame follows within the gap).
The first frames of a flight (no keyframe yet) and a blurred last frame (nothing follows) bridge
no gap between keyframes.
"""

from __future__ import annotations

import math
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
    'Pick',
    'TargetSelection',
    'blur_px',
    'detail_score',
    'select_keyframes',
    'select_keyframes_for_target',
    'target_baseline',
]

T = TypeVar('T')


def _edge_bins(gray: NDArray[np.float32], m: int) -> dict[tuple[int, int], NDArray[np.bool_]]:
    """Per direction (dy, dx): the pixels of ``gray[m:-m, m:-m]`` whose gradient points that way
    (within 22.5 deg, either sign)."""
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)[m:-m, m:-m]
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)[m:-m, m:-m]
    ax, ay = np.abs(gx), np.abs(gy)
    t = math.tan(math.radians(22.5))
    along_x, along_y = ax * t >= ay, ay * t >= ax
    diagonal = ~(along_x | along_y)
    same_sign = gx * gy > 0
    return {
        (0, 1): along_x,
        (1, 1): diagonal & same_sign,
        (1, 0): along_y,
        (1, -1): diagonal & ~same_sign,
    }


def _across(gray: NDArray[np.float32], dy: int, dx: int) -> NDArray[np.float32]:
    """``gray`` smoothed by [1, 2, 1] / 4 across the direction (dy, dx) (less noise, same edges)."""
    k = np.zeros((3, 3), np.float32)
    k[1, 1] = 0.5
    k[1 + dx, 1 - dy] = k[1 - dx, 1 + dy] = 0.25
    return np.asarray(cv2.filter2D(gray, cv2.CV_32F, k, borderType=cv2.BORDER_REPLICATE), np.float32)


def blur_px(
    image: NDArray[np.uint8],
    *,
    max_side: int = 1000,
    span_px: int = 12,
    min_contrast: float = 16.0,
    min_edges: int = 50,
) -> float:
    """Blur of an image: the median width (px) of its strong edges; higher = blurrier, NaN = no edge.

    Colour images are converted to gray; an image longer than ``max_side`` px is first shrunk to that
    long side (INTER_AREA), so widths are pixels at that working resolution. For each of four
    directions (0, 45, 90, 135 deg) the edge points are the pixels whose gradient points that way,
    that are the steepest one-pixel step along it within ``span_px`` and whose contrast across
    ``span_px`` is at least ``min_contrast`` grey levels (of 255; below that, noise and JPEG steps).
    Their width is contrast / steepest step (a focused step edge: 1-2 px; a ramp w px wide: w); the
    direction's width is the median over its stronger half. The result is the largest direction
    (a linear motion blur widens only the edges across the motion), from the directions with at
    least ``min_edges`` edge points; NaN when none has (a featureless image cannot be judged).

    As a width rather than a gradient energy it does not grow with the amount of texture: a sharp
    photo of a lawn or a lake shore scores as low as one of a town.
    """
    img = np.asarray(image)
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    h, w = gray.shape[:2]
    if max(h, w) > max_side:
        s = max_side / max(h, w)
        gray = cv2.resize(gray, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    g = np.asarray(gray, np.float32)
    half = span_px // 2
    m = half + 2  # margin: every shift below stays inside the image
    if min(g.shape) <= 2 * m:
        return math.nan
    H, W = g.shape

    def at(a: NDArray[np.float32], dy: int, dx: int) -> NDArray[np.float32]:
        """``a`` at p + (dy, dx), for every p of the interior."""
        return a[m + dy : H - m + dy, m + dx : W - m + dx]

    widths = []
    for (dy, dx), facing in _edge_bins(g, m).items():
        step_px = math.hypot(dy, dx)  # a diagonal step is sqrt(2) px long
        k = max(1, round(half / step_px))  # steps either side of p
        a = _across(g, dy, dx)
        steps = np.zeros_like(a)
        steps[m:-m, m:-m] = np.abs(at(a, dy, dx) - at(a, 0, 0))
        line = np.eye(2 * k + 1, dtype=np.uint8) if dy and dx else np.ones((1, 2 * k + 1), np.uint8)
        if dy and dx < 0:
            line = np.ascontiguousarray(line[:, ::-1])
        elif dy and not dx:
            line = line.T.copy()
        steepest = at(np.asarray(cv2.dilate(steps, line), np.float32), 0, 0)
        step = at(steps, 0, 0)
        contrast = np.abs(at(a, k * dy, k * dx) - at(a, -k * dy, -k * dx))
        edge = facing & (step >= steepest) & (contrast >= min_contrast) & (step > 0)
        if np.count_nonzero(edge) < min_edges:
            continue
        c, s = contrast[edge], step[edge]
        strong = c >= np.quantile(c, 0.5)
        widths.append(float(np.median(c[strong] / s[strong])) * step_px)
    return max(widths) if widths else math.nan


def detail_score(image: NDArray[np.uint8], *, max_side: int = 480) -> float:
    """Detail as the variance of the Laplacian of the gray image (higher = more detail).

    Content-dependent (a busy scene scores far higher than a lawn at the same sharpness): it ranks
    frames of one window (:class:`IntervalSelector`), never decides whether one is blurred
    (:func:`blur_px`). Colour images are converted to gray; images larger than ``max_side`` are
    downscaled first (by an integer factor with INTER_AREA), so it costs about the same at any size.
    """
    img = np.asarray(image)
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    step = max(1, math.ceil(max(gray.shape) / max_side))
    if step > 1:
        gray = cv2.resize(gray, (gray.shape[1] // step, gray.shape[0] // step), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(gray, cv2.CV_32F).var())


def _blurred(blur: float, max_blur_px: float) -> bool:
    """Whether a :func:`blur_px` is over ``max_blur_px`` (0 = off; NaN, no edge to judge: not blurred)."""
    return max_blur_px > 0 and blur > max_blur_px


@dataclass(frozen=True)
class KeyframeConfig:
    """Thresholds of :class:`KeyframeSelector` and :class:`IntervalSelector` (module docstring).

    ``max_blur_px``: a frame is blurred when its :func:`blur_px` exceeds this (px at the working
    resolution; 0 = off); an absolute threshold for video and stills alike. ``overlap_gap``: a
    blurred frame is kept anyway when the frame after it is more than this many keyframe spacings
    from the last keyframe (the baseline, rotation or interval rule's threshold; ``interval_s``
    without poses); 0 = off (blurred frames are always dropped), else >= 1.
    """

    baseline_ratio: float = 0.08
    min_baseline_m: float = 2.0
    max_rotation_deg: float = 15.0
    max_interval_s: float = 0.0
    min_interval_s: float = 0.0
    max_blur_px: float = 3.0
    overlap_gap: float = 2.0

    def __post_init__(self) -> None:
        for name in (
            'baseline_ratio',
            'min_baseline_m',
            'max_rotation_deg',
            'max_interval_s',
            'min_interval_s',
            'max_blur_px',
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f'KeyframeConfig.{name} must be >= 0, got {getattr(self, name)}')
        if not (self.overlap_gap == 0 or self.overlap_gap >= 1):
            raise ValueError(f'KeyframeConfig.overlap_gap must be 0 (off) or >= 1, got {self.overlap_gap}')


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
    """Whether a frame became a keyframe, and why (kept: ``first``, ``baseline``, ``rotation``,
    ``interval``, ``overlap`` = blurred but kept for overlap; dropped: ``blurred``, ``too_soon``,
    ``not_moved``; ``held``: blurred, decided with the next frame); ``blur`` is the frame's
    :func:`blur_px`. ``previous``: the final decision (``overlap`` or ``blurred``) of the frame
    before, when that one was ``held``."""

    keep: bool
    reason: str
    baseline_m: float = 0.0
    rotation_deg: float = 0.0
    blur: float = 0.0
    previous: Decision | None = None


class KeyframeSelector:
    """Online keyframe decisions, one frame at a time (state: the last keyframe and a held frame).

    A blurred frame (``max_blur_px``) is dropped, except one that would have been a keyframe: it is
    ``held`` and decided with the next frame (:attr:`Decision.previous` of that frame's decision),
    kept (``overlap``) when that next frame already moved, turned or waited more than
    ``overlap_gap`` times what makes a keyframe (without the held frame the gap between keyframes
    would exceed that), else dropped (``blurred``); :meth:`flush` drops a frame still held at the
    end. Without a keyframe yet, a blurred frame is dropped.
    """

    def __init__(self, config: KeyframeConfig | None = None) -> None:
        self.config = config or KeyframeConfig()
        self._last_pose: NDArray[np.float64] | None = None
        self._last_stamp: int | None = None
        self._held: tuple[int, NDArray[np.float64], Decision] | None = None
        self.count = 0

    def decide(
        self, stamp_ns: int, t_wc: NDArray[np.float64], blur: float, scene_depth_m: float | None = None
    ) -> Decision:
        """Decide for one frame of :func:`blur_px` ``blur`` (and for the held frame before it, in
        ``previous``); ``scene_depth_m`` is e.g. the median depth seen (None = unknown)."""
        previous = None
        if self._held is not None:
            stamp, pose, held = self._held
            self._held = None
            if self._moved(self.config.overlap_gap, *self._motion(stamp_ns, t_wc), scene_depth_m):
                previous = self._keep(stamp, pose, replace(held, keep=True, reason='overlap'))
            else:
                previous = replace(held, reason='blurred')
        d = self._decide(stamp_ns, t_wc, blur, scene_depth_m)
        return replace(d, previous=previous) if previous is not None else d

    def flush(self) -> Decision | None:
        """The end of the flight: the held frame, if any, is dropped (``blurred``: nothing follows)."""
        held, self._held = self._held, None
        return None if held is None else replace(held[2], reason='blurred')

    def _decide(
        self, stamp_ns: int, t_wc: NDArray[np.float64], blur: float, scene_depth_m: float | None
    ) -> Decision:
        c = self.config
        blurred = _blurred(blur, c.max_blur_px)
        if self._last_pose is None:
            if blurred:
                return Decision(False, 'blurred', blur=blur)
            return self._keep(stamp_ns, t_wc, Decision(True, 'first', blur=blur))
        dt, base, rot = self._motion(stamp_ns, t_wc)
        if dt < c.min_interval_s:
            return Decision(False, 'blurred' if blurred else 'too_soon', base, rot, blur)
        reason = self._moved(1.0, dt, base, rot, scene_depth_m)
        if blurred and reason and c.overlap_gap:
            self._held = (
                stamp_ns,
                np.array(t_wc, dtype=np.float64),
                Decision(False, 'held', base, rot, blur),
            )
            return self._held[2]
        if blurred:
            return Decision(False, 'blurred', base, rot, blur)
        if reason:
            return self._keep(stamp_ns, t_wc, Decision(True, reason, base, rot, blur))
        return Decision(False, 'not_moved', base, rot, blur)

    def _motion(self, stamp_ns: int, t_wc: NDArray[np.float64]) -> tuple[float, float, float]:
        """Seconds, metres and degrees from the last keyframe (which must exist)."""
        assert self._last_pose is not None
        assert self._last_stamp is not None
        dt = (stamp_ns - self._last_stamp) * 1e-9
        base = float(np.linalg.norm(t_wc[:3, 3] - self._last_pose[:3, 3]))
        return dt, base, rotation_angle_deg(self._last_pose[:3, :3], t_wc[:3, :3])

    def _moved(self, factor: float, dt: float, base: float, rot: float, depth: float | None) -> str:
        """The rule (``baseline``, ``rotation``, ``interval``) met with its threshold x ``factor`` > 0,
        or ``''`` (also for ``factor`` 0)."""
        c = self.config
        if not factor:
            return ''
        need = c.baseline_ratio * depth if depth and depth > 0 else c.min_baseline_m
        if base >= max(need * factor, 1e-9):
            return 'baseline'
        if c.max_rotation_deg and rot >= c.max_rotation_deg * factor:
            return 'rotation'
        if c.max_interval_s and dt >= c.max_interval_s * factor:
            return 'interval'
        return ''

    def _keep(self, stamp_ns: int, t_wc: NDArray[np.float64], d: Decision) -> Decision:
        self._last_pose = np.array(t_wc, dtype=np.float64)
        self._last_stamp = stamp_ns
        self.count += 1
        return d


@dataclass(frozen=True)
class Pick(Generic[T]):
    """A keyframe of :class:`IntervalSelector`: its ``stamp`` (ns), ``item`` and ``reason``
    (``sharpest`` of its window's unblurred frames, or ``overlap``: its window had only blurred
    frames, the least blurred is kept for overlap)."""

    stamp: int
    item: T
    reason: str


class IntervalSelector(Generic[T]):
    """Keyframes without poses: the sharpest frame of each ``interval_s`` window of stamps.

    Windows are consecutive intervals of ``interval_s`` seconds from the first frame's stamp; frames
    older than the current window are ignored (``late``). A window's keyframe is, of its frames that
    are not blurred (:func:`blur_px` at most ``max_blur_px``), the one with the most ``detail``
    (:func:`detail_score`: in video the sharpest, among stills the most textured, which SfM matches
    best), or without ``detail`` the lowest :func:`blur_px`. A window with only blurred
    frames gives its least blurred one anyway (reason ``overlap``) when the next frame comes more
    than ``overlap_gap`` x ``interval_s`` after the last keyframe: survey stills seconds apart, each
    needed for the overlap of its neighbours. A window's choice is known when a frame of a later
    window arrives (:meth:`push`) or at the end (:meth:`flush`: nothing follows, so a blurred last
    window gives none), so keyframes come up to one interval late. ``item`` is any payload returned
    with the choice. ``rejected`` counts the frames dropped as ``blurred`` or ``late``.
    """

    def __init__(self, interval_s: float, config: KeyframeConfig | None = None) -> None:
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValueError(f'interval_s must be > 0, got {interval_s}')
        self.interval_ns = round(interval_s * 1e9)
        self.config = config or KeyframeConfig()
        self._t0: int | None = None
        self._window = -1
        self._best: tuple[int, float, T] | None = None  # the window's unblurred frame to keep, rank
        self._fallback: tuple[int, float, T] | None = None  # its least blurred blurred frame, blur
        self._last: int | None = None  # the last keyframe's stamp
        self._blurred = 0
        self._late = 0
        self.count = 0
        self.kept_for_overlap = 0

    @property
    def rejected(self) -> dict[str, int]:
        """Frames dropped so far: ``blurred`` (not kept for overlap) and ``late``."""
        return {'blurred': self._blurred - self.kept_for_overlap, 'late': self._late}

    def push(self, stamp_ns: int, blur: float, item: T, *, detail: float | None = None) -> list[Pick[T]]:
        """Offer one frame of :func:`blur_px` ``blur`` (and :func:`detail_score` ``detail``); return the
        keyframes decided by it (0 or 1)."""
        stamp = int(stamp_ns)
        if self._t0 is None:
            self._t0 = stamp
        window = (stamp - self._t0) // self.interval_ns
        if window < self._window:
            self._late += 1
            return []
        out = self._close(stamp) if window > self._window else []
        self._window = window
        key = blur if math.isfinite(blur) else math.inf  # no edge to judge: after any measured frame
        if _blurred(blur, self.config.max_blur_px):
            self._blurred += 1
            if self._fallback is None or key < self._fallback[1]:
                self._fallback = (stamp, key, item)
            return out
        if detail is not None:
            key = -detail
        if self._best is None or key < self._best[1]:
            self._best = (stamp, key, item)
        return out

    def flush(self) -> list[Pick[T]]:
        """The choice of the current window, if it has an unblurred frame (then the window is closed)."""
        return self._close(None)

    def _close(self, next_stamp: int | None) -> list[Pick[T]]:
        """Close the current window; ``next_stamp``: the first frame after it (None: the end)."""
        best, fallback = self._best, self._fallback
        self._best = self._fallback = None
        gap = self.config.overlap_gap * self.interval_ns
        if best is not None:
            pick, reason = best, 'sharpest'
        elif (
            fallback is not None
            and gap
            and next_stamp is not None
            and self._last is not None
            and next_stamp - self._last > gap
        ):
            pick, reason = fallback, 'overlap'
            self.kept_for_overlap += 1
        else:
            return []
        self._last = pick[0]
        self.count += 1
        return [Pick(pick[0], pick[2], reason)]


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
    ``target`` as possible; ``blur`` is each frame's :func:`blur_px`.
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
        out: list[Decision] = []
        for i in range(n):
            d = sel.decide(stamps_ns[i], poses[i], blur[i], depths[i])
            if d.previous is not None:  # the frame before was held
                out[-1] = d.previous
            out.append(replace(d, previous=None))
        if (last := sel.flush()) is not None:
            out[-1] = last
        return out

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
