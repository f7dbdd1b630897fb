# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""SLIC superpixels (Achanta et al. 2012, TPAMI 34(11)) in numba, and per-superpixel depth statistics.

Superpixels are the warping unit of the renderer (Liu et al. 2020, Sec. III-B): every superpixel is
warped with the median depth of its pixels, so labels must be compact, follow image edges and be
single 4-connected regions.

Algorithm (``slic``):

* Colour space: CIELAB from ``cv2.cvtColor(rgb, COLOR_RGB2Lab)`` on uint8 (sRGB, D65), rescaled to
  true CIELAB units: ``L = L8 * 100 / 255`` in 0..100, ``a = a8 - 128``, ``b = b8 - 128``. The
  compactness therefore has the meaning of the paper and of skimage (``compactness=10`` is typical).
* Distance: ``D = dLab**2 + (compactness / S)**2 * dxy**2`` with ``S = sqrt(H * W / n_segments)``
  pixels (the grid step) and ``dxy`` in pixels.
* Cluster ``k`` is seeded in grid cell ``k`` (an ``ny x nx`` grid of near-square cells), optionally
  moved to the lowest-gradient pixel of its 3x3 neighbourhood. Assignment is pixel-centric as in
  fast_slic: a pixel only compares to the clusters seeded in its own and the 8 neighbouring grid
  cells (the classic SLIC 2S x 2S search window, seen from the pixel). Every pixel is assigned in every
  iteration; nothing is subsampled.
* For speed the image is stored cell by cell (block-major, uint8 Lab, uint16 in-cell coordinates)
  and distances are expanded as ``|m|^2 - 2 <c, m>`` (per-pixel constant terms dropped, the Lab
  scaling folded into the coefficients), so the inner loop is 5 float32 fused multiply-adds per
  candidate over a contiguous cell, vectorised by LLVM. Cells are processed in parallel
  (``prange``); each cell writes exact integer partial sums to its own slot and the centres are
  reduced from them in a fixed order, so the result does not depend on the thread count.
* Connectivity (optional, default on): 4-connected components of the label map are found on runs
  (union-find over horizontal runs); components smaller than ``min_size_factor * S**2`` pixels are
  merged into the component that touches their first pixel (scan order) from the left or from
  above, every other component becomes its own superpixel. Labels are then contiguous ``0..K-1``
  in scan order of each superpixel's first pixel.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

__all__ = ['SuperpixelStats', 'slic', 'split_at_depth_edges', 'superpixel_stats']

_PAD = 32  # cell slots in the block-major arrays are padded to a multiple of this
_ACC_CHUNK = 16384  # pixels per int32 partial sum: 16384 * 65535 < 2**31


# --------------------------------------------------------------------------------------------- grid


@dataclass(frozen=True, eq=False)
class _Layout:
    """The seed grid and the block-major pixel order for one image size and ``n_segments``.

    Cell ``k = cy * nx + cx`` covers rows ``yb[cy]:yb[cy + 1]`` and columns ``xb[cx]:xb[cx + 1]``; its
    pixels start at ``off[k]`` in the block-major arrays, row-major inside the cell, and the cell's
    slot ends at ``off[k + 1]``: slots are padded to a multiple of ``_PAD`` so that the vectorised
    loops have no scalar remainder. ``X``/``Y`` hold each pixel's coordinates relative to the
    top-left pixel of its cell (0 in the padding).
    """

    yb: NDArray[np.int64]
    xb: NDArray[np.int64]
    step: float
    off: NDArray[np.int64]
    X: NDArray[np.uint16]
    Y: NDArray[np.uint16]


