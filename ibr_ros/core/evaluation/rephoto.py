# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Virtual-rephotography error (Waechter et al. 2017) as used by Liu et al. 2020, Sec. IV-B.

A held-out input photo (ground truth) is re-rendered from its own pose and compared with the
"shiftable L1 error" of DeepBlending (Hedman et al. 2018). No reference code exists; this module
defines it exactly:

* Colours are 0..255 values of the uint8 images (channel order irrelevant, both the same).
* The error at pixel ``p`` is ``min_s mean_{u, c} |gt(p + u, c) - synth(p + u + s, c)|`` over integer
  shifts ``s = (sx, sy)`` with ``|sx|, |sy| <= shift``, the mean taken over the ``patch x patch``
  window ``u`` centred at ``p`` (``patch`` odd) and the 3 channels. It is in 0..255 colour units.
* Pixels whose patch or any shifted patch leaves the image are NaN and excluded from every
  statistic: valid ``p`` are ``m <= y < H - m``, ``m <= x < W - m`` with ``m = patch // 2 + shift``.
* Holes of the synthesized view count with the colour they were rendered with (usually black)
  unless the caller fills them first; ``completeness`` reports how much was synthesized.

The paper's numbers: 7 x 7 patches, shifts up to +-2 px, images 960 x 540; the error curve is the
sorted per-pixel error against the percentage of pixels, its "AUC" over 0..100 % is the mean error,
and the 99-100 % part (the worst 1 %) is where visible artefacts live.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

__all__ = ['RephotoScore', 'error_curve', 'score', 'shiftable_l1']

_CHUNK_ROWS = 32


@njit(cache=True)
def _diff_row(g0, g1, g2, s0, s1, s2, col, sign):
    """``col += sign * sum_c |g_c - s_c|`` on 1-D contiguous rows (vectorised)."""
    for i in range(col.size):
        col[i] += sign * (abs(g0[i] - s0[i]) + abs(g1[i] - s1[i]) + abs(g2[i] - s2[i]))


@njit(cache=True)
def _add_diff_row(g, s, y, sy, sx, x0, col, sign):
    """``col[i] += sign * sum_c |g[c, y, x0 + i] - s[c, y + sy, x0 + i + sx]|``."""
    n = col.size
    a = x0 + sx
    _diff_row(
        g[0, y, x0 : x0 + n],
        g[1, y, x0 : x0 + n],
        g[2, y, x0 : x0 + n],
        s[0, y + sy, a : a + n],
        s[1, y + sy, a : a + n],
        s[2, y + sy, a : a + n],
        col,
        sign,
    )


@njit(cache=True)
def _window_min(col, r, win, best):
    """``best = min(best, sum_{u=0}^{2r} col[i + u])`` for every output column ``i``."""
    for i in range(win.size):
        win[i] = col[i]
    for u in range(1, 2 * r + 1):
        for i in range(win.size):
            win[i] += col[i + u]
    for i in range(win.size):
        best[i] = min(best[i], win[i])


@njit(cache=True, parallel=True)
def _min_patch_sad(g, s, r, shift, out):
    """Minimum over shifts of the patch sum of absolute differences, written to the valid region.

    ``g``, ``s``: float32 ``(3, H, W)`` holding integers, so every sum is exact in float32.
    Rows are processed in chunks in parallel; per shift, column sums over the ``2r + 1`` patch rows
    are updated incrementally as the chunk moves down.
    """
    h = g.shape[1]
    w = g.shape[2]
    m = r + shift
    n_rows = h - 2 * m
    n_out = w - 2 * m
    if n_rows <= 0 or n_out <= 0:
        return
    n_chunks = (n_rows + _CHUNK_ROWS - 1) // _CHUNK_ROWS
    for c in prange(n_chunks):
        ya = m + c * _CHUNK_ROWS
        yb = min(ya + _CHUNK_ROWS, h - m)
        col = np.empty(w - 2 * shift, np.float32)
        win = np.empty(n_out, np.float32)
        for y in range(ya, yb):
            out[y, m : w - m] = np.inf
        for sy in range(-shift, shift + 1):
            for sx in range(-shift, shift + 1):
                col[:] = 0.0
                for yy in range(ya - r, ya + r + 1):
                    _add_diff_row(g, s, yy, sy, sx, shift, col, np.float32(1.0))
                for y in range(ya, yb):
                    if y > ya:
                        _add_diff_row(g, s, y + r, sy, sx, shift, col, np.float32(1.0))
                        _add_diff_row(g, s, y - r - 1, sy, sx, shift, col, np.float32(-1.0))
                    _window_min(col, r, win, out[y, m : w - m])


def _check_pair(gt: NDArray[np.uint8], synth: NDArray[np.uint8]) -> None:
    for name, img in (('gt', gt), ('synth', synth)):
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            desc = f'{img.dtype} {img.shape}' if isinstance(img, np.ndarray) else type(img).__name__
            raise ValueError(f'{name} must be a uint8 (H, W, 3) array, got {desc}')
    if gt.shape != synth.shape:
        raise ValueError(f'gt and synth shapes differ: gt {gt.shape}, synth {synth.shape}')


