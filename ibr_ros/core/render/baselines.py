"""Baseline kernels for evaluation: point splatting and unstructured-lumigraph blending."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ibr_ros.core.render.blend import bilinear, put_rgb
from ibr_ros.core.render.warp import project_pixel


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