@functools.lru_cache(maxsize=4)
def _layout(height: int, width: int, n_segments: int) -> _Layout:
    step = math.sqrt(height * width / n_segments)
    ny = min(height, max(1, round(height / step)))
    nx = min(width, max(1, round(width / step)))
    yb = np.round(np.linspace(0, height, ny + 1)).astype(np.int64)
    xb = np.round(np.linspace(0, width, nx + 1)).astype(np.int64)
    sizes = np.diff(yb)[:, None] * np.diff(xb)[None, :]
    off = np.zeros(ny * nx + 1, np.int64)
    np.cumsum(-(-sizes.ravel() // _PAD) * _PAD, out=off[1:])
    X = np.zeros(off[-1], np.uint16)
    Y = np.zeros(off[-1], np.uint16)
    _cell_coords(yb, xb, off, X, Y)
    for arr in (yb, xb, off, X, Y):
        arr.flags.writeable = False
    return _Layout(yb, xb, step, off, X, Y)


@njit(cache=True)
def _cell_coords(yb, xb, off, X, Y):
    nx = xb.size - 1
    for cy in range(yb.size - 1):
        for cx in range(nx):
            i = off[cy * nx + cx]
            for yy in range(yb[cy + 1] - yb[cy]):
                for xx in range(xb[cx + 1] - xb[cx]):
                    X[i] = xx
                    Y[i] = yy
                    i += 1


@njit(cache=True)
def _to_blocks(lab8, yb, xb, off, L, A, B):
    """Copy the uint8 Lab image cell by cell into planar uint8 arrays (still in cv2's 8-bit units)."""
    w = lab8.shape[1]
    src = lab8.reshape(-1)
    nx = xb.size - 1
    for cy in range(yb.size - 1):
        for y in range(yb[cy], yb[cy + 1]):
            for cx in range(nx):
                x0 = xb[cx]
                bw = xb[cx + 1] - x0
                i = off[cy * nx + cx] + (y - yb[cy]) * bw
                p = (y * w + x0) * 3
                for t in range(bw):
                    L[i + t] = src[p + 3 * t]
                    A[i + t] = src[p + 3 * t + 1]
                    B[i + t] = src[p + 3 * t + 2]


@njit(cache=True)
def _lab_at(lab8, y, x):
    return (
        np.float64(lab8[y, x, 0]) * (100.0 / 255.0),
        np.float64(lab8[y, x, 1]) - 128.0,
        np.float64(lab8[y, x, 2]) - 128.0,
    )


@njit(cache=True)
def _gradient(lab8, y, x):
    """Squared Lab gradient magnitude (central differences, clamped at the border)."""
    h, w = lab8.shape[0], lab8.shape[1]
    l0, a0, b0 = _lab_at(lab8, y, max(x - 1, 0))
    l1, a1, b1 = _lab_at(lab8, y, min(x + 1, w - 1))
    l2, a2, b2 = _lab_at(lab8, max(y - 1, 0), x)
    l3, a3, b3 = _lab_at(lab8, min(y + 1, h - 1), x)
    return (l1 - l0) ** 2 + (a1 - a0) ** 2 + (b1 - b0) ** 2 + (l3 - l2) ** 2 + (a3 - a2) ** 2 + (b3 - b2) ** 2


@njit(cache=True)
def _seed(lab8, yb, xb, on_gradient):
    """Initial centres ``(L, a, b, x, y)`` at cell centres, optionally moved to the 3x3 gradient minimum."""
    h, w = lab8.shape[0], lab8.shape[1]
    ny = yb.size - 1
    nx = xb.size - 1
    cen = np.empty((ny * nx, 5), np.float64)
    for cy in range(ny):
        for cx in range(nx):
            y = (yb[cy] + yb[cy + 1] - 1) // 2
            x = (xb[cx] + xb[cx + 1] - 1) // 2
            if on_gradient:
                best = np.inf
                by, bx = y, x
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        g = _gradient(lab8, yy, xx)
                        if g < best:
                            best, by, bx = g, yy, xx
                y, x = by, bx
            k = cy * nx + cx
            cen[k, 0], cen[k, 1], cen[k, 2] = _lab_at(lab8, y, x)
            cen[k, 3] = x
            cen[k, 4] = y
    return cen


# --------------------------------------------------------------------------------------- iterations


@njit(cache=True, fastmath={'contract'})
def _nearest(L, A, B, X, Y, P, slot):
    """Slot (0..8) of the nearest of 9 candidates for every pixel of one cell.

    ``P[:, j]`` holds candidate ``j``'s coefficients ``(c0, cL, cA, cB, cX, cY)`` of the expanded
    distance ``c0 + cL * L + cA * a + cB * b + cX * x + cY * y`` (per-pixel constants dropped); absent
    candidates have ``c0 = +inf``. Ties go to the lower slot. Returns the bit set of slots used.
    """
    used = 0
    for i in range(L.size):
        lv = np.float32(L[i])
        a = np.float32(A[i])
        b = np.float32(B[i])
        x = np.float32(X[i])
        y = np.float32(Y[i])
        best = P[0, 0] + lv * P[1, 0] + a * P[2, 0] + b * P[3, 0] + x * P[4, 0] + y * P[5, 0]
        bj = 0
        for j in range(1, 9):
            d = P[0, j] + lv * P[1, j] + a * P[2, j] + b * P[3, j] + x * P[4, j] + y * P[5, j]
            if d < best:
                best = d
                bj = j
        slot[i] = np.uint8(bj)
        used |= 1 << bj
    return used


@njit(cache=True)
def _slot_sums(L, A, B, X, Y, slot, j):
    """Count and sums of L8, a8, b8, x, y over the pixels of slot ``j``, exact for <= _ACC_CHUNK pixels."""
    n = np.int32(0)
    sL = np.int32(0)
    sA = np.int32(0)
    sB = np.int32(0)
    sX = np.int32(0)
    sY = np.int32(0)
    for i in range(L.size):
        m = np.int32(slot[i] == j)
        n = np.int32(n + m)
        sL = np.int32(sL + m * np.int32(L[i]))
        sA = np.int32(sA + m * np.int32(A[i]))
        sB = np.int32(sB + m * np.int32(B[i]))
        sX = np.int32(sX + m * np.int32(X[i]))
        sY = np.int32(sY + m * np.int32(Y[i]))
    return n, sL, sA, sB, sX, sY  # 32-bit vector sums; no overflow (see _ACC_CHUNK)


@njit(cache=True)
def _accumulate(L, A, B, X, Y, slot, used, acc):
    """Per-slot int64 sums (count, L8, a8, b8, x, y) of one cell's pixels into ``acc`` (9 x 6)."""
    acc[:, :] = 0
    for c0 in range(0, L.size, _ACC_CHUNK):
        c1 = min(c0 + _ACC_CHUNK, L.size)
        _accumulate_chunk(L[c0:c1], A[c0:c1], B[c0:c1], X[c0:c1], Y[c0:c1], slot[c0:c1], used, acc)


@njit(cache=True)
def _accumulate_chunk(L, A, B, X, Y, slot, used, acc):
    for j in range(9):
        if used & (1 << j):
            n, sL, sA, sB, sX, sY = _slot_sums(L, A, B, X, Y, slot, np.uint8(j))
            acc[j, 0] += n
            acc[j, 1] += sL
            acc[j, 2] += sA
            acc[j, 3] += sB
            acc[j, 4] += sX
            acc[j, 5] += sY


@njit(cache=True)
def _coefficients(cen, yb, xb, cy, cx, w, P):
    """Fill ``P`` (6 x 9) for the clusters around cell ``(cy, cx)``, slot ``(dy + 1) * 3 + dx + 1``."""
    ny = yb.size - 1
    nx = xb.size - 1
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            j = (dy + 1) * 3 + dx + 1
            ky = cy + dy
            kx = cx + dx
            if ky < 0 or ky >= ny or kx < 0 or kx >= nx:
                P[0, j] = np.inf
                P[1:, j] = 0.0
                continue
            c = ky * nx + kx
            mL = cen[c, 0]  # CIELAB L; the pixels are L8 = L * 255 / 100
            mA = cen[c, 1] + 128.0  # a8 units
            mB = cen[c, 2] + 128.0
            mx = cen[c, 3] - xb[cx]
            my = cen[c, 4] - yb[cy]
            P[0, j] = mL * mL + mA * mA + mB * mB + w * (mx * mx + my * my)
            P[1, j] = -2.0 * mL * (100.0 / 255.0)
            P[2, j] = -2.0 * mA
            P[3, j] = -2.0 * mB
            P[4, j] = -2.0 * w * mx
            P[5, j] = -2.0 * w * my


@njit(cache=True, parallel=True)
def _assign(L, A, B, X, Y, off, yb, xb, cen, w, P, slot, acc, accumulate):
    """Assign every pixel to the nearest of the <= 9 clusters around its cell (cells in parallel).

    ``slot[i]`` is ``(dy + 1) * 3 + (dx + 1)`` for the cluster of cell ``(cy + dy, cx + dx)``. With
    ``accumulate`` the per-cell integer sums (count, L8, a8, b8, x_rel, y_rel) go to ``acc[cell, slot]``.
    """
    nx = xb.size - 1
    for k in prange(off.size - 1):
        cy = k // nx
        cx = k - cy * nx
        s = off[k]
        e = off[k + 1]
        _coefficients(cen, yb, xb, cy, cx, w, P[k])
        used = _nearest(L[s:e], A[s:e], B[s:e], X[s:e], Y[s:e], P[k], slot[s:e])
        for i in range(s + (yb[cy + 1] - yb[cy]) * (xb[cx + 1] - xb[cx]), e):
            slot[i] = np.uint8(9)  # padding: matches no slot
        if accumulate:
            _accumulate(L[s:e], A[s:e], B[s:e], X[s:e], Y[s:e], slot[s:e], used, acc[k])


@njit(cache=True)
def _update(acc, yb, xb, cen):
    """New centres = mean of their pixels, summed over the 9 cells in a fixed order; empty ones stay."""
    ny = yb.size - 1
    nx = xb.size - 1
    for c in range(ny * nx):
        cy = c // nx
        cx = c - cy * nx
        n = 0.0
        sL = 0.0
        sA = 0.0
        sB = 0.0
        sX = 0.0
        sY = 0.0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                ky = cy - dy
                kx = cx - dx
                if ky < 0 or ky >= ny or kx < 0 or kx >= nx:
                    continue
                a = acc[ky * nx + kx, (dy + 1) * 3 + dx + 1]
                n += a[0]
                sL += a[1]
                sA += a[2]
                sB += a[3]
                sX += a[4] + a[0] * xb[kx]
                sY += a[5] + a[0] * yb[ky]
        if n > 0.0:
            cen[c, 0] = sL / n * (100.0 / 255.0)
            cen[c, 1] = sA / n - 128.0
            cen[c, 2] = sB / n - 128.0
            cen[c, 3] = sX / n
            cen[c, 4] = sY / n


@njit(cache=True, parallel=True)
def _scatter_labels(slot, off, yb, xb, out):
    """Write the cluster id (cell index of the winning cluster) of every pixel into the image."""
    ny = yb.size - 1
    nx = xb.size - 1
    for k in prange(ny * nx):
        cy = k // nx
        cx = k - cy * nx
        i = off[k]
        for y in range(yb[cy], yb[cy + 1]):
            for x in range(xb[cx], xb[cx + 1]):
                j = slot[i]
                out[y, x] = (cy + j // 3 - 1) * nx + cx + j % 3 - 1
                i += 1


# ------------------------------------------------------------------------------------- connectivity


@njit(cache=True)
def _find(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True)
def _runs(line, r, x1, lab):
    """Append the maximal runs of equal labels of one image row, starting at run index ``r``.

    Branch-free: every pixel rewrites the end and label of the current run. Returns the next index.
    """
    x1[r] = 1
    lab[r] = line[0]
    for x in range(1, line.size):
        r += line[x] != line[x - 1]
        x1[r] = x + 1
        lab[r] = line[x]
    return r + 1


@njit(cache=True)
def _union_rows(a, a_end, b, b_end, x1, lab, parent):
    """Union equal-label runs of two consecutive rows that overlap (4-connectivity)."""
    while a < a_end and b < b_end:
        if lab[a] == lab[b]:
            ra = _find(parent, a)
            rb = _find(parent, b)
            if ra < rb:  # the root is always the first run of a component in scan order
                parent[rb] = ra
            elif rb < ra:
                parent[ra] = rb
        ea = x1[a]
        eb = x1[b]
        a += ea <= eb
        b += eb <= ea


@njit(cache=True)
def _write_row(line, r, final, out):
    """Write ``final[run]`` for every pixel of one row whose first run has index ``r``."""
    out[0] = final[r]
    for x in range(1, line.size):
        r += line[x] != line[x - 1]
        out[x] = final[r]


@njit(cache=True)
def _enforce_connectivity(labels, min_size):
    """Relabel into 4-connected superpixels ``0..K-1``; components < ``min_size`` px join a neighbour."""
    h, w = labels.shape
    x1 = np.empty(h * w, np.int32)  # worst case; only the pages actually written are touched
    lab = np.empty(h * w, np.int32)
    row = np.empty(h + 1, np.int64)
    r = 0
    for y in range(h):
        row[y] = r
        r = _runs(labels[y], r, x1, lab)
    row[h] = r
    n_runs = r

    parent = np.arange(n_runs)
    for y in range(1, h):
        _union_rows(row[y - 1], row[y], row[y], row[y + 1], x1, lab, parent)
    size = np.empty(n_runs, np.int64)
    for y in range(h):
        x0 = 0
        for r in range(row[y], row[y + 1]):
            size[r] = 0
            parent[r] = parent[parent[r]]  # parent[r] <= r: one forward pass flattens the forest
            size[parent[r]] += x1[r] - x0
            x0 = x1[r]

    # Final labels in scan order; a small component joins the component left of (or above) its
    # first pixel, which comes earlier in scan order and is therefore already labelled.
    final = np.empty(n_runs, np.int32)
    n_labels = 0
    for y in range(h):
        for r in range(row[y], row[y + 1]):
            if parent[r] != r:
                final[r] = final[parent[r]]
            elif size[r] < min_size and r > 0:
                final[r] = final[r - 1] if r > row[y] else final[row[y - 1]]
            else:
                final[r] = n_labels
                n_labels += 1
    out = np.empty((h, w), np.int32)
    for y in range(h):
        _write_row(labels[y], row[y], final, out[y])
    return out


def _compact(labels: NDArray[np.int32], n: int) -> NDArray[np.int32]:
    used = np.bincount(labels.ravel(), minlength=n) > 0
    remap = (np.cumsum(used) - 1).astype(np.int32)
    return remap[labels]


# ------------------------------------------------------------------------------------------- public


def slic(
    rgb: NDArray[np.uint8],
    *,
    n_segments: int = 1500,
    compactness: float = 10.0,
    iterations: int = 5,
    seed_on_gradient: bool = True,
    enforce_connectivity: bool = True,
    min_size_factor: float = 0.25,
) -> NDArray[np.int32]:
    """SLIC oversegmentation of an RGB image into about ``n_segments`` superpixels.

    Args:
        rgb: ``uint8`` array ``(H, W, 3)``, RGB order.
        n_segments: wanted number of superpixels; the grid step is ``S = sqrt(H * W / n_segments)`` px.
        compactness: weight ``m`` of the spatial term, ``D = dLab**2 + (m / S)**2 * dxy**2`` (CIELAB).
        iterations: assignment passes (the centres are updated between passes); 4-5 suffice.
        seed_on_gradient: move each seed to the lowest Lab-gradient pixel of its 3x3 neighbourhood.
        enforce_connectivity: make every label one 4-connected region (see the module docstring).
        min_size_factor: fragments smaller than ``min_size_factor * S**2`` px are merged away.

    Returns:
        ``int32`` labels ``(H, W)`` with values ``0..K-1``, every value used. Deterministic: the same
        input gives the same labels, whatever the number of threads.
    """
    img = np.asarray(rgb)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f'rgb must be a uint8 (H, W, 3) array, got {img.dtype} {img.shape}')
    h, w = img.shape[:2]
    if h == 0 or w == 0 or max(h, w) > 65535:
        raise ValueError(f'rgb must be 1..65535 pixels high and wide, got shape {img.shape}')
    if int(n_segments) < 1:
        raise ValueError(f'n_segments must be >= 1, got {n_segments}')
    if not compactness > 0:
        raise ValueError(f'compactness must be > 0, got {compactness}')
    if int(iterations) < 1:
        raise ValueError(f'iterations must be >= 1, got {iterations}')
    if not 0 <= min_size_factor < 1:
        raise ValueError(f'min_size_factor must be in [0, 1), got {min_size_factor}')

    lab8 = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2Lab)
    lay = _layout(h, w, min(int(n_segments), h * w))
    n_cells = lay.off.size - 1
    L, A, B = (np.zeros(lay.off[-1], np.uint8) for _ in range(3))
    _to_blocks(lab8, lay.yb, lay.xb, lay.off, L, A, B)
    cen = _seed(lab8, lay.yb, lay.xb, bool(seed_on_gradient))
    weight = (float(compactness) / lay.step) ** 2
    P = np.empty((n_cells, 6, 9), np.float32)
    slot = np.empty(lay.off[-1], np.uint8)
    acc = np.empty((n_cells, 9, 6), np.int64)
    for it in range(int(iterations)):
        last = it == int(iterations) - 1
        _assign(L, A, B, lay.X, lay.Y, lay.off, lay.yb, lay.xb, cen, weight, P, slot, acc, not last)
        if not last:
            _update(acc, lay.yb, lay.xb, cen)
    labels = np.empty((h, w), np.int32)
    _scatter_labels(slot, lay.off, lay.yb, lay.xb, labels)
    if enforce_connectivity:
        return _enforce_connectivity(labels, int(min_size_factor * lay.step * lay.step))
    return _compact(labels, n_cells)


# ------------------------------------------------------------------------------------ depth edges


@njit(cache=True)
def _split_sky(labels, ld, out):
    """``out = 2 * label + (pixel is sky)``."""
    for i in range(labels.size):
        out[i] = 2 * labels[i] + (1 if ld[i] == np.inf else 0)


@njit(cache=True)
def _split_pass(labels, ld, n, gap, out):
    """One 2-means split of every label on log depth; ``out = 2 * label + (pixel in the far cluster)``.

    ``ld``: log depth, NaN unknown, ``+inf`` sky (both stay in the near cluster). The clusters start
    at the label's minimum and maximum and take 4 Lloyd iterations; a label is split only when the
    two cluster means end up more than ``gap`` apart.
    """
    c0 = np.full(n, np.inf)
    c1 = np.full(n, -np.inf)
    for i in range(labels.size):
        d = ld[i]
        if d == d and d != np.inf:
            k = labels[i]
            c0[k] = min(c0[k], d)
            c1[k] = max(c1[k], d)
    s = np.zeros((n, 4))
    for _ in range(4):
        s[:] = 0.0
        for i in range(labels.size):
            d = ld[i]
            if d == d and d != np.inf:
                k = labels[i]
                f = 2 if d > 0.5 * (c0[k] + c1[k]) else 0
                s[k, f] += d
                s[k, f + 1] += 1.0
        for k in range(n):
            if s[k, 1] > 0:
                c0[k] = s[k, 0] / s[k, 1]
            if s[k, 3] > 0:
                c1[k] = s[k, 2] / s[k, 3]
    for i in range(labels.size):
        k = labels[i]
        d = ld[i]
        far = c1[k] - c0[k] > gap and d == d and d != np.inf and d > 0.5 * (c0[k] + c1[k])
        out[i] = 2 * k + (1 if far else 0)


def split_at_depth_edges(
    labels: NDArray[np.integer],
    depth: NDArray[np.floating],
    *,
    log_gap: float = 0.02,
    levels: int = 2,
    min_size: int = 2,
) -> NDArray[np.int32]:
    """Split superpixels that straddle a depth discontinuity (not in the paper).

    The renderer warps each superpixel as one near-planar patch; a superpixel that covers a roof
    edge and the street below is smeared across the gap. Sky pixels (``+inf``) are first split
    from the rest of their superpixel; then, ``levels`` times, every superpixel whose two log-depth
    clusters (2-means, :func:`_split_pass`) have means more than ``log_gap`` apart (0.02: 2 %) is
    split between them. Unknown depth (0, NaN, negative) stays with the nearer part. The parts are
    made 4-connected; fragments under ``min_size`` px join the part left of or above them (as in
    :func:`slic`).

    Args:
        labels: ``(H, W)`` non-negative integer labels (``slic`` output).
        depth: ``(H, W)`` depth in metres (REP-118: 0/NaN unknown, ``+inf`` sky).

    Returns:
        ``int32`` labels ``0..K'-1`` (``K' >= K``), every value used, each one 4-connected.
    """
    lab = np.asarray(labels)
    dep = np.asarray(depth)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer) or lab.size == 0:
        raise ValueError(f'labels must be a non-empty 2-D integer array, got {lab.dtype} {lab.shape}')
    if dep.shape != lab.shape or not np.issubdtype(dep.dtype, np.floating):
        raise ValueError(f'depth must be a float array of shape {lab.shape}, got {dep.dtype} {dep.shape}')
    if not log_gap > 0 or int(levels) < 0 or int(min_size) < 0:
        raise ValueError(
            f'need log_gap > 0, levels >= 0 and min_size >= 0, got {log_gap}, {levels}, {min_size}'
        )
    top = (2**30 >> (int(levels) + 1)) - 1  # every pass doubles the label values
    if int(lab.min()) < 0 or int(lab.max()) > top:
        raise ValueError(f'labels must be in 0..{top}, got {int(lab.min())}..{int(lab.max())}')
    with np.errstate(divide='ignore', invalid='ignore'):
        ld = np.log(np.where(dep > 0, dep, np.nan)).astype(np.float64).ravel()
    cur = np.empty(lab.size, np.int32)
    nxt = np.empty(lab.size, np.int32)
    _split_sky(np.ascontiguousarray(lab, dtype=np.int32).ravel(), ld, cur)  # the input is not written
    for _ in range(int(levels)):
        _split_pass(cur, ld, int(cur.max()) + 1, float(log_gap), nxt)
        cur, nxt = nxt, cur
    return _enforce_connectivity(cur.reshape(lab.shape), int(min_size))


