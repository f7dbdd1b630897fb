# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Numba ray caster for :class:`~ibr_ros.core.synth.scene.Scene` with exact ground truth.

Shading is view-independent: every surface colour is a function of the 3D point only (procedural
albedo in world / object coordinates with features >= ~10 cm and soft 3-5 cm edges, Lambertian
sun with a hard shadow ray, hemispherical ambient, haze by distance of the point from the town
centre), so one 3D point has the same colour in every view. The sky is a function of the ray
direction only. Foliage is not self-shadowed (wrapped Lambert on the sphere normal instead).

Geometry: ground plane z = 0 (out to ``world_r``), boxes (slab test in the box frame), crowns
(sphere-traced noise-displaced spheres, see _hit_crown), trunks (cylinders), hills (ellipsoids).
Primary rays walk a uniform 2D grid (DDA) that skips cells whose objects are all below the ray;
shadow rays look up one cell of a grid in the plane orthogonal to the sun.

Anti-aliasing (``antialias=True``): adaptive quincunx sampling. The colour of a pixel is
``0.5 * centre + 0.125 * (4 pixel corners)``; a corner sample, shared by the 4 pixels around
it, is traced only where those pixels' centre colours differ by more than ``aa_contrast`` or
their labels differ, and is their mean elsewhere (1 to 2 primary rays per pixel). Depth, sky
mask and labels always come from the pixel-centre ray.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal, TypedDict

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import validate_pose
from ibr_ros.core.synth.scene import FACADE_STONE, FACADE_UNIFORM, PARAM_INDEX, Scene

__all__ = [
    'LABEL_BUILDING_WALL',
    'LABEL_GROUND',
    'LABEL_HILL',
    'LABEL_NAMES',
    'LABEL_ROAD',
    'LABEL_ROOF',
    'LABEL_SKY',
    'LABEL_TREE',
    'SynthFrame',
    'render_view',
    'shade_rays',
]

LABEL_SKY = 0
LABEL_GROUND = 1
LABEL_ROAD = 2  # asphalt, markings and sidewalks
LABEL_BUILDING_WALL = 3
LABEL_ROOF = 4
LABEL_TREE = 5  # foliage and trunks
LABEL_HILL = 6
LABEL_NAMES = ('sky', 'ground', 'road', 'wall', 'roof', 'tree', 'hill')