def _check_window(patch: int, shift: int) -> None:
    if isinstance(patch, bool) or not isinstance(patch, (int, np.integer)) or patch < 1 or patch % 2 == 0:
        raise ValueError(f'patch must be a positive odd integer, got patch={patch!r}')
    if isinstance(shift, bool) or not isinstance(shift, (int, np.integer)) or shift < 0:
        raise ValueError(f'shift must be a non-negative integer, got shift={shift!r}')


def shiftable_l1(
    gt: NDArray[np.uint8], synth: NDArray[np.uint8], patch: int = 7, shift: int = 2
) -> NDArray[np.float32]:
    """Per-pixel shiftable L1 error (0..255 colour units; see the module docstring).

    Args:
        gt: ground-truth photo, uint8 ``(H, W, 3)``.
        synth: synthesized view from the same pose, uint8 ``(H, W, 3)``.
        patch: odd side of the square comparison window in pixels.
        shift: largest shift of the synthesized patch in x and in y, in pixels.

    Returns:
        float32 ``(H, W)``: the error, NaN within ``patch // 2 + shift`` pixels of the border.
        Exact: the minimum patch sum is computed in integers and divided by ``3 * patch**2``.
    """
    _check_pair(gt, synth)
    _check_window(patch, shift)
    h, w = gt.shape[:2]
    out = np.full((h, w), np.nan, np.float32)
    g = np.ascontiguousarray(gt.transpose(2, 0, 1), dtype=np.float32)
    s = np.ascontiguousarray(synth.transpose(2, 0, 1), dtype=np.float32)
    _min_patch_sad(g, s, int(patch) // 2, int(shift), out)
    out /= np.float32(3 * patch * patch)
    return out


def error_curve(errors: NDArray[np.floating]) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
    """The rephotography error curve: ``(percent, sorted_errors)`` of the finite errors.

    ``percent[i] = 100 * (i + 1) / n``: ``percent[i]`` % of the pixels have an error
    ``<= sorted_errors[i]``. NaNs (border) are dropped; empty input gives two empty arrays.
    """
    e = np.asarray(errors, dtype=np.float32).ravel()
    e = np.sort(e[np.isfinite(e)])
    percent = 100.0 * np.arange(1, e.size + 1, dtype=np.float64) / max(e.size, 1)
    return percent, e


@dataclass(frozen=True)
class RephotoScore:
    """Summary of one rephotography comparison (errors in 0..255 colour units).

    Attributes:
        auc: area under the error curve over 0..100 %, normalised by 100 % (= mean error).
        tail: mean error of the worst 1 % of pixels (the paper's 99-100 % zoom).
        median: median error.
        completeness: fraction of the image's pixels that were synthesized (``valid_mask``);
            1.0 when no mask was given.
        n_pixels: number of pixels that were scored (the non-NaN errors).
        patch, shift: the window used.
    """

    auc: float
    tail: float
    median: float
    completeness: float
    n_pixels: int
    patch: int
    shift: int


def score(
    gt: NDArray[np.uint8],
    synth: NDArray[np.uint8],
    valid_mask: NDArray[np.bool_] | None = None,
    patch: int = 7,
    shift: int = 2,
) -> RephotoScore:
    """Shiftable-L1 rephotography score of ``synth`` against the held-out photo ``gt``.

    ``valid_mask`` (bool ``(H, W)``, True where the renderer produced a colour) only feeds
    ``completeness``: holes are scored with whatever colour ``synth`` has there.
    Raises ValueError for bad inputs and for images too small to hold one valid patch.
    """
    _check_pair(gt, synth)
    _check_window(patch, shift)
    h, w = gt.shape[:2]
    m = int(patch) // 2 + int(shift)
    if h <= 2 * m or w <= 2 * m:
        raise ValueError(f'image {w}x{h} is too small for patch={patch}, shift={shift}')
    if valid_mask is None:
        completeness = 1.0
    else:
        vm = np.asarray(valid_mask)
        if vm.shape != (h, w) or vm.dtype != np.bool_:
            raise ValueError(f'valid_mask must be a bool ({h}, {w}) array, got {vm.dtype} {vm.shape}')
        completeness = float(np.count_nonzero(vm)) / vm.size
    _, e = error_curve(shiftable_l1(gt, synth, patch, shift))
    n_tail = max(1, int(np.ceil(0.01 * e.size)))
    return RephotoScore(
        auc=float(np.mean(e, dtype=np.float64)),
        tail=float(np.mean(e[-n_tail:], dtype=np.float64)),
        median=float(np.median(e)),
        completeness=completeness,
        n_pixels=int(e.size),
        patch=int(patch),
        shift=int(shift),
    )