# -------------------------------------------------------------------------------------------- stats


@dataclass(frozen=True, eq=False)
class SuperpixelStats:
    """Per-superpixel statistics for ``K`` labels of an ``(H, W)`` label image.

    Pixel coordinates: x = column, y = row, pixel centres at integers (OpenCV / ROS convention).

    Attributes:
        shape: ``(H, W)`` of the label image.
        count: ``int32 (K,)`` pixels per superpixel (0 for a label value that does not occur).
        bbox: ``int32 (K, 4)`` inclusive ``(x_min, y_min, x_max, y_max)``; ``-1`` for empty labels.
        centroid: ``float64 (K, 2)`` mean ``(x, y)``; NaN for empty labels.
        median_depth: ``float32 (K,)`` median of the known depth samples (``np.median`` semantics:
            the mean of the two middle samples for an even count); NaN without known samples.
        n_depth: ``int32 (K,)`` number of known depth samples.
        has_depth: ``bool (K,)`` ``n_depth >= max(min_samples, ceil(min_fraction * count))``.
            The renderer does not warp superpixels with ``has_depth == False``: they are left out
            of that source view (holes are filled by other views or stay holes), never warped with
            a guessed depth.
        offsets: ``int64 (K + 1,)`` CSR offsets into ``indices``.
        indices: ``int32 (H * W,)`` flat pixel indices ``y * W + x`` grouped by label, ascending
            within a label: the pixels of superpixel ``k`` are ``indices[offsets[k]:offsets[k + 1]]``.
    """

    shape: tuple[int, int]
    count: NDArray[np.int32]
    bbox: NDArray[np.int32]
    centroid: NDArray[np.float64]
    median_depth: NDArray[np.float32]
    n_depth: NDArray[np.int32]
    has_depth: NDArray[np.bool_]
    offsets: NDArray[np.int64]
    indices: NDArray[np.int32]

    @property
    def n_labels(self) -> int:
        return int(self.count.size)

    def pixels(self, k: int) -> NDArray[np.int32]:
        """Flat pixel indices ``y * W + x`` of superpixel ``k``."""
        return self.indices[self.offsets[k] : self.offsets[k + 1]]


