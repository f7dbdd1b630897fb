# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Renderer baselines for evaluation (not on the product path): point splatting and an unstructured
lumigraph (ULR) blend, with :class:`~ibr_ros.core.render.renderer.NovelViewRenderer`'s interface,
view selection and refusals.

:class:`SplatRenderer` forward-warps every pixel with depth of the ``n_splat`` nearest selected
views as a 1-pixel splat with a z-buffer. :class:`UlrRenderer` blends in the spirit of SIBR
``ulr_v3``: the depth maps of the selected views are splatted into the novel view (z-buffer min,
then one 3x3 pass fills single-pixel cracks with the nearest neighbour's depth); every novel pixel's
3D point is reprojected into each selected view, kept if the view's own depth there agrees within
``occlusion_eps`` (relative), penalised by
``angle (rad) + resolution_weight * max(0, (|P - C_i| - |P - C_n|) / |P - C_i|)`` and blended with
weights ``1 - p / p_max`` over the kept views (equal weights if those are all 0). ``Rendered.depth``
is the splatted novel-view z-depth (m). Both use ``RenderConfig.n_views``, ``near`` and the view
selection settings; the superpixel settings do not apply.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render.blend import bilinear, put_rgb
from ibr_ros.core.render.config import RenderConfig
from ibr_ros.core.render.projection import intrinsics_vector, relative_pose
from ibr_ros.core.render.renderer import NovelViewRenderer, Rendered, SourceView
from ibr_ros.core.render.warp import project_pixel

__all__ = ['SplatRenderer', 'UlrRenderer']


class SplatRenderer(NovelViewRenderer):
    """Point-splat baseline (see the module docstring): ``n_splat`` (>= 1, at most
    ``config.n_views``) nearest selected views, 1-pixel splats, z-buffer."""

    def __init__(
        self, views: Sequence[SourceView], config: RenderConfig | None = None, *, n_splat: int = 1
    ) -> None:
        if not n_splat > 0:
            raise ValueError(f'n_splat must be > 0, got {n_splat}')
        super().__init__(views, config)
        self.n_splat = n_splat

    def prepare(self, indices: Sequence[int] | None = None) -> None:
        """Nothing to prepare: splatting keeps no per-view cache."""

    def _render_views(
        self, t_wn: NDArray[np.float64], camera: PinholeCamera, cands: Sequence[int]
    ) -> Rendered:
        cands = cands[: min(self.config.n_views, self.n_splat)]
        h, w = camera.height, camera.width
        out_rgb = np.zeros((h, w, 3), np.uint8)
        z = np.full((h, w), np.inf, np.float64)
        claimed = np.zeros((h, w), np.bool_)
        src = np.full((h, w), -1, np.int16)
        kn = intrinsics_vector(camera)
        for i in cands:
            v = self.views[i]
            before = claimed.copy()
            zb = z.copy()
            r, t = relative_pose(t_wn, v.t_wc)
            depth = self.view_depth(i)
            _splat(
                v.rgb,
                depth,
                intrinsics_vector(v.camera),
                kn,
                r,
                t,
                self.config.near,
                out_rgb,
                z,
                claimed,
                True,
            )
            src[claimed & (~before | (z < zb))] = i
        depth = np.where(claimed, z, 0.0).astype(np.float32)
        return Rendered(out_rgb, claimed, src, depth, list(cands), None, self.skipped_views)


class UlrRenderer(NovelViewRenderer):
    """Unstructured-lumigraph baseline (see the module docstring) over the ``config.n_views``
    nearest selected views; ``occlusion_eps`` (relative depth) and ``resolution_weight`` as there."""

    def __init__(
        self,
        views: Sequence[SourceView],
        config: RenderConfig | None = None,
        *,
        occlusion_eps: float = 0.05,
        resolution_weight: float = 0.1,
    ) -> None:
        super().__init__(views, config)
        self.occlusion_eps = occlusion_eps
        self.resolution_weight = resolution_weight

    def prepare(self, indices: Sequence[int] | None = None) -> None:
        """Nothing to prepare: ULR keeps no per-view cache."""

    def _render_views(
        self, t_wn: NDArray[np.float64], camera: PinholeCamera, cands: Sequence[int]
    ) -> Rendered:
        cands = cands[: self.config.n_views]
        cfg = self.config
        h, w = camera.height, camera.width
        kn = intrinsics_vector(camera)
        nz = np.full((h, w), np.inf, np.float64)
        claimed = np.zeros((h, w), np.bool_)
        dummy = np.zeros((1, 1, 3), np.uint8)
        for i in cands:
            v = self.views[i]
            r, t = relative_pose(t_wn, v.t_wc)
            depth = self.view_depth(i)
            _splat(dummy, depth, intrinsics_vector(v.camera), kn, r, t, cfg.near, dummy, nz, claimed, False)
        _fill_cracks(nz, claimed)
        n = len(cands)
        rgb_v = np.zeros((n, h, w, 3), np.uint8)
        pen_v = np.empty((n, h, w), np.float64)
        for j, i in enumerate(cands):
            v = self.views[i]
            r_sn, t_sn = relative_pose(v.t_wc, t_wn)  # novel frame -> view frame
            depth = self.view_depth(i)
            _ulr_view(
                v.rgb,
                depth,
                intrinsics_vector(v.camera),
                kn,
                r_sn,
                t_sn,
                nz,
                claimed,
                self.occlusion_eps,
                self.resolution_weight,
                rgb_v[j],
                pen_v[j],
            )
        out_rgb, valid, src, depth = self._alloc(camera)
        _ulr_blend(rgb_v, pen_v, np.array(cands, np.int16), nz, out_rgb, valid, src, depth)
        return Rendered(out_rgb, valid, src, depth.astype(np.float32), list(cands), None, self.skipped_views)


# ------------------------------------------------------------------------------ numba kernels


@njit(cache=True)
def _splat(rgb, depth, ki, kn, r, t, near, out_rgb, out_z, claimed, with_colour):
    """Forward-splat every pixel with depth to its nearest novel pixel; keep the nearest (z-buffer)."""
    h, w = depth.shape
    oh, ow = out_z.shape
    for v in range(h):
        for u in range(w):
            d = np.float64(depth[v, u])
            if not d > 0:
                continue
            x, y, zz = project_pixel(r, t, ki, kn, np.float64(u), np.float64(v), d, near)
            if zz != zz:
                continue
            if not (-0.5 <= x < ow - 0.5 and -0.5 <= y < oh - 0.5):
                continue
            xi = math.floor(x + 0.5)
            yi = math.floor(y + 0.5)
            if claimed[yi, xi] and not zz < out_z[yi, xi]:
                continue
            claimed[yi, xi] = True
            out_z[yi, xi] = zz
            if with_colour:
                for c in range(3):
                    out_rgb[yi, xi, c] = rgb[v, u, c]


@njit(cache=True)
def _fill_cracks(z, claimed):
    """One 3x3 pass: an unclaimed pixel with claimed neighbours takes their smallest depth."""
    h, w = z.shape
    src = z.copy()
    had = claimed.copy()
    for y in range(h):
        for x in range(w):
            if had[y, x]:
                continue
            best = np.inf
            found = False
            for yy in range(max(y - 1, 0), min(y + 2, h)):
                for xx in range(max(x - 1, 0), min(x + 2, w)):
                    if had[yy, xx] and (not found or src[yy, xx] < best):
                        best = src[yy, xx]
                        found = True
            if found:
                z[y, x] = best
                claimed[y, x] = True


@njit(cache=True, parallel=True)
def _ulr_view(rgb, depth, ki, kn, r_in, t_in, nz, claimed, eps, res_w, out_rgb, out_pen):
    """ULR penalty and colour of one source view at every novel pixel (``+inf`` penalty: not seen).

    ``r_in``, ``t_in`` map novel-frame points into the view's frame; the view centre in the novel
    frame is ``c = -r_in^T t_in``.
    """
    oh, ow = nz.shape
    h, w = depth.shape
    cx = -(r_in[0, 0] * t_in[0] + r_in[1, 0] * t_in[1] + r_in[2, 0] * t_in[2])
    cy = -(r_in[0, 1] * t_in[0] + r_in[1, 1] * t_in[1] + r_in[2, 1] * t_in[2])
    cz = -(r_in[0, 2] * t_in[0] + r_in[1, 2] * t_in[1] + r_in[2, 2] * t_in[2])
    for y in prange(oh):
        for x in range(ow):
            out_pen[y, x] = np.inf
            if not claimed[y, x]:
                continue
            d = np.float64(nz[y, x])
            px = (x - kn[2]) / kn[0]
            py = (y - kn[3]) / kn[1]
            pz = 1.0
            sky = d == np.inf
            if not sky:
                px *= d
                py *= d
                pz = d
            xc = r_in[0, 0] * px + r_in[0, 1] * py + r_in[0, 2] * pz
            yc = r_in[1, 0] * px + r_in[1, 1] * py + r_in[1, 2] * pz
            zc = r_in[2, 0] * px + r_in[2, 1] * py + r_in[2, 2] * pz
            if not sky:
                xc += t_in[0]
                yc += t_in[1]
                zc += t_in[2]
            if not zc > 1e-9:
                continue
            u = ki[0] * xc / zc + ki[2]
            v = ki[1] * yc / zc + ki[3]
            if not (-0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
                continue
            ui = math.floor(u + 0.5)
            vi = math.floor(v + 0.5)
            dv = np.float64(depth[vi, ui])
            if sky:
                if dv != np.inf:
                    continue
                pen = 0.0
            else:
                if not (dv < np.inf and abs(dv - zc) <= eps * zc):
                    continue
                qx, qy, qz = px - cx, py - cy, pz - cz
                di = math.sqrt(qx * qx + qy * qy + qz * qz)
                dn = math.sqrt(px * px + py * py + pz * pz)
                c = (qx * px + qy * py + qz * pz) / max(di * dn, 1e-300)
                pen = math.acos(min(1.0, max(-1.0, c))) + res_w * max(0.0, (di - dn) / di)
            out_pen[y, x] = pen
            cr, cg, cb = bilinear(rgb, u, v)
            put_rgb(out_rgb, y, x, cr, cg, cb)


@njit(cache=True, parallel=True)
def _ulr_blend(rgb, pen, ids, nz, out_rgb, out_valid, out_src, out_depth):
    """ULR weights ``1 - p / p_max`` over the views that see each pixel (equal weights if all 0)."""
    n, h, w = pen.shape
    for y in prange(h):
        for x in range(w):
            pmax = -1.0
            pmin = np.inf
            best = -1
            cnt = 0
            for i in range(n):
                p = pen[i, y, x]
                if p < np.inf:
                    cnt += 1
                    pmax = max(pmax, p)
                    if p < pmin:
                        pmin = p
                        best = i
            if cnt == 0:
                out_valid[y, x] = False
                out_src[y, x] = -1
                out_depth[y, x] = 0.0
                for c in range(3):
                    out_rgb[y, x, c] = 0
                continue
            s = np.zeros(3)
            sw = 0.0
            for i in range(n):
                p = pen[i, y, x]
                if p < np.inf:
                    wt = 1.0 - p / pmax if pmax > 0 else 1.0
                    for c in range(3):
                        s[c] += wt * rgb[i, y, x, c]
                    sw += wt
            if not sw > 1e-12:
                s[:] = 0.0
                for i in range(n):
                    if pen[i, y, x] < np.inf:
                        for c in range(3):
                            s[c] += rgb[i, y, x, c]
                sw = cnt
            for c in range(3):
                out_rgb[y, x, c] = np.uint8(s[c] / sw + 0.5)
            out_valid[y, x] = True
            out_src[y, x] = ids[best]
            out_depth[y, x] = nz[y, x]
