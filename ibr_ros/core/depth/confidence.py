# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-pixel confidence of a refined depth map, float32 in [0, 1] (0 = unknown depth).

Three kinds of pixel, in decreasing trust:

* **MVS** (pruned MVS depth kept): ``0.5 + 0.5 * p * g`` with the photometric term
  ``p = clip((zncc - min_zncc) / (1 - min_zncc), 0, 1)`` (the sweep's aggregated ZNCC above the
  acceptance threshold) and the geometric term ``g = min(1, n_consistent / full_consistent)`` (how
  many other views confirmed the depth). A kept MVS pixel is never below 0.5, except within
  ``edge_radius_px`` of a depth step of more than ``edge_step`` (relative), where window matching
  smears the nearer surface over the farther one: there it is capped at 0.45 (not confident).
* **Filled** (no MVS depth; fused from the MVS depth propagated along the colour MST and the
  remapped monocular depth): ``mono_only + (0.5 - mono_only) * s * a`` with the MST support
  ``s = J^A / (J^A + 1)`` (Eq. 11: ``J^A`` is the sum of tree similarities to MVS pixels, so
  ``s`` falls with the tree distance to the nearest MVS support) and the agreement of the fused
  depth with the remapped monocular depth ``a = exp(-|ln(fused / mono)| / agreement_scale)``.
  A filled pixel is always below 0.5; one far from any MVS support, or whose propagated MVS depth
  the monocular depth contradicts, gets about ``mono_only``.
* **Sky** (+inf): ``sky``; **unknown** (0, NaN, or depth outside the plausible range): 0.

A depth sample without MVS evidence (an SfM point seeding the fusion: ``zncc`` and
``n_consistent`` 0 there) counts as an MVS pixel with ``p = g = 0``: 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ['ConfidenceConfig', 'depth_confidence']


@dataclass(frozen=True)
class ConfidenceConfig:
    """Constants of :func:`depth_confidence` (see the module docstring).

    ``min_zncc``: the ZNCC at which MVS accepts a match (MvsOptions.min_zncc); ``full_consistent``:
    agreeing views for the full geometric term; ``agreement_scale``: relative fused/mono
    disagreement (log ratio) at which the agreement falls to 1/e; ``mono_only``: confidence of
    monocular depth without MVS support; ``sky``: confidence of segmented sky; ``edge_radius_px`` /
    ``edge_step``: the depth-edge rule of MVS pixels (radius 0: off).
    """

    min_zncc: float = 0.5
    full_consistent: int = 2
    agreement_scale: float = 0.25
    mono_only: float = 0.1
    sky: float = 0.5
    edge_radius_px: int = 2
    edge_step: float = 0.1

    def __post_init__(self) -> None:
        if not -1.0 <= self.min_zncc < 1.0:
            raise ValueError(f'ConfidenceConfig.min_zncc must be in [-1, 1), got {self.min_zncc}')
        if self.full_consistent < 1:
            raise ValueError(f'ConfidenceConfig.full_consistent must be >= 1, got {self.full_consistent}')
        if not self.agreement_scale > 0:
            raise ValueError(f'ConfidenceConfig.agreement_scale must be > 0, got {self.agreement_scale}')
        if not 0.0 <= self.mono_only < 0.5:
            raise ValueError(f'ConfidenceConfig.mono_only must be in [0, 0.5), got {self.mono_only}')
        if self.edge_radius_px < 0 or not self.edge_step > 0:
            raise ValueError(
                f'ConfidenceConfig needs edge_radius_px >= 0 and edge_step > 0, got {self.edge_radius_px}, '
                f'{self.edge_step}'
            )
        if not 0.0 <= self.sky <= 1.0:
            raise ValueError(f'ConfidenceConfig.sky must be in [0, 1], got {self.sky}')


def _check(name: str, a: NDArray, shape: tuple[int, ...]) -> NDArray:
    arr = np.asarray(a)
    if arr.shape != shape:
        raise ValueError(f'{name} has shape {arr.shape}, the depth is {shape}')
    return arr


def _depth_edges(
    d: NDArray[np.float32], known: NDArray[np.bool_], radius: int, step: float
) -> NDArray[np.bool_]:
    """Pixels within ``radius`` of a relative depth step above ``step`` (sky counts as far; unknown
    depth as no step)."""
    far = np.float32(1e9)
    hi = np.where(known, np.minimum(d, far), np.float32(0.0)).astype(np.float32)
    lo = np.where(known, np.minimum(d, far), far).astype(np.float32)
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(hi, kernel) > cv2.erode(lo, kernel) * np.float32(1.0 + step)


def depth_confidence(
    depth: NDArray[np.floating],
    mvs: NDArray[np.floating],
    mono: NDArray[np.floating],
    support: NDArray[np.floating],
    *,
    zncc: NDArray[np.floating] | None = None,
    n_consistent: NDArray[np.integer] | None = None,
    config: ConfidenceConfig | None = None,
) -> NDArray[np.float32]:
    """Confidence (float32 HxW in [0, 1]) of the refined ``depth`` (metres; 0/NaN unknown, +inf sky).

    ``mvs``: the pruned MVS depth the fusion kept (known where finite and > 0); ``mono``: the
    remapped monocular depth; ``support``: ``J^A`` of the fusion (:func:`~ibr_ros.core.depth.fusion.
    fuse_with_support`); ``zncc`` / ``n_consistent``: the MVS score and agreeing-view count per
    pixel (None: full photometric / geometric terms, e.g. for depth from another source).
    """
    c = config or ConfidenceConfig()
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f'depth must be HxW, got shape {d.shape}')
    shape = d.shape
    m = _check('mvs', mvs, shape).astype(np.float32, copy=False)
    mo = _check('mono', mono, shape).astype(np.float32, copy=False)
    j = _check('support', support, shape).astype(np.float32, copy=False)
    known = np.isfinite(d) & (d > 0)
    is_mvs = known & np.isfinite(m) & (m > 0)
    p = np.float32(1.0)
    if zncc is not None:
        z = _check('zncc', zncc, shape).astype(np.float32, copy=False)
        p = np.clip((z - c.min_zncc) / (1.0 - c.min_zncc), 0.0, 1.0)
    g = np.float32(1.0)
    if n_consistent is not None:
        n = _check('n_consistent', n_consistent, shape).astype(np.float32)
        g = np.minimum(1.0, n / np.float32(c.full_consistent))
    c_mvs = 0.5 + 0.5 * p * g
    if c.edge_radius_px > 0:
        c_mvs = np.where(
            _depth_edges(d, known, c.edge_radius_px, c.edge_step), np.minimum(c_mvs, 0.45), c_mvs
        )
    s = np.where(j > 0, j / (j + 1.0), 0.0).astype(np.float32)
    ok = np.isfinite(mo) & (mo > 0)
    ratio = np.abs(np.log(np.where(known & ok, d, 1.0) / np.where(known & ok, mo, 1.0)))
    a = np.where(ok, np.exp(-ratio / c.agreement_scale), 0.0).astype(np.float32)
    c_fill = c.mono_only + (0.5 - c.mono_only) * s * a
    out = np.where(is_mvs, c_mvs, np.where(known, c_fill, 0.0)).astype(np.float32)
    out[np.isposinf(d)] = c.sky
    return out