@njit(cache=True)
def _csr(labels, n_labels, bbox, centroid):
    """Counting sort of the pixels by label (raster order within a label), boxes and centroids."""
    h, w = labels.shape
    count = np.zeros(n_labels, np.int64)
    sx = np.zeros(n_labels, np.float64)
    sy = np.zeros(n_labels, np.float64)
    bbox[:, 0] = w
    bbox[:, 1] = h
    bbox[:, 2] = -1
    bbox[:, 3] = -1
    for y in range(h):
        for x in range(w):
            k = labels[y, x]
            count[k] += 1
            sx[k] += x
            sy[k] += y
            bbox[k, 0] = min(bbox[k, 0], x)
            bbox[k, 1] = min(bbox[k, 1], y)
            bbox[k, 2] = max(bbox[k, 2], x)
            bbox[k, 3] = max(bbox[k, 3], y)
    offsets = np.zeros(n_labels + 1, np.int64)
    for k in range(n_labels):
        offsets[k + 1] = offsets[k] + count[k]
        if count[k] == 0:
            bbox[k, :] = -1
            centroid[k, :] = np.nan
        else:
            centroid[k, 0] = sx[k] / count[k]
            centroid[k, 1] = sy[k] / count[k]
    pos = offsets[:-1].copy()
    indices = np.empty(h * w, np.int32)
    flat = labels.ravel()
    for i in range(h * w):
        k = flat[i]
        indices[pos[k]] = i
        pos[k] += 1
    return offsets, indices


