# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-view remapping of monocular depth to the MVS depth scale (Liu et al. 2020, Eq. 1-4).

The monocular network output ``G`` is uint16 (0..65535) and grows as the scene gets *nearer* (it
behaves like inverse depth, with unknown scale and offset).  The MVS depth ``d_mvs`` is float32
metres along the optical axis; a pixel is a valid MVS sample when its depth is finite and > 0.

:func:`lut_remap` is the paper's method: 256 levels ``i = G // 256`` (Eq. 1), the median valid MVS
depth ``d'_i`` of each level (Eq. 2), and a 65536-entry lookup table interpolating linearly between
neighbouring levels (Eq. 3-4).  :func:`median_factor_remap` and :func:`linear_remap` are the two
baselines of the paper's Table 1.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ['build_lut', 'level_medians', 'linear_remap', 'lut_remap', 'median_factor_remap']

N_LEVELS = 256
LEVEL_WIDTH = 256


@njit(cache=True)
def _level_medians(g, d):
    """Median (numpy's: mean of the two middle values for even counts) of valid ``d`` per level,
    leaving out ``g == 0`` unless no other pixel is valid."""
    g = g.ravel()
    d = d.ravel()
    cnt = np.zeros(N_LEVELS + 1, np.int64)
    n_zero = 0
    for i in range(g.shape[0]):
        v = d[i]
        if v > 0 and v < np.inf:
            if g[i] == 0:
                n_zero += 1
            else:
                cnt[(g[i] >> 8) + 1] += 1
    g_min = 1
    if n_zero > 0 and cnt.sum() == 0:
        g_min = 0
        cnt[1] = n_zero
    for k in range(N_LEVELS):
        cnt[k + 1] += cnt[k]
    vals = np.empty(cnt[N_LEVELS], np.float64)
    fill = cnt[:N_LEVELS].copy()
    for i in range(g.shape[0]):
        v = d[i]
        if v > 0 and v < np.inf and g[i] >= g_min:
            lv = g[i] >> 8
            vals[fill[lv]] = v
            fill[lv] += 1
    med = np.full(N_LEVELS, np.nan)
    counts = np.empty(N_LEVELS, np.int64)
    for k in range(N_LEVELS):
        counts[k] = cnt[k + 1] - cnt[k]
        if counts[k] > 0:
            med[k] = np.median(vals[cnt[k] : cnt[k + 1]])
    return med, counts


def _check(g: np.ndarray, d_mvs: np.ndarray) -> None:
    if not isinstance(g, np.ndarray) or g.dtype != np.uint16:
        raise ValueError(f'g must be a uint16 array, got {getattr(g, "dtype", type(g).__name__)}')
    if g.ndim != 2:
        raise ValueError(f'g must be 2-D (H, W), got shape {g.shape}')
    if not isinstance(d_mvs, np.ndarray) or d_mvs.dtype != np.float32:
        raise ValueError(
            f'd_mvs must be a float32 array, got {getattr(d_mvs, "dtype", type(d_mvs).__name__)}'
        )
    if d_mvs.shape != g.shape:
        raise ValueError(f'd_mvs has shape {d_mvs.shape}, expected {g.shape} (the shape of g)')


def _valid(d_mvs: np.ndarray) -> NDArray[np.bool_]:
    valid = np.isfinite(d_mvs) & (d_mvs > 0)
    if not valid.any():
        raise ValueError(f'd_mvs has no valid depth (finite and > 0) among its {d_mvs.size} pixels')
    return valid


def level_medians(g: np.ndarray, d_mvs: np.ndarray) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Representative MVS depth ``d'_i`` of each level ``i = G // 256`` (Eq. 1-2).

    Returns ``(medians, counts)``, both of length 256: the median (numpy's definition: the mean of
    the two middle values for even counts, in float64) of the valid MVS depths whose pixel has
    ``G // 256 == i``, NaN for an empty level, and the number of those samples.  Pixels with
    ``G = 0`` (no monocular prediction, e.g. above the horizon of the ground-plane prior) are left
    out, unless no pixel with ``G > 0`` has a valid depth.
    """
    _check(g, d_mvs)
    med, counts = _level_medians(np.ascontiguousarray(g), np.ascontiguousarray(d_mvs))
    if counts.sum() == 0:
        raise ValueError(f'd_mvs has no valid depth (finite and > 0) among its {d_mvs.size} pixels')
    return med, counts


def build_lut(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """The per-view lookup table ``d_G`` for every ``G`` in 0..65535 (float32 metres, Eq. 3).

    ``d_G = (d'_{i+1} - d'_i) * (G / 256 - i) + d'_i`` with ``i = G // 256``.  Empty levels get
    ``d'_i`` by linear interpolation over the level index between the nearest non-empty levels, and
    the value of the nearest non-empty level beyond the first/last one.  There is no level 256, so
    the table is constant (``d'_255``) within level 255.

    Note that ``d'_i`` is the median over ``G`` in ``[256 i, 256 i + 256)`` but Eq. 3 anchors it at
    ``G = 256 i``: the table lags the data by about half a level (as in the paper).
    """
    med, counts = level_medians(g, d_mvs)
    full = counts > 0
    levels = np.arange(N_LEVELS)
    d_lv = np.interp(levels, levels[full], med[full])  # constant beyond the ends
    nxt = np.append(d_lv[1:], d_lv[-1])  # d'_{i+1}; level 255 has no successor
    frac = (np.arange(LEVEL_WIDTH) / LEVEL_WIDTH)[None, :]
    lut = (nxt - d_lv)[:, None] * frac + d_lv[:, None]
    return lut.reshape(-1).astype(np.float32)


def lut_remap(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """Remap monocular ``g`` (uint16 H x W) to MVS scale with the per-view table (Eq. 1-4).

    ``d_mvs`` float32 H x W, valid where finite and > 0 (at least one pixel).  Returns float32 metres
    for every pixel.  Raises ValueError for a wrong dtype, shape or an ``d_mvs`` with no valid depth.
    """
    return build_lut(g, d_mvs)[g]


def median_factor_remap(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """Baseline: treat ``G`` as relative inverse depth and fix its scale by a median ratio.

    ``depth_mono = 1 / max(G, 1)``, scaled by ``median(d_mvs) / median(depth_mono)`` over the valid
    MVS pixels (numpy's median).  Exact when ``G`` is proportional to inverse depth; it cannot absorb
    an offset.  Returns float32 metres.
    """
    _check(g, d_mvs)
    valid = _valid(d_mvs)
    inv = 1.0 / np.maximum(g, 1).astype(np.float64)
    scale = np.median(d_mvs[valid].astype(np.float64)) / np.median(inv[valid])
    return (scale * inv).astype(np.float32)


def linear_remap(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """Baseline: least-squares fit ``D ~ a * G + b`` over the valid MVS pixels, applied everywhere.

    A constant ``G`` over the valid pixels gives ``a = 0, b = mean(D)``.  The fit may extrapolate to
    values <= 0 (unknown, by convention) where ``G`` lies far outside the fitted range.  float32.
    """
    _check(g, d_mvs)
    valid = _valid(d_mvs)
    x = g[valid].astype(np.float64)
    y = d_mvs[valid].astype(np.float64)
    xm, ym = x.mean(), y.mean()
    var = np.mean((x - xm) ** 2)
    a = float(np.mean((x - xm) * (y - ym)) / var) if var > 0 else 0.0
    b = ym - a * xm
    return (a * g.astype(np.float64) + b).astype(np.float32)