@dataclass(frozen=True, eq=False)
class SynthFrame:
    """One rendered view.

    ``rgb``: HxWx3 uint8; ``depth``: HxW float32 z-depth in metres along the optical axis (not the
    ray length), +inf for sky; ``sky``: HxW bool, equal to ``isinf(depth)``; ``label``: HxW uint8
    class ids (``LABEL_*``, names in ``LABEL_NAMES``).
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    sky: NDArray[np.bool_]
    label: NDArray[np.uint8]


class _JitOptions(TypedDict, total=False):
    """The `njit` keywords used here, typed so that `njit(**_OPTS)` type-checks."""

    cache: bool
    fastmath: bool
    error_model: Literal['python', 'numpy']
    nogil: bool
    inline: Literal['never', 'always']


_OPTS: _JitOptions = {'cache': True, 'fastmath': False, 'error_model': 'numpy', 'nogil': True}
_INLINE: _JitOptions = {**_OPTS, 'inline': 'always'}
_INF = math.inf

# Scalar parameter indices (compile-time constants in the kernels).
_EXTENT = PARAM_INDEX['extent']
_ROAD_X0 = PARAM_INDEX['road_x0']
_ROAD_SP = PARAM_INDEX['road_sp']
_ROAD_N = PARAM_INDEX['road_n']
_ROAD_HW = PARAM_INDEX['road_hw']
_WALK_W = PARAM_INDEX['walk_w']
_SUN = PARAM_INDEX['sun_x']
_SUN_RGB = PARAM_INDEX['sun_r']
_AMB = PARAM_INDEX['amb_r']
_ZEN = PARAM_INDEX['zen_r']
_HOR = PARAM_INDEX['hor_r']
_CLOUD = PARAM_INDEX['cloud_cover']
_HILL_RMIN = PARAM_INDEX['hill_rmin']
_WORLD_R = PARAM_INDEX['world_r']
_HAZE_R0 = PARAM_INDEX['haze_r0']
_HAZE_R1 = PARAM_INDEX['haze_r1']
_HAZE_MAX = PARAM_INDEX['haze_max']
_FOL_AMP = PARAM_INDEX['foliage_amp']
_FOL_FREQ = PARAM_INDEX['foliage_freq']
_SEED = PARAM_INDEX['seed']

# Flat scene layout (see _pack): float data fv, int data iv; iv[0:_N_HEAD] holds the offsets of the
# blocks (offsets into fv: _O_BOX.._O_SD, into iv: _O_STREE.._O_HBI) and the counts _N_*. Arrays are
# passed to the kernels as these two (plus tuples of scalars) because numba reference-counts every
# array argument of every call with atomic operations, which dominated the run time.
(_O_BOX, _O_MAT, _O_SPH, _O_TRK, _O_TRGB, _O_TREE, _O_HILL, _O_GF, _O_CZ, _O_SF, _O_SD) = range(11)
(_O_STREE, _O_TSTART, _O_GN, _O_CST, _O_CIT, _O_SN, _O_SST, _O_SIT, _O_HBS, _O_HBI) = range(11, 21)
_N_BOX, _N_SPH, _N_TREE, _N_HILL, _N_HB = range(21, 26)
_N_HEAD = 26
_BOX_W, _MAT_W = 7, 12

# Hit kinds returned by the tracers.
_K_NONE, _K_BOX, _K_FOLIAGE, _K_TRUNK, _K_GROUND, _K_HILL = 0, 1, 2, 3, 4, 5


# -- noise -----------------------------------------------------------------------------------------
@njit(**_OPTS)
def _hash(ix: int, iy: int, iz: int, s: int) -> float:
    """Uniform [0, 1) hash of an integer lattice point (murmur3 finaliser on 32 bits)."""
    h = (ix * 0x27D4EB2F + iy * 0x165667B1 + iz * 0x3C6EF372 + s * 0x9E3779B1) & 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & 0xFFFFFFFF
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & 0xFFFFFFFF
    h ^= h >> 16
    return h / 4294967296.0


@njit(**_OPTS)
def _vnoise2(x: float, y: float, s: int) -> float:
    """Smooth value noise in [0, 1] with unit lattice spacing."""
    fx, fy = math.floor(x), math.floor(y)
    ix, iy = int(fx), int(fy)
    tx, ty = x - fx, y - fy
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    a = _hash(ix, iy, 0, s)
    b = _hash(ix + 1, iy, 0, s)
    c = _hash(ix, iy + 1, 0, s)
    d = _hash(ix + 1, iy + 1, 0, s)
    return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * ty


@njit(**_OPTS)
def _vnoise3(x: float, y: float, z: float, s: int) -> float:
    """Smooth 3D value noise in [0, 1] with unit lattice spacing."""
    fx, fy, fz = math.floor(x), math.floor(y), math.floor(z)
    ix, iy, iz = int(fx), int(fy), int(fz)
    tx, ty, tz = x - fx, y - fy, z - fz
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    tz = tz * tz * (3.0 - 2.0 * tz)
    v0 = 0.0
    v1 = 0.0
    for k in range(2):
        a = _hash(ix, iy, iz + k, s)
        b = _hash(ix + 1, iy, iz + k, s)
        c = _hash(ix, iy + 1, iz + k, s)
        d = _hash(ix + 1, iy + 1, iz + k, s)
        ab = a + (b - a) * tx
        v = ab + ((c + (d - c) * tx) - ab) * ty
        if k == 0:
            v0 = v
        else:
            v1 = v
    return v0 + (v1 - v0) * tz


@njit(**_OPTS)
def _fbm2(x: float, y: float, s: int, octaves: int) -> float:
    """Fractal sum of value noise, normalised to [0, 1]."""
    amp, tot, acc = 0.5, 0.0, 0.0
    for o in range(octaves):
        acc += amp * _vnoise2(x, y, s + 17 * o)
        tot += amp
        x, y = 2.03 * x + 0.37, 2.03 * y + 0.61
        amp *= 0.5
    return acc / tot


@njit(**_OPTS)
def _smoothstep(a: float, b: float, x: float) -> float:
    t = min(max((x - a) / (b - a), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


@njit(**_OPTS)
def _band(x: float, half: float, soft: float) -> float:
    """1 inside |x| < half, 0 outside, with a smooth ramp of width 2 * soft (world units)."""
    return 1.0 - _smoothstep(half - soft, half + soft, abs(x))


@njit(**_OPTS)
def _stripes(x: float, period: float, duty: float, soft: float) -> float:
    """Soft periodic stripes: 1 on ``[0, duty * period)`` of every period, ramps of ``2 * soft``."""
    half = 0.5 * duty * period
    m = (x - half) % period
    return _band(min(m, period - m), half, soft)


# -- primitive intersections (unit ray direction; return inf on a miss) --------------------------------
@njit(**_OPTS)
def _hit_box(ox, oy, oz, dx, dy, dz, cx, cy, hx, hy, h, c, s, tmin, tmax):
    """Entry distance and face (0 +x, 1 -x, 2 +y, 3 -y local walls, 4 roof) of a z-rotated box."""
    rx, ry = ox - cx, oy - cy
    lo = (c * rx + s * ry, -s * rx + c * ry, oz)
    ld = (c * dx + s * dy, -s * dx + c * dy, dz)
    lim_lo = (-hx, -hy, 0.0)
    lim_hi = (hx, hy, h)
    t0, t1, face = tmin, tmax, -1
    for a in range(3):
        if ld[a] == 0.0:
            if lo[a] < lim_lo[a] or lo[a] > lim_hi[a]:
                return _INF, -1
            continue
        inv = 1.0 / ld[a]
        ta = (lim_lo[a] - lo[a]) * inv
        tb = (lim_hi[a] - lo[a]) * inv
        if ta > tb:
            ta, tb = tb, ta
        if ta > t0:
            t0 = ta
            face = 2 * a + (1 if ld[a] > 0.0 else 0)
        if tb < t1:
            t1 = tb
    if face < 0 or face == 5 or t0 > t1:
        return _INF, -1
    return t0, face


@njit(**_INLINE)
def _crown_f(px, py, pz, fv, s0, s1, amp, freq, seed):
    """Implicit of a crown at p (< 0 inside, Lipschitz, metres), nearest sphere, shape noise.

    Sphere ``k`` (rows ``s0:s1`` of the sphere block, fv offsets) is
    ``|p - c_k| <= r_k (1 + amp (2 n(p) - 1))`` with ``n`` one octave of value noise in world
    coordinates; the crown is their union (min).
    """
    n = _vnoise3(px * freq, py * freq, pz * freq, seed)
    scale = 1.0 + amp * (2.0 * n - 1.0)
    f, kmin = _INF, -1
    for k in range(s0, s1, 4):
        fk = math.sqrt((px - fv[k]) ** 2 + (py - fv[k + 1]) ** 2 + (pz - fv[k + 2]) ** 2) - fv[k + 3] * scale
        if fk < f:
            f, kmin = fk, k
    return f, kmin, n


@njit(**_OPTS)
def _hit_crown(ox, oy, oz, dx, dy, dz, fv, tb, s0, s1, tmin, tmax, amp, freq, seed, any_hit):
    """First hit of the crown with bound sphere fv[tb:tb+4] and spheres fv[s0:s1] (see _crown_f).

    Returns (t, fv offset of the nearest sphere, shape noise). Steps by the Lipschitz bound or,
    when larger, a secant prediction capped at 15 cm (so a grazing sliver thinner than that
    along the ray may be skipped), then regula falsi (Illinois) once a sign change is bracketed;
    converges to 1 mm (``any_hit``: returns on bracketing).
    """
    qx, qy, qz = ox - fv[tb], oy - fv[tb + 1], oz - fv[tb + 2]
    b = qx * dx + qy * dy + qz * dz
    disc = b * b - (qx * qx + qy * qy + qz * qz - fv[tb + 3] * fv[tb + 3])
    if disc <= 0.0 or -b + math.sqrt(disc) < tmin or -b - math.sqrt(disc) > tmax:
        return _INF, -1, 0.0
    t0, t1, rmax = _INF, -_INF, 0.0
    for k in range(s0, s1, 4):
        rb = fv[k + 3] * (1.0 + amp)
        qx, qy, qz = ox - fv[k], oy - fv[k + 1], oz - fv[k + 2]
        b = qx * dx + qy * dy + qz * dz
        disc = b * b - (qx * qx + qy * qy + qz * qz - rb * rb)
        if disc > 0.0:
            sq = math.sqrt(disc)
            t0 = min(t0, -b - sq)
            t1 = max(t1, -b + sq)
            rmax = max(rmax, fv[k + 3])
    t = max(t0, tmin)
    tend = min(t1, tmax)
    if t > tend:
        return _INF, -1, 0.0
    # |grad n| <= 1.5 sqrt(3) freq for smoothstep value noise.
    lip = 1.0 + rmax * amp * 2.0 * 2.6 * freq
    f, k, n = _crown_f(ox + t * dx, oy + t * dy, oz + t * dz, fv, s0, s1, amp, freq, seed)
    tp, fp = t, _INF
    for _ in range(200):
        if f < 1e-3:
            return t, k, n
        step = f / lip  # always safe
        if fp > f:
            # Secant prediction of the root, slightly overshot to bracket it, capped at 15 cm.
            step = max(step, min(1.1 * f * (t - tp) / (fp - f), 0.15))
        if t + f / lip > tend:
            return _INF, -1, 0.0
        tn = min(t + step, tend)
        fn, kn, nn = _crown_f(ox + tn * dx, oy + tn * dy, oz + tn * dz, fv, s0, s1, amp, freq, seed)
        if fn < 0.0 and any_hit:
            return tn, kn, nn
        if fn < 0.0:
            # Bracketed: f(t) > 0 > f(tn); regula falsi (Illinois).
            a, fa, c, fc, side = t, f, tn, fn, 0
            for _ in range(40):
                tm = (a * fc - c * fa) / (fc - fa)
                fm, km, nm = _crown_f(ox + tm * dx, oy + tm * dy, oz + tm * dz, fv, s0, s1, amp, freq, seed)
                if abs(fm) < 1e-3 or c - a < 2e-3:
                    return tm, km, nm
                if fm > 0.0:
                    a, fa = tm, fm
                    if side == 1:
                        fc *= 0.5
                    side = 1
                else:
                    c, fc = tm, fm
                    if side == -1:
                        fa *= 0.5
                    side = -1
            return a, km, nm
        tp, fp = t, f
        t, f, k, n = tn, fn, kn, nn
    return _INF, -1, 0.0


@njit(**_OPTS)
def _hit_trunk(ox, oy, oz, dx, dy, dz, x, y, r, h, tmin, tmax):
    """Outer surface of a vertical cylinder of radius r at (x, y) from z = 0 to z = h."""
    rx, ry = ox - x, oy - y
    a = dx * dx + dy * dy
    if a < 1e-12:
        return _INF
    b = rx * dx + ry * dy
    disc = b * b - a * (rx * rx + ry * ry - r * r)
    if disc <= 0.0:
        return _INF
    t = (-b - math.sqrt(disc)) / a
    if t < tmin or t > tmax:
        return _INF
    z = oz + t * dz
    if z < 0.0 or z > h:
        return _INF
    return t


@njit(**_OPTS)
def _hit_ellipsoid(ox, oy, oz, dx, dy, dz, cx, cy, cz, ea, eb, ec, tmin, tmax):
    qx, qy, qz = (ox - cx) / ea, (oy - cy) / eb, (oz - cz) / ec
    ex, ey, ez = dx / ea, dy / eb, dz / ec
    a = ex * ex + ey * ey + ez * ez
    b = qx * ex + qy * ey + qz * ez
    c = qx * qx + qy * qy + qz * qz - 1.0
    disc = b * b - a * c
    if disc <= 0.0:
        return _INF
    t = (-b - math.sqrt(disc)) / a
    if t < tmin or t > tmax:
        return _INF
    return t


@njit(**_INLINE)
def _hit_tree(ox, oy, oz, dx, dy, dz, fv, iv, ti, tmin, tmax, amp, freq, seed, any_hit):
    """Crown then trunk of tree ti: (t, kind, index, shape noise); index = sphere or tree id."""
    osph = iv[_O_SPH]
    ts0, ts1 = iv[iv[_O_TSTART] + ti], iv[iv[_O_TSTART] + ti + 1]
    tb, s0, s1 = iv[_O_TREE] + 4 * ti, osph + 4 * ts0, osph + 4 * ts1
    t, k, n = _hit_crown(ox, oy, oz, dx, dy, dz, fv, tb, s0, s1, tmin, tmax, amp, freq, seed, any_hit)
    kind, idx = _K_NONE, -1
    if t < _INF:
        kind, idx, tmax = _K_FOLIAGE, (k - osph) // 4, t
        if any_hit:
            return t, kind, idx, n
    o = iv[_O_TRK] + 4 * ti
    tt = _hit_trunk(ox, oy, oz, dx, dy, dz, fv[o], fv[o + 1], fv[o + 2], fv[o + 3], tmin, tmax)
    if tt < _INF:
        return tt, _K_TRUNK, ti, 0.0
    return t, kind, idx, n


# -- tracing -----------------------------------------------------------------------------------------
@njit(**_OPTS)
def _trace_objects(ox, oy, oz, dx, dy, dz, tmin, tmax, fv, iv, par):
    """Nearest box / foliage / trunk hit via a 2D DDA over the grid.

    Returns (t, kind, index, face, shape noise); kind is _K_NONE on a miss.
    """
    og, ocz, ocs, oci = iv[_O_GF], iv[_O_CZ], iv[_O_CST], iv[_O_CIT]
    nx, ny = iv[iv[_O_GN]], iv[iv[_O_GN] + 1]
    x0, y0, cs, zmax = fv[og], fv[og + 1], fv[og + 2], fv[og + 3]
    t0, t1 = tmin, tmax
    lo = (x0, y0, -1.0)
    hi = (x0 + nx * cs, y0 + ny * cs, zmax)
    o = (ox, oy, oz)
    d = (dx, dy, dz)
    for a in range(3):
        if d[a] == 0.0:
            if o[a] < lo[a] or o[a] > hi[a]:
                return _INF, _K_NONE, -1, -1, 0.0
            continue
        ta = (lo[a] - o[a]) / d[a]
        tb = (hi[a] - o[a]) / d[a]
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    if t0 > t1:
        return _INF, _K_NONE, -1, -1, 0.0
    px, py = ox + t0 * dx, oy + t0 * dy
    ix = min(max(math.floor((px - x0) / cs), 0), nx - 1)
    iy = min(max(math.floor((py - y0) / cs), 0), ny - 1)
    if dx > 0.0:
        sx, tnx, tdx = 1, (x0 + (ix + 1) * cs - ox) / dx, cs / dx
    elif dx < 0.0:
        sx, tnx, tdx = -1, (x0 + ix * cs - ox) / dx, -cs / dx
    else:
        sx, tnx, tdx = 0, _INF, _INF
    if dy > 0.0:
        sy, tny, tdy = 1, (y0 + (iy + 1) * cs - oy) / dy, cs / dy
    elif dy < 0.0:
        sy, tny, tdy = -1, (y0 + iy * cs - oy) / dy, -cs / dy
    else:
        sy, tny, tdy = 0, _INF, _INF
    nb, ob = iv[_N_BOX], iv[_O_BOX]
    amp, freq, seed = par[_FOL_AMP], par[_FOL_FREQ], int(par[_SEED])
    best, kind, idx, face, aux = t1, _K_NONE, -1, -1, 0.0
    tenter = t0
    while True:
        cell = iy * nx + ix
        texit = min(tnx, tny)
        # Skip the cell when the ray passes above everything in it.
        if oz + (tenter if dz >= 0.0 else min(texit, t1)) * dz <= fv[ocz + cell]:
            for k in range(iv[ocs + cell], iv[ocs + cell + 1]):
                oid = iv[oci + k]
                if oid < nb:
                    b = ob + _BOX_W * oid
                    t, f = _hit_box(
                        ox,
                        oy,
                        oz,
                        dx,
                        dy,
                        dz,
                        fv[b],
                        fv[b + 1],
                        fv[b + 2],
                        fv[b + 3],
                        fv[b + 4],
                        fv[b + 5],
                        fv[b + 6],
                        tmin,
                        best,
                    )
                    if t < best:
                        best, kind, idx, face = t, _K_BOX, oid, f
                else:
                    t, kk, ii, n = _hit_tree(
                        ox, oy, oz, dx, dy, dz, fv, iv, oid - nb, tmin, best, amp, freq, seed, False
                    )
                    if t < best:
                        best, kind, idx, aux = t, kk, ii, n
        if (kind != _K_NONE and best <= texit) or texit >= t1:
            break
        tenter = texit
        if tnx < tny:
            ix += sx
            tnx += tdx
            if ix < 0 or ix >= nx:
                break
        else:
            iy += sy
            tny += tdy
            if iy < 0 or iy >= ny:
                break
    if kind == _K_NONE:
        return _INF, _K_NONE, -1, -1, 0.0
    return best, kind, idx, face, aux


@njit(**_OPTS)
def _sun_occluded(px, py, pz, fv, iv, par, skip_tree):
    """Whether the ray from p towards the sun hits a box, crown or trunk (sun-space grid).

    Tree ``skip_tree`` is ignored (foliage is not self-shadowed: its shading uses the wrapped
    Lambert term of the sphere normal instead).
    """
    sf, osd, osi, oss = iv[_O_SF], iv[_O_SD], iv[_O_SIT], iv[_O_SST]
    na, nbb = iv[iv[_O_SN]], iv[iv[_O_SN] + 1]
    sx, sy, sz = par[_SUN], par[_SUN + 1], par[_SUN + 2]
    a = px * fv[sf + 3] + py * fv[sf + 4] + pz * fv[sf + 5]
    b = px * fv[sf + 6] + py * fv[sf + 7] + pz * fv[sf + 8]
    ia = math.floor((a - fv[sf]) / fv[sf + 2])
    ib = math.floor((b - fv[sf + 1]) / fv[sf + 2])
    if ia < 0 or ib < 0 or ia >= na or ib >= nbb:
        return False
    d = px * sx + py * sy + pz * sz
    nb, ob = iv[_N_BOX], iv[_O_BOX]
    amp, freq, seed = par[_FOL_AMP], par[_FOL_FREQ], int(par[_SEED])
    cell = ib * na + ia
    for k in range(iv[oss + cell], iv[oss + cell + 1]):
        if fv[osd + k] <= d:
            continue
        oid = iv[osi + k]
        if oid < nb:
            o = ob + _BOX_W * oid
            t, _ = _hit_box(
                px,
                py,
                pz,
                sx,
                sy,
                sz,
                fv[o],
                fv[o + 1],
                fv[o + 2],
                fv[o + 3],
                fv[o + 4],
                fv[o + 5],
                fv[o + 6],
                1e-4,
                _INF,
            )
        elif oid - nb != skip_tree:
            t, _, _, _ = _hit_tree(
                px, py, pz, sx, sy, sz, fv, iv, oid - nb, 1e-4, _INF, amp, freq, seed, True
            )
        else:
            continue
        if t < _INF:
            return True
    return False


@njit(**_OPTS)
def _trace(ox, oy, oz, dx, dy, dz, fv, iv, par):
    """Nearest hit of a primary ray from the camera: (t, kind, index, face, aux).

    Hills are looked up in the per-view azimuth bins (see _hill_bins).
    """
    t, kind, idx, face, aux = _INF, _K_NONE, -1, -1, 0.0
    ground_r = _INF
    if dz < 0.0 and oz > 0.0:
        tg = -oz / dz
        ground_r = math.hypot(ox + tg * dx, oy + tg * dy)
        if ground_r < par[_WORLD_R]:
            t, kind = tg, _K_GROUND
    to, ko, io, fo, ao = _trace_objects(ox, oy, oz, dx, dy, dz, 1e-4, t, fv, iv, par)
    if ko != _K_NONE:
        return to, ko, io, fo, ao
    if ground_r > par[_HILL_RMIN]:
        ohs, ohi, oh, nbin = iv[_O_HBS], iv[_O_HBI], iv[_O_HILL], iv[_N_HB]
        hb = int((math.atan2(dy, dx) + math.pi) * (nbin / (2.0 * math.pi))) % nbin
        for j in range(iv[ohs + hb], iv[ohs + hb + 1]):
            k = iv[ohi + j]
            e = oh + 6 * k
            th = _hit_ellipsoid(
                ox, oy, oz, dx, dy, dz, fv[e], fv[e + 1], fv[e + 2], fv[e + 3], fv[e + 4], fv[e + 5], 1e-4, t
            )
            if th < t:
                t, kind, idx = th, _K_HILL, k
    return t, kind, idx, face, aux


# -- materials -----------------------------------------------------------------------------------------
@njit(**_OPTS)
def _ground_albedo(x, y, par):  # par: params tuple
    """Albedo rgb and label of the z = 0 plane: roads, sidewalks, grass / soil, fields."""
    seed = int(par[_SEED])
    e, hw, ww = par[_EXTENT], par[_ROAD_HW], par[_WALK_W]
    lim = e + hw + ww
    if abs(x) <= lim and abs(y) <= lim:
        x0, sp, n = par[_ROAD_X0], par[_ROAD_SP], int(par[_ROAD_N])
        kx = min(max(round((x - x0) / sp), 0), n - 1)
        ky = min(max(round((y - x0) / sp), 0), n - 1)
        ddx, ddy = x - (x0 + kx * sp), y - (x0 + ky * sp)
        ax, ay = abs(ddx), abs(ddy)
        on_x = ax < hw and abs(y) <= e + hw  # road running north-south
        on_y = ay < hw and abs(x) <= e + hw  # road running east-west
        if on_x or on_y:
            g = 0.25 + 0.04 * (_vnoise2(x / 0.35, y / 0.35, seed + 3) - 0.5)
            g += 0.06 * (_fbm2(x / 6.0, y / 6.0, seed + 4, 2) - 0.5)
            paint = 0.0
            if not (on_x and on_y):
                across, along, dist_int = (ddx, y, ay) if on_x else (ddy, x, ax)
                aa = abs(across)
                # Crosswalk next to each intersection, centre dashes and edge lines elsewhere.
                cross = _band(dist_int - (hw + 2.3), 1.5, 0.05) * _band(across, hw - 0.6, 0.05)
                cross *= _stripes(across + 100.0, 1.0, 0.5, 0.05)
                lines = _band(across, 0.15, 0.05) * _stripes(along + 1000.0, 6.0, 0.5, 0.05)
                lines = max(lines, _band(aa - (hw - 0.5), 0.12, 0.05))
                paint = max(cross, lines * _smoothstep(hw + 3.9, hw + 4.0, dist_int))
            w = (0.80 + 0.08 * _vnoise2(x / 0.5, y / 0.5, seed + 5)) * paint
            g = g * (1.0 - paint)
            return g + w, g * 1.01 + w, g * 1.04 + w * 0.97, 2
        if (ax < hw + ww and abs(y) <= lim) or (ay < hw + ww and abs(x) <= lim):
            across, along = (ax, y) if ax < hw + ww else (ay, x)
            slab = math.floor(along / 1.5)
            v = 0.60 + 0.035 * _hash(int(slab), int(across > hw + ww * 0.5), 7, seed)
            v *= 1.0 - 0.12 * _stripes(along + 0.06, 1.5, 0.08, 0.03)
            kerb = _band(across - hw, 0.25, 0.04)
            v = v * (1.0 - kerb) + 0.70 * kerb
            return v, v * 0.98, v * 0.94, 2
    r = math.hypot(x, y)
    # Grass with dry-soil patches inside / near the town.
    m = _smoothstep(0.56, 0.70, _fbm2(x / 14.0, y / 14.0, seed + 6, 3))
    det = 0.82 + 0.24 * _vnoise2(x / 0.6, y / 0.6, seed + 7) + 0.08 * _vnoise2(x / 0.2, y / 0.2, seed + 8)
    gr = (0.29 * (1 - m) + 0.50 * m) * det
    gg = (0.42 * (1 - m) + 0.42 * m) * det
    gb = (0.16 * (1 - m) + 0.30 * m) * det
    wf = _smoothstep(e + 20.0, e + 70.0, r)
    if wf > 0.0:
        # Fields: rotated grid of parcels with a per-parcel crop colour and row stripes.
        u, v = 0.96 * x + 0.28 * y, -0.28 * x + 0.96 * y
        cu, cv = math.floor(u / 70.0), math.floor(v / 45.0)
        h = _hash(int(cu), int(cv), 11, seed)
        if h < 0.35:
            fr, fg, fb = 0.30, 0.44, 0.16
        elif h < 0.6:
            fr, fg, fb = 0.55, 0.50, 0.28
        elif h < 0.8:
            fr, fg, fb = 0.45, 0.36, 0.25
        else:
            fr, fg, fb = 0.22, 0.36, 0.14
        stripe = 0.92 + 0.08 * math.sin((u if h < 0.5 else v) * 2.0)
        fd = (0.85 + 0.3 * _vnoise2(x / 5.0, y / 5.0, seed + 9)) * stripe
        gr = gr * (1 - wf) + fr * fd * wf
        gg = gg * (1 - wf) + fg * fd * wf
        gb = gb * (1 - wf) + fb * fd * wf
    return gr, gg, gb, 1


@njit(**_OPTS)
def _wall_albedo(mat, face, s, z, width, height):
    """Facade albedo at wall coordinate s (m along the wall) and height z (m); soft 3 cm edges."""
    br, bg, bb = mat[1], mat[2], mat[3]
    ftype, seed = int(mat[0]), int(mat[11])
    if ftype == FACADE_UNIFORM:
        return br, bg, bb
    v = 0.93 + 0.10 * _vnoise2(s / 1.5, z / 1.5, seed) + 0.05 * _vnoise2(s / 0.3, z / 0.3, seed + 1)
    if ftype == FACADE_STONE:
        row = math.floor(z / 0.5)
        off = 0.5 * (int(row) & 1)
        v *= 0.9 + 0.12 * _hash(math.floor(s + off), int(row), face, seed)
        mortar = max(_stripes(z + 0.03, 0.5, 0.12, 0.02), _stripes(s + off + 0.03, 1.0, 0.06, 0.02))
        v *= 1.0 - 0.2 * mortar
    v *= 1.0 - 0.22 * _smoothstep(height - 0.55, height - 0.45, z)  # parapet band
    r, g, b = br * v, bg * v, bb * v
    fh, ws = mat[7], mat[8] * (1.4 if ftype == FACADE_STONE else 1.0)
    nc = math.floor((width - 1.0) / ws)
    j = math.floor(z / fh)
    if nc < 1 or j < 0 or (j + 1) * fh > height - 0.6:
        return r, g, b
    sc = (s - 0.5 * (width - nc * ws)) / ws
    i = math.floor(sc)
    if i < 0 or i >= nc:
        return r, g, b
    hwid, z0, z1 = 0.5 * mat[9] * ws, 0.3 * fh, (0.3 + mat[10]) * fh
    if j == 0 and _hash(int(i), face, 3, seed) < 0.5:
        hwid, z0, z1 = 0.42 * ws, 0.08 * fh, 0.82 * fh  # shop window
    ds = (sc - i - 0.5) * ws  # metres from the window axis
    dz = z - j * fh - 0.5 * (z0 + z1)
    hh = 0.5 * (z1 - z0)
    frame = _band(ds, hwid + 0.12, 0.03) * _band(dz, hh + 0.12, 0.03)
    if frame <= 0.0:
        return r, g, b
    glass = _band(ds, hwid, 0.03) * _band(dz, hh, 0.03)
    h = _hash(int(i), int(j), face, seed + 1)
    if h < 0.18:
        gr, gg, gb = 0.62, 0.56, 0.46  # curtains
    else:
        q = (0.7 + 0.8 * h) * (0.8 + 0.5 * (dz + hh) / (2 * hh))
        gr, gg, gb = 0.14 * q, 0.18 * q, 0.23 * q
    fc = 0.85 if seed & 1 else 0.28
    fr = frame - glass
    wr = 1.0 - frame
    return r * wr + fc * fr + gr * glass, g * wr + fc * fr + gg * glass, b * wr + 0.97 * fc * fr + gb * glass


@njit(**_OPTS)
def _roof_albedo(mat, lx, ly, hx, hy):
    """Flat roof albedo at box-local (lx, ly) (m): parapet rim, noise, a few roof-top units."""
    seed = int(mat[11])
    v = 0.85 + 0.2 * _vnoise2(lx / 3.0, ly / 3.0, seed + 2) + 0.06 * _vnoise2(lx / 0.3, ly / 0.3, seed + 3)
    r, g, b = mat[4] * v, mat[5] * v, mat[6] * v
    cx, cy = math.floor(lx / 4.0), math.floor(ly / 4.0)
    if _hash(int(cx), int(cy), 5, seed) < 0.12:
        unit = _band(lx - 4.0 * (cx + 0.5), 1.2, 0.04) * _band(ly - 4.0 * (cy + 0.5), 1.2, 0.04)
        r, g, b = r + (0.68 - r) * unit, g + (0.68 - g) * unit, b + (0.67 - b) * unit
    rim = 1.0 - _smoothstep(0.31, 0.39, min(hx - abs(lx), hy - abs(ly)))
    return r + (0.66 - r) * rim, g + (0.65 - g) * rim, b + (0.62 - b) * rim


@njit(**_OPTS)
def _hill_albedo(x, y, z, seed):
    m = _fbm2(x / 150.0, y / 150.0, seed + 20, 3)
    forest = _smoothstep(0.55, 0.65, _fbm2(x / 70.0, y / 70.0, seed + 21, 2))
    d = 0.85 + 0.3 * _vnoise2(x / 9.0, y / 9.0, seed + 22)
    r = (0.30 + 0.12 * m) * (1 - forest) + 0.13 * forest
    g = (0.38 + 0.06 * m) * (1 - forest) + 0.24 * forest
    b = (0.18 + 0.06 * m) * (1 - forest) + 0.11 * forest
    return r * d, g * d, b * d


@njit(**_OPTS)
def _sky(dx, dy, dz, par):
    """Sky radiance of a unit direction (function of the direction only)."""
    e = max(dz, 0.0)
    w = math.sqrt(e)
    r = par[_HOR] * (1 - w) + par[_ZEN] * w
    g = par[_HOR + 1] * (1 - w) + par[_ZEN + 1] * w
    b = par[_HOR + 2] * (1 - w) + par[_ZEN + 2] * w
    if dz > 0.005:
        k = 1.0 / (dz + 0.04)
        u, v = dx * k * 1.2, dy * k * 1.2
        seed = int(par[_SEED])
        n = _fbm2(u, v, seed + 30, 4)
        cov = par[_CLOUD]
        c = _smoothstep(1.0 - cov - 0.05, 1.0 - cov + 0.25, n) * _smoothstep(0.005, 0.12, dz)
        shade = 0.80 + 0.2 * _fbm2(u * 2.0 + 5.0, v * 2.0, seed + 31, 2)
        r = r * (1 - c) + 0.97 * shade * c
        g = g * (1 - c) + 0.97 * shade * c
        b = b * (1 - c) + 0.98 * shade * c
    cs = dx * par[_SUN] + dy * par[_SUN + 1] + dz * par[_SUN + 2]
    if cs > 0.0:
        glow = 0.35 * cs**48
        r, g, b = r + glow, g + glow * 0.95, b + glow * 0.8
    return r, g, b


# -- shading ---------------------------------------------------------------------------------------------
@njit(**_OPTS)
def _shade(ox, oy, oz, dx, dy, dz, t, kind, idx, face, aux, fv, iv, par, shadow_hint):
    """Colour (r, g, b), label and sun state of the hit (t, kind, idx, face, aux) of a unit ray.

    Sun state: 0 in shadow, 1 lit, 2 no shadow test (facing away, hill, sky). ``shadow_hint``
    0 / 1 imposes the state instead of tracing a shadow ray (-1: trace).
    """
    if kind == _K_NONE:
        r, g, b = _sky(dx, dy, dz, par)
        return r, g, b, LABEL_SKY, 2
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    seed = int(par[_SEED])
    nx, ny, nz = 0.0, 0.0, 1.0
    wrap = 0.0
    off = 0.02
    skip = -1
    if kind == _K_GROUND:
        ar, ag, ab, label = _ground_albedo(px, py, par)
        pz = 0.0
    elif kind == _K_BOX:
        o = iv[_O_BOX] + _BOX_W * idx
        m = iv[_O_MAT] + _MAT_W * idx
        mat = (
            fv[m], fv[m + 1], fv[m + 2], fv[m + 3], fv[m + 4], fv[m + 5],
            fv[m + 6], fv[m + 7], fv[m + 8], fv[m + 9], fv[m + 10], fv[m + 11],
        )  # fmt: skip
        c, s = fv[o + 5], fv[o + 6]
        rx, ry = px - fv[o], py - fv[o + 1]
        lx, ly = c * rx + s * ry, -s * rx + c * ry
        if face == 4:
            label = LABEL_ROOF
            ar, ag, ab = _roof_albedo(mat, lx, ly, fv[o + 2], fv[o + 3])
        else:
            label = LABEL_BUILDING_WALL
            sg = 1.0 if face % 2 == 0 else -1.0
            if face < 2:
                nx, ny, nz = sg * c, sg * s, 0.0
                ar, ag, ab = _wall_albedo(mat, face, ly + fv[o + 3], pz, 2 * fv[o + 3], fv[o + 4])
            else:
                nx, ny, nz = -sg * s, sg * c, 0.0
                ar, ag, ab = _wall_albedo(mat, face, lx + fv[o + 2], pz, 2 * fv[o + 2], fv[o + 4])
    elif kind == _K_FOLIAGE:
        label = LABEL_TREE
        o = iv[_O_SPH] + 4 * idx
        qx, qy, qz = px - fv[o], py - fv[o + 1], pz - fv[o + 2]
        qn = math.sqrt(qx * qx + qy * qy + qz * qz)
        nx, ny, nz = qx / qn, qy / qn, qz / qn
        skip = iv[iv[_O_STREE] + idx]
        tc = iv[_O_TRGB] + 3 * skip
        leaf = 0.72 + 0.5 * _vnoise3(px * 7.0, py * 7.0, pz * 7.0, seed + 40)
        hue = _vnoise3(px * 1.5, py * 1.5, pz * 1.5, seed + 41)
        cre = 0.45 + 0.75 * aux
        ar = fv[tc] * leaf * cre * (0.9 + 0.3 * hue)
        ag = fv[tc + 1] * leaf * cre
        ab = fv[tc + 2] * leaf * cre * (1.1 - 0.2 * hue)
        wrap = 0.35
    elif kind == _K_TRUNK:
        label = LABEL_TREE
        o = iv[_O_TRK] + 4 * idx
        qx, qy = px - fv[o], py - fv[o + 1]
        qn = math.hypot(qx, qy)
        nx, ny, nz = qx / qn, qy / qn, 0.0
        v = 0.8 + 0.35 * _vnoise3(px * 6.0, py * 6.0, pz * 1.5, seed + 42)
        ar, ag, ab = 0.30 * v, 0.23 * v, 0.17 * v
    else:  # hill
        label = LABEL_HILL
        o = iv[_O_HILL] + 6 * idx
        qx, qy, qz = (
            (px - fv[o]) / fv[o + 3] ** 2,
            (py - fv[o + 1]) / fv[o + 4] ** 2,
            (pz - fv[o + 2]) / fv[o + 5] ** 2,
        )
        qn = math.sqrt(qx * qx + qy * qy + qz * qz)
        nx, ny, nz = qx / qn, qy / qn, qz / qn
        ar, ag, ab = _hill_albedo(px, py, pz, seed)
    sx, sy, sz = par[_SUN], par[_SUN + 1], par[_SUN + 2]
    ndl = (nx * sx + ny * sy + nz * sz + wrap) / (1.0 + wrap)
    direct = 0.0
    sun = 2
    if ndl > 0.0:
        direct = ndl
        if kind != _K_HILL:
            sun = shadow_hint
            if sun < 0:
                sun = (
                    0 if _sun_occluded(px + off * nx, py + off * ny, pz + off * nz, fv, iv, par, skip) else 1
                )
            if sun == 0:
                direct = 0.0
    amb = 0.75 + 0.25 * nz
    r = ar * (par[_AMB] * amb + par[_SUN_RGB] * direct)
    g = ag * (par[_AMB + 1] * amb + par[_SUN_RGB + 1] * direct)
    b = ab * (par[_AMB + 2] * amb + par[_SUN_RGB + 2] * direct)
    rad = math.hypot(px, py)
    if rad > par[_HAZE_R0]:
        hz = par[_HAZE_MAX] * min((rad - par[_HAZE_R0]) / (par[_HAZE_R1] - par[_HAZE_R0]), 1.0)
        r = r * (1 - hz) + par[_HOR] * hz
        g = g * (1 - hz) + par[_HOR + 1] * hz
        b = b * (1 - hz) + par[_HOR + 2] * hz
    return r, g, b, label, sun


@njit(**_INLINE)
def _plane_t(ox, oy, oz, dx, dy, dz, kind, idx, face, fv, iv):
    """Distance to the plane of a ground / box-face hit (inf for other kinds or no crossing)."""
    t = _INF
    if kind == _K_GROUND:
        if dz < 0.0:
            t = -oz / dz
    elif kind == _K_BOX:
        o = iv[_O_BOX] + _BOX_W * idx
        if face == 4:
            if dz != 0.0:
                t = (fv[o + 4] - oz) / dz
        else:
            c, s = fv[o + 5], fv[o + 6]
            rx, ry = ox - fv[o], oy - fv[o + 1]
            sg = 1.0 if face % 2 == 0 else -1.0
            if face < 2:
                lo, ld, half = c * rx + s * ry, c * dx + s * dy, fv[o + 2]
            else:
                lo, ld, half = -s * rx + c * ry, -s * dx + c * dy, fv[o + 3]
            if ld != 0.0:
                t = (sg * half - lo) / ld
    return t if t > 0.0 else _INF


@njit(**_INLINE)
def _ray(u, v, cam):
    """Unit world direction of pixel (u, v) and its optical-axis component (z-depth = t * cz).

    ``cam``: row-major R_wc (9), camera centre (3), then 1/fx, -cx/fx, 1/fy, -cy/fy.
    """
    cx = cam[12] * u + cam[13]
    cy = cam[14] * v + cam[15]
    nrm = math.sqrt(cx * cx + cy * cy + 1.0)
    dx = (cam[0] * cx + cam[1] * cy + cam[2]) / nrm
    dy = (cam[3] * cx + cam[4] * cy + cam[5]) / nrm
    dz = (cam[6] * cx + cam[7] * cy + cam[8]) / nrm
    return dx, dy, dz, 1.0 / nrm


@njit(**_OPTS)
def _pixel(u, v, cam, fv, iv, par):
    """Radiance, z-depth, label, sun state and hit key of the ray through pixel (u, v).

    The key identifies the surface: kind + 8 (face + 1) + 64 (index + 1), with the tree id as
    index for foliage.
    """
    dx, dy, dz, cz = _ray(u, v, cam)
    t, kind, idx, face, aux = _trace(cam[9], cam[10], cam[11], dx, dy, dz, fv, iv, par)
    r, g, b, label, sun = _shade(
        cam[9], cam[10], cam[11], dx, dy, dz, t, kind, idx, face, aux, fv, iv, par, -1
    )
    kid = iv[iv[_O_STREE] + idx] if kind == _K_FOLIAGE else idx
    return r, g, b, t * cz, label, sun, kind + 8 * (face + 1) + 64 * (kid + 1)


@njit(**_OPTS)
def _corner(u, v, cam, fv, iv, par, shadow_hint, key):
    """Radiance of the ray through (u, v); ``key`` >= 0: the surface all 4 pixels around it hit.

    On a planar surface (ground, box face) seen by all 4 pixels the corner ray meets the same
    plane, so it is intersected directly instead of traced through the scene; on foliage of one
    tree only that tree is traced (a thin occluder in front of it may be missed: anti-aliasing
    only).
    """
    dx, dy, dz, _ = _ray(u, v, cam)
    ox, oy, oz = cam[9], cam[10], cam[11]
    kind, face, idx = key % 8, (key // 8) % 8 - 1, key // 64 - 1
    t, aux = _INF, 0.0
    if key >= 0 and kind == _K_FOLIAGE:
        amp, freq, seed = par[_FOL_AMP], par[_FOL_FREQ], int(par[_SEED])
        t, kind, idx, aux = _hit_tree(ox, oy, oz, dx, dy, dz, fv, iv, idx, 1e-4, _INF, amp, freq, seed, False)
    elif key >= 0:
        t = _plane_t(ox, oy, oz, dx, dy, dz, kind, idx, face, fv, iv)
    if t == _INF:
        t, kind, idx, face, aux = _trace(ox, oy, oz, dx, dy, dz, fv, iv, par)
    r, g, b, _, _ = _shade(ox, oy, oz, dx, dy, dz, t, kind, idx, face, aux, fv, iv, par, shadow_hint)
    return r, g, b


@njit(**_OPTS)
def _to_u8(x: float) -> np.uint8:
    return np.uint8(int(min(max(x, 0.0), 1.0) * 255.0 + 0.5))


@njit(cache=True, parallel=True, fastmath=False, error_model='numpy')
def _render_kernel(cam, rows, crows, aa, contrast, centre, sun, key, corner, rgb, depth, label, fv, iv, par):
    """Centre rays for every pixel, then (aa) quincunx corners, traced where the up to 4 pixels
    sharing a corner differ by more than ``contrast`` in a channel or in label, else averaged.
    A traced corner reuses the sun state of its pixels when they all agree on it, and their
    surface when they all hit the same plane (see _corner)."""
    h, w = depth.shape
    for k in prange(h):
        r = rows[k]
        for c in range(w):
            cr, cg, cb, z, lab, sn, ky = _pixel(float(c), float(r), cam, fv, iv, par)
            sun[r, c] = sn
            key[r, c] = ky
            centre[r, c, 0] = cr
            centre[r, c, 1] = cg
            centre[r, c, 2] = cb
            depth[r, c] = np.float32(z)
            label[r, c] = lab
    if aa:
        for k in prange(h + 1):
            r = crows[k]
            for c in range(w + 1):
                r0, r1, c0, c1 = max(r - 1, 0), min(r, h - 1), max(c - 1, 0), min(c, w - 1)
                trace = label[r0, c0] != label[r1, c1] or label[r0, c1] != label[r1, c0]
                trace = trace or label[r0, c0] != label[r0, c1]
                for ch in range(3):
                    a, b_, c_, d_ = (
                        centre[r0, c0, ch],
                        centre[r0, c1, ch],
                        centre[r1, c0, ch],
                        centre[r1, c1, ch],
                    )
                    corner[r, c, ch] = 0.25 * (a + b_ + c_ + d_)
                    if max(max(a, b_), max(c_, d_)) - min(min(a, b_), min(c_, d_)) > contrast:
                        trace = True
                if trace:
                    hint = sun[r0, c0]
                    if hint > 1 or hint != sun[r0, c1] or hint != sun[r1, c0] or hint != sun[r1, c1]:
                        hint = -1
                    ky = key[r0, c0]
                    if ky != key[r0, c1] or ky != key[r1, c0] or ky != key[r1, c1]:
                        ky = -1
                    cr, cg, cb = _corner(c - 0.5, r - 0.5, cam, fv, iv, par, hint, ky)
                    corner[r, c, 0] = cr
                    corner[r, c, 1] = cg
                    corner[r, c, 2] = cb
    for k in prange(h):
        r = rows[k]
        for c in range(w):
            for ch in range(3):
                v = centre[r, c, ch]
                if aa:
                    v = 0.5 * v + 0.125 * (
                        corner[r, c, ch]
                        + corner[r, c + 1, ch]
                        + corner[r + 1, c, ch]
                        + corner[r + 1, c + 1, ch]
                    )
                rgb[r, c, ch] = _to_u8(v)


@njit(cache=True, parallel=True, fastmath=False, error_model='numpy')
def _rays_kernel(org, dirs, rgb, dist, label, fv, iv, par):
    for k in prange(dirs.shape[0]):
        ox, oy, oz = org[k, 0], org[k, 1], org[k, 2]
        n = math.sqrt(dirs[k, 0] ** 2 + dirs[k, 1] ** 2 + dirs[k, 2] ** 2)
        dx, dy, dz = dirs[k, 0] / n, dirs[k, 1] / n, dirs[k, 2] / n
        t, kind, idx, face, aux = _trace(ox, oy, oz, dx, dy, dz, fv, iv, par)
        r, g, b, lab, _ = _shade(ox, oy, oz, dx, dy, dz, t, kind, idx, face, aux, fv, iv, par, -1)
        rgb[k, 0], rgb[k, 1], rgb[k, 2] = r, g, b
        dist[k] = t
        label[k] = lab


def shade_rays(
    scene: Scene, origins: NDArray[np.float64], directions: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
    """Trace single rays (no anti-aliasing): linear rgb (N x 3, 0..1 before clipping), distance
    along the normalised direction (m, inf for sky) and label of each (world frame, metres).

    For debugging and tests: the radiance of a surface point does not depend on the ray that
    reaches it. Hills are tested for every ray (origins may differ).
    """
    org = np.ascontiguousarray(np.broadcast_to(np.asarray(origins, np.float64), np.shape(directions)))
    dirs = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    org = org.reshape(-1, 3)
    f, i = _pack(scene, None)
    n = dirs.shape[0]
    rgb, dist, label = np.empty((n, 3)), np.empty(n), np.empty(n, np.uint8)
    _rays_kernel(org, dirs, rgb, dist, label, f, i, tuple(float(x) for x in scene.params))
    return rgb, dist, label


def _hill_bins(hills: NDArray[np.float64], cam_xy: NDArray[np.float64] | None, nbins: int = 128):
    """CSR lists of the hills a ray from ``cam_xy`` may hit, per bin of ray azimuth atan2(dy, dx).

    ``cam_xy`` None: a single bin listing every hill (rays from anywhere).
    """
    if cam_xy is None:
        return np.array([0, hills.shape[0]], np.int64), np.arange(hills.shape[0], dtype=np.int64)
    rel = hills[:, :2] - cam_xy
    dist = np.hypot(rel[:, 0], rel[:, 1])
    rmax = np.maximum(hills[:, 3], hills[:, 4])
    phi = np.arctan2(rel[:, 1], rel[:, 0])
    half = np.where(dist > rmax, np.arcsin(np.clip(rmax / np.maximum(dist, 1e-9), 0.0, 1.0)), np.pi)
    width = 2 * np.pi / nbins
    lists: list[list[int]] = [[] for _ in range(nbins)]
    cover: Iterable[int]
    for k in range(hills.shape[0]):
        if half[k] >= np.pi / 2:
            cover = range(nbins)
        else:
            b0 = math.floor((phi[k] - half[k] + np.pi) / width) - 1
            b1 = math.floor((phi[k] + half[k] + np.pi) / width) + 1
            cover = (b % nbins for b in range(b0, b1 + 1))
        for b in cover:
            lists[b].append(k)
    start = np.zeros(nbins + 1, np.int64)
    start[1:] = np.cumsum([len(x) for x in lists])
    items = np.array([k for x in lists for k in x], np.int64)
    return start, items


def _pack(scene: Scene, cam_xy: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Flat float / int arrays of the scene and the per-view hill bins (layout: _O_* / _N_*)."""
    hb_start, hb_items = _hill_bins(scene.hills, cam_xy)
    fblocks = [
        scene.boxes,
        scene.box_mat,
        scene.spheres,
        scene.trunks,
        scene.tree_rgb,
        scene.trees,
        scene.hills,
        scene.grid_f,
        scene.cell_zmax,
        scene.sun_f,
        scene.sun_dmax,
    ]
    iblocks = [
        scene.sphere_tree,
        scene.tree_start,
        scene.grid_n,
        scene.cell_start,
        scene.cell_items,
        scene.sun_n,
        scene.sun_start,
        scene.sun_items,
        hb_start,
        hb_items,
    ]
    head = np.zeros(_N_HEAD, np.int64)
    fsizes = [b.size for b in fblocks]
    head[: len(fblocks)] = np.concatenate([[0], np.cumsum(fsizes)[:-1]])
    isizes = [b.size for b in iblocks]
    head[_O_STREE : _O_STREE + len(iblocks)] = _N_HEAD + np.concatenate([[0], np.cumsum(isizes)[:-1]])
    head[_N_BOX] = scene.boxes.shape[0]
    head[_N_SPH] = scene.spheres.shape[0]
    head[_N_TREE] = scene.trees.shape[0]
    head[_N_HILL] = scene.hills.shape[0]
    head[_N_HB] = hb_start.size - 1
    f = np.concatenate([np.asarray(b, np.float64).ravel() for b in fblocks])
    i = np.concatenate([head, *(np.asarray(b, np.int64).ravel() for b in iblocks)])
    return f, i


