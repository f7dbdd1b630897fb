# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-view remapping of monocular depth to the MVS depth scale (Liu et al. 2020, Eq. 1-4).

The monocular network output ``G`` is uint16 (0..65535) and grows as the scene gets *nearer* (it
behaves like inverse depth, with unknown scale and offset).  The MVS depth ``d_mvs`` is float32
metres along the optical axis; a pixel is a valid MVS sample when its depth is finite and > 0.

:func:`lut_remap` is the paper's method: 256 levels ``i = G // 256`` (Eq. 1), the median valid MVS
depth ``d'_i`` of each level (Eq. 2), and a 65536-entry lookup table interpolating linearly between
neighbouring levels (Eq. 3-4).  The paper leaves open what the table holds beyond the farthest and
nearest levels with MVS samples (a view that sees the horizon has far ground that MVS never
reached); :func:`build_lut` continues the trend of ``1 / d'_i`` there (see its docstring).
:func:`median_factor_remap` and :func:`linear_remap` are the two baselines of the paper's Table 1.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = [
    'FAR_FACTOR',
    'NEAR_FACTOR',
    'build_lut',
    'level_medians',
    'linear_remap',
    'lut_remap',
    'median_factor_remap',
]

N_LEVELS = 256
LEVEL_WIDTH = 256
#: Extrapolated depth is at most this factor times the largest valid MVS depth: the paper's sky
#: depth (Eq. 14), so no ground lies beyond the sky; also the depth given beyond the horizon.
FAR_FACTOR = 2.0
#: Extrapolated depth is at least this factor times the smallest valid MVS depth.
NEAR_FACTOR = 0.5
_HUBER_K = 1.345  # Huber's constant (95 % efficiency for Gaussian residuals)
_IRLS_STEPS = 10


@njit(cache=True)
def _level_medians(g, d):
    """Median (numpy's: mean of the two middle values for even counts) of valid ``d`` per level,
    leaving out ``g == 0`` unless no other pixel is valid; also the smallest and largest valid ``d``
    (all pixels; inf and 0 when there is none)."""
    g = g.ravel()
    d = d.ravel()
    cnt = np.zeros(N_LEVELS + 1, np.int64)
    n_zero = 0
    d_min, d_max = np.inf, 0.0
    for i in range(g.shape[0]):
        v = d[i]
        if v > 0 and v < np.inf:
            d_min = min(d_min, np.float64(v))
            d_max = max(d_max, np.float64(v))
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
    return med, counts, d_min, d_max


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


def _medians_and_range(
    g: np.ndarray, d_mvs: np.ndarray
) -> tuple[NDArray[np.float64], NDArray[np.int64], float, float]:
    """:func:`level_medians` and the smallest and largest valid MVS depth (m)."""
    _check(g, d_mvs)
    med, counts, d_min, d_max = _level_medians(np.ascontiguousarray(g), np.ascontiguousarray(d_mvs))
    if counts.sum() == 0:
        raise ValueError(f'd_mvs has no valid depth (finite and > 0) among its {d_mvs.size} pixels')
    return med, counts, float(d_min), float(d_max)