@njit(cache=True)
def _select(a, kth):
    """Partially sort ``a`` in place so that ``a[kth]`` is its ``kth`` smallest value (no NaNs).

    Quickselect with a median-of-three pivot and a branch-free Lomuto partition (depth samples
    are data-dependent, so compare-and-branch partitions mispredict about every other element).
    """
    lo = 0
    hi = a.size - 1
    while hi > lo:
        mid = (lo + hi) // 2
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        a[mid], a[hi] = a[hi], a[mid]  # park the pivot at the end
        j = lo
        for i in range(lo, hi):
            x = a[i]
            a[i] = a[j]
            a[j] = x
            j += x < pivot
        a[j], a[hi] = a[hi], a[j]  # a[lo:j] < pivot == a[j] <= a[j + 1:hi + 1]
        if kth < j:
            hi = j - 1
            continue
        e = j + 1  # move the copies of the pivot next to it, so that equal values end the search
        for i in range(j + 1, hi + 1):
            x = a[i]
            a[i] = a[e]
            a[e] = x
            e += x == pivot
        if kth < e:
            break
        lo = e
    return a[kth]


@njit(cache=True)
def _median_inplace(a):
    """``np.median`` of a non-empty NaN-free float32 array, reordering it."""
    h = a.size // 2
    upper = _select(a, h)
    if a.size % 2:
        return upper
    lower = a[0]
    for i in range(1, h):  # after selection a[:h] holds the h smallest values
        lower = max(lower, a[i])
    return (lower + upper) / np.float32(2.0)