def _row_order(n: int) -> NDArray[np.int64]:
    """Fixed shuffled row order so that prange's static chunks get balanced work."""
    return np.random.default_rng(12345).permutation(n).astype(np.int64)


def render_view(
    scene: Scene,
    camera: PinholeCamera,
    t_wc: NDArray[np.float64],
    *,
    antialias: bool = True,
    aa_contrast: float = 0.03,
) -> SynthFrame:
    """Render ``scene`` from pose ``t_wc`` (4x4 camera-to-world, optical frame) with ``camera``.

    Uses the pinhole part of ``camera`` (K); distorted cameras are rejected. ``antialias``
    enables quincunx sampling; a corner sample is traced only where the pixels around it differ
    by more than ``aa_contrast`` (linear colour 0..1, 0 traces all) or in label, elsewhere it is
    their mean. The output is bit-identical for equal inputs.
    """
    if camera.is_distorted:
        raise ValueError('render_view renders ideal pinhole images; the camera has distortion')
    pose = validate_pose(t_wc, field='t_wc')
    h, w = camera.height, camera.width
    kinv = (1.0 / camera.fx, -camera.cx / camera.fx, 1.0 / camera.fy, -camera.cy / camera.fy)
    cam = (*(float(x) for x in pose[:3, :3].ravel()), *(float(x) for x in pose[:3, 3]), *kinv)
    f, i = _pack(scene, pose[:2, 3])
    p = tuple(float(x) for x in scene.params)
    rgb = np.empty((h, w, 3), np.uint8)
    depth = np.empty((h, w), np.float32)
    label = np.empty((h, w), np.uint8)
    centre = np.empty((h, w, 3))
    sun = np.empty((h, w), np.int64)
    key = np.empty((h, w), np.int64)
    corner = np.empty((h + 1, w + 1, 3) if antialias else (1, 1, 3))
    rows, crows = _row_order(h), _row_order(h + 1)
    _render_kernel(
        cam, rows, crows, antialias, aa_contrast, centre, sun, key, corner, rgb, depth, label, f, i, p
    )
    return SynthFrame(rgb=rgb, depth=depth, sky=np.isinf(depth), label=label)