def level_medians(g: np.ndarray, d_mvs: np.ndarray) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Representative MVS depth ``d'_i`` of each level ``i = G // 256`` (Eq. 1-2).

    Returns ``(medians, counts)``, both of length 256: the median (numpy's definition: the mean of
    the two middle values for even counts, in float64) of the valid MVS depths whose pixel has
    ``G // 256 == i``, NaN for an empty level, and the number of those samples.  Pixels with
    ``G = 0`` (no monocular prediction, e.g. above the horizon of the ground-plane prior) are left
    out, unless no pixel with ``G > 0`` has a valid depth.
    """
    med, counts, _, _ = _medians_and_range(g, d_mvs)
    return med, counts


def _inverse_depth_line(
    levels: NDArray[np.int64], medians: NDArray[np.float64], counts: NDArray[np.int64]
) -> tuple[float, float] | None:
    """Robust fit ``1 / d'_i ~ a * (i + 1/2) + b`` over populated levels (1/m per level unit).

    Weighted least squares (weights: the sample counts) with Huber reweighting of the residuals
    (scale: their MAD), each median placed at the centre of its level.  None for fewer than two
    levels or a slope that is not positive (inverse depth must grow with G).
    """
    if levels.size < 2:
        return None
    x = levels + 0.5
    y = 1.0 / medians
    w0 = counts.astype(np.float64)
    w = w0
    a = b = 0.0
    for _ in range(_IRLS_STEPS):
        xm, ym = np.average(x, weights=w), np.average(y, weights=w)
        var = float(np.sum(w * (x - xm) ** 2))
        if var <= 0:
            return None
        a = float(np.sum(w * (x - xm) * (y - ym))) / var
        b = float(ym - a * xm)
        r = np.abs(y - (a * x + b))
        scale = _HUBER_K * 1.4826 * float(np.median(r))
        if scale <= 0:
            break
        w_new = w0 * np.minimum(1.0, scale / np.maximum(r, 1e-300))
        if np.allclose(w_new, w):
            break
        w = w_new
    return (a, b) if a > 0 and np.isfinite(a) and np.isfinite(b) else None


def build_lut(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """The per-view lookup table ``d_G`` for every ``G`` in 0..65535 (float32 metres, Eq. 3).

    Between the anchors ``G = 256 lo`` and ``G = 256 hi`` of the farthest and nearest populated
    levels ``lo <= hi`` (:func:`level_medians`) it is the paper's table:
    ``d_G = (d'_{i+1} - d'_i) * (G / 256 - i) + d'_i`` with ``i = G // 256``, empty levels getting
    ``d'_i`` by linear interpolation over the level index between the nearest populated ones.
    (``d'_i`` is the median over ``G`` in ``[256 i, 256 i + 256)`` but Eq. 3 anchors it at
    ``G = 256 i``: the table lags the data by about half a level, as in the paper.)

    Beyond the anchors it continues the trend of the monocular depth in inverse depth:
    ``1 / d_G = a * G / 256 + b``, the robust weighted line of ``1 / d'_i`` against the level
    centre ``i + 1/2`` over all populated levels, never nearer than ``d'_lo`` below ``256 lo`` nor
    farther than ``d'_hi`` above ``256 hi`` (the table is monotone wherever the medians are), and
    within ``[NEAR_FACTOR * D_min, FAR_FACTOR * D_max]``, ``D_min`` and ``D_max`` the smallest and
    largest valid MVS depth (``G = 0`` pixels included).  Where the line
    reaches ``1 / d <= 1 / (FAR_FACTOR * D_max)``, including beyond its horizon ``1 / d <= 0``, the
    table holds ``FAR_FACTOR * D_max``, the paper's sky depth (Eq. 14).  With a single populated
    level, or a line whose slope is not positive, the table holds ``d'_lo`` and ``d'_hi`` beyond
    the ends instead.
    """
    med, counts, d_min, d_max = _medians_and_range(g, d_mvs)
    full = counts > 0
    levels = np.arange(N_LEVELS)
    d_lv = np.interp(levels, levels[full], med[full])  # constant beyond the ends
    nxt = np.append(d_lv[1:], d_lv[-1])  # d'_{i+1}; level 255 has no successor
    frac = (np.arange(LEVEL_WIDTH) / LEVEL_WIDTH)[None, :]
    lut = ((nxt - d_lv)[:, None] * frac + d_lv[:, None]).reshape(-1)
    lv, md = levels[full], med[full]
    line = _inverse_depth_line(lv, md, counts[full])
    if line is not None:
        a, b = line
        inv_far = 1.0 / (FAR_FACTOR * d_max)
        inv_near = 1.0 / (NEAR_FACTOR * d_min)
        g_lo, g_hi = LEVEL_WIDTH * int(lv[0]), LEVEL_WIDTH * int(lv[-1])  # the anchors
        x = np.arange(N_LEVELS * LEVEL_WIDTH, dtype=np.float64) / LEVEL_WIDTH
        far = np.clip(np.minimum(a * x[:g_lo] + b, 1.0 / md[0]), inv_far, inv_near)
        near = np.clip(np.maximum(a * x[g_hi + 1 :] + b, 1.0 / md[-1]), inv_far, inv_near)
        lut[:g_lo] = 1.0 / far
        lut[g_hi + 1 :] = 1.0 / near
    return lut.astype(np.float32)


def lut_remap(g: np.ndarray, d_mvs: np.ndarray) -> NDArray[np.float32]:
    """Remap monocular ``g`` (uint16 H x W) to MVS scale with the per-view table (Eq. 1-4).

    ``d_mvs`` float32 H x W, valid where finite and > 0 (at least one pixel).  Returns float32 metres
    (finite, > 0) for every pixel, extrapolated beyond the populated levels as :func:`build_lut`
    says.  Raises ValueError for a wrong dtype, shape or an ``d_mvs`` with no valid depth.
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