@njit(cache=True, parallel=True)
def _median_depth(offsets, indices, depth, median, n_depth):
    """Median of the known (``> 0``, ``+inf`` included) depth samples of every label; NaN if none."""
    flat = depth.ravel()
    for k in prange(offsets.size - 1):
        s = offsets[k]
        buf = np.empty(offsets[k + 1] - s, np.float32)
        m = 0
        for t in range(s, offsets[k + 1]):
            d = flat[indices[t]]
            if d > 0:  # unknown: 0, negative, NaN
                buf[m] = d
                m += 1
        n_depth[k] = m
        if m == 0:
            median[k] = np.nan
            continue
        median[k] = _median_inplace(buf[:m])


def superpixel_stats(
    labels: NDArray[np.integer],
    depth: NDArray[np.floating],
    *,
    min_samples: int = 10,
    min_fraction: float = 0.05,
    n_labels: int | None = None,
) -> SuperpixelStats:
    """Pixel lists, boxes, centroids and median depth of every superpixel.

    Args:
        labels: ``(H, W)`` non-negative integer labels (``slic`` output).
        depth: ``(H, W)`` depth in metres (REP-118): ``> 0`` is a known sample, ``+inf`` included
            (sky: a sky superpixel gets median ``+inf``); 0, negative and NaN are unknown.
        min_samples, min_fraction: a superpixel ``has_depth`` when it has at least
            ``max(min_samples, ceil(min_fraction * count))`` known samples (default: 10 and 5 %).
        n_labels: number of labels ``K`` (default ``labels.max() + 1``).
    """
    lab = np.asarray(labels)
    dep = np.asarray(depth)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f'labels must be a 2-D integer array, got {lab.dtype} {lab.shape}')
    if dep.shape != lab.shape or not np.issubdtype(dep.dtype, np.floating):
        raise ValueError(f'depth must be a float array of shape {lab.shape}, got {dep.dtype} {dep.shape}')
    if lab.size == 0:
        raise ValueError('labels must not be empty')
    if int(lab.min()) < 0:
        raise ValueError(f'labels must be >= 0, got min {int(lab.min())}')
    k = int(lab.max()) + 1 if n_labels is None else int(n_labels)
    if k < int(lab.max()) + 1:
        raise ValueError(f'n_labels={n_labels} is smaller than labels.max() + 1 = {int(lab.max()) + 1}')
    if int(min_samples) < 0 or not 0 <= min_fraction <= 1:
        raise ValueError(
            f'need min_samples >= 0 and 0 <= min_fraction <= 1, got {min_samples}, {min_fraction}'
        )
    bbox = np.empty((k, 4), np.int32)
    centroid = np.empty((k, 2), np.float64)
    offsets, indices = _csr(np.ascontiguousarray(lab, dtype=np.int32), k, bbox, centroid)
    median = np.empty(k, np.float32)
    n_depth = np.empty(k, np.int32)
    _median_depth(offsets, indices, np.ascontiguousarray(dep, np.float32), median, n_depth)
    count = np.diff(offsets).astype(np.int32)
    need = np.maximum(int(min_samples), np.ceil(min_fraction * count)).astype(np.int64)
    return SuperpixelStats(
        shape=(int(lab.shape[0]), int(lab.shape[1])),
        count=count,
        bbox=bbox,
        centroid=centroid,
        median_depth=median,
        n_depth=n_depth,
        has_depth=(n_depth >= need) & (count > 0),
        offsets=offsets,
        indices=indices,
    )
