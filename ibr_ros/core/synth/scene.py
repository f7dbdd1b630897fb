# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Procedural town for the synthetic drone data set: a seed in, plain numpy arrays out.

World frame: ENU metres (x east, y north, z up), flat ground at z = 0, town centred on the origin
inside ``[-extent_m, extent_m]^2``. Everything is a deterministic function of ``SceneConfig``
(``numpy.random.default_rng(seed)``); the renderer (:mod:`.render`) only reads the arrays.

Content: a square grid of roads (asphalt, lane markings, sidewalks) with blocks in between; blocks
hold box buildings on lots (a few rotated about z, facades windowed / stone / uniform low-texture,
flat textured roofs) or are parks; trees are clusters of noise-displaced spheres on a trunk
(parks, yards, street trees); a ring of large sunk ellipsoids forms hills far beyond the town.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    'BOX_COLS',
    'FACADE_STONE',
    'FACADE_UNIFORM',
    'FACADE_WINDOWS',
    'PARAM_INDEX',
    'Scene',
    'SceneConfig',
    'build_scene',
]

# Facade types (column 0 of Scene.box_mat).
FACADE_WINDOWS = 0
FACADE_STONE = 1
FACADE_UNIFORM = 2

# Columns of Scene.boxes: centre x/y, half sizes along the local x/y axes, height, cos/sin of the
# rotation about z (local -> world).
BOX_COLS = ('cx', 'cy', 'hx', 'hy', 'h', 'cos', 'sin')

# Columns of Scene.box_mat: facade type, wall rgb, roof rgb, floor height, window spacing,
# window width / spacing, window height / floor, per-building random seed.
MAT_COLS = ('type', 'wr', 'wg', 'wb', 'rr', 'rg', 'rb', 'floor_h', 'win_sp', 'win_w', 'win_h', 'seed')

# Layout of Scene.params (scalars the renderer needs), name -> index.
PARAM_NAMES = (
    'extent',  # town half-size (m)
    'road_x0',  # first road centre line (m), same for x and y
    'road_sp',  # road spacing (m)
    'road_n',  # number of road lines per axis
    'road_hw',  # half width of the asphalt (m)
    'walk_w',  # sidewalk width (m)
    'sun_x',
    'sun_y',
    'sun_z',  # unit vector towards the sun
    'sun_r',
    'sun_g',
    'sun_b',  # direct sun irradiance
    'amb_r',
    'amb_g',
    'amb_b',  # sky ambient
    'zen_r',
    'zen_g',
    'zen_b',  # sky colour at the zenith
    'hor_r',
    'hor_g',
    'hor_b',  # sky colour at the horizon (also the haze colour)
    'cloud_cover',  # 0..1
    'hill_rmin',  # no hill reaches closer than this to the origin (m)
    'world_r',  # ground plane radius (m); beyond it rays see the sky
    'haze_r0',
    'haze_r1',  # haze ramps from 0 at haze_r0 to haze_max at haze_r1 (distance to origin, m)
    'haze_max',
    'foliage_amp',  # relative radius modulation of foliage spheres
    'foliage_freq',  # spatial frequency of that modulation (1/m)
    'seed',
)
PARAM_INDEX = {n: i for i, n in enumerate(PARAM_NAMES)}


@dataclass(frozen=True)
class SceneConfig:
    """Parameters of the procedural town (lengths in metres, angles in degrees, colours 0..1).

    ``extent_m``: town half-size (roads run from -extent to +extent); ``block_m``: nominal road
    spacing (rounded so the grid fits the extent); ``n_buildings``: at most this many buildings
    (one per lot, lots are limited by the blocks); ``building_height_m`` / ``tree_height_m``:
    (min, max); ``low_texture_fraction``: share of buildings with uniform, textureless facades;
    ``rotated_fraction``: share of buildings rotated about z; ``park_fraction``: share of blocks
    that are parks; ``tree_density``: multiplier on tree counts (0: no trees); sun azimuth is
    counter-clockwise from east (ENU), elevation above the horizon; ``cloud_cover`` 0..1;
    ``hills``: ring of hills at ``hill_ring_m`` (inner, outer radius) plus farther mountains.
    """

    seed: int = 0
    extent_m: float = 150.0
    block_m: float = 60.0
    road_width_m: float = 10.0
    sidewalk_m: float = 2.5
    n_buildings: int = 60
    building_height_m: tuple[float, float] = (6.0, 30.0)
    low_texture_fraction: float = 0.25
    rotated_fraction: float = 0.15
    park_fraction: float = 0.12
    tree_density: float = 1.0
    tree_height_m: tuple[float, float] = (6.0, 13.0)
    sun_azimuth_deg: float = 220.0
    sun_elevation_deg: float = 42.0
    sky_zenith_rgb: tuple[float, float, float] = (0.28, 0.48, 0.82)
    sky_horizon_rgb: tuple[float, float, float] = (0.74, 0.82, 0.90)
    cloud_cover: float = 0.5
    hills: bool = True
    hill_ring_m: tuple[float, float] = (650.0, 1000.0)

    def __post_init__(self) -> None:
        sp = 2 * self.extent_m / max(1, round(2 * self.extent_m / max(self.block_m, 1e-9)))
        checks = (
            (self.extent_m > 0, 'extent_m must be > 0'),
            (self.road_width_m > 0 and self.sidewalk_m >= 0, 'road_width_m > 0 and sidewalk_m >= 0'),
            (sp > self.road_width_m + 2 * self.sidewalk_m + 6, 'block_m too small for roads and sidewalks'),
            (self.n_buildings >= 0, 'n_buildings must be >= 0'),
            (0 < self.building_height_m[0] <= self.building_height_m[1], 'building_height_m: 0 < min <= max'),
            (0 < self.tree_height_m[0] <= self.tree_height_m[1], 'tree_height_m: 0 < min <= max'),
            (self.tree_density >= 0, 'tree_density must be >= 0'),
            (0 < self.sun_elevation_deg < 90, 'sun_elevation_deg must be in (0, 90)'),
            (0 <= self.cloud_cover <= 1, 'cloud_cover must be in [0, 1]'),
            (
                not self.hills or self.extent_m * 2 < self.hill_ring_m[0] <= self.hill_ring_m[1],
                'hill_ring_m must satisfy 2 extent_m < inner <= outer',
            ),
        )
        for ok, msg in checks:
            if not ok:
                raise ValueError(f'SceneConfig: {msg}')
        for name in ('low_texture_fraction', 'rotated_fraction', 'park_fraction'):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f'SceneConfig: {name} must be in [0, 1]')

    @property
    def max_height_m(self) -> float:
        """Upper bound on the height of buildings and trees (m)."""
        return max(self.building_height_m[1], self.tree_height_m[1]) + 1.0


@dataclass(frozen=True, eq=False)
class Scene:
    """Arrays describing a town (see module docstring; column layouts in BOX_COLS / MAT_COLS).

    ``spheres``: (S, 4) foliage sphere centre x/y/z and base radius, grouped by tree: tree ``i``
    owns rows ``tree_start[i]:tree_start[i + 1]``; ``sphere_tree``: (S,) tree id of each sphere.
    ``trees``: (T, 4) bounding sphere (centre x/y/z, radius) of each crown with its displacement.
    ``trunks``: (T, 4) x, y, radius, top height; ``tree_rgb``: (T, 3) foliage albedo.
    ``hills``: (H, 6) ellipsoid centre x/y/z and semi-axes a/b/c (centres below ground).
    ``grid_f``: x0, y0, cell size, max object height; ``grid_n``: cells along x, y;
    ``cell_start`` / ``cell_items``: CSR lists of object ids per cell (id < B: box ``id``, else
    tree ``id - B`` with its crown and trunk), cell index ``iy * nx + ix``; ``cell_zmax``: top
    of the highest object listed in each cell (m), so rays passing above a cell skip it.
    ``sun_f``: a0, b0, cell size, then the unit axes e1, e2 of the sun-space plane (the plane
    orthogonal to the sun direction s); ``sun_n``: cells along a, b; ``sun_start`` /
    ``sun_items``: CSR lists (ids as above) of the objects whose projection along s covers each
    cell, ``sun_dmax``: per list entry, the object's largest ``p . s`` (an occluder of point q
    must have ``sun_dmax > q . s``).
    """

    config: SceneConfig
    boxes: NDArray[np.float64]
    box_mat: NDArray[np.float64]
    spheres: NDArray[np.float64]
    sphere_tree: NDArray[np.int64]
    tree_start: NDArray[np.int64]
    trees: NDArray[np.float64]
    trunks: NDArray[np.float64]
    tree_rgb: NDArray[np.float64]
    hills: NDArray[np.float64]
    params: NDArray[np.float64]
    grid_f: NDArray[np.float64]
    grid_n: NDArray[np.int64]
    cell_start: NDArray[np.int64]
    cell_items: NDArray[np.int64]
    cell_zmax: NDArray[np.float64]
    sun_f: NDArray[np.float64]
    sun_n: NDArray[np.int64]
    sun_start: NDArray[np.int64]
    sun_items: NDArray[np.int64]
    sun_dmax: NDArray[np.float64]

    @property
    def n_buildings(self) -> int:
        return int(self.boxes.shape[0])

    @property
    def n_trees(self) -> int:
        return int(self.trunks.shape[0])


_WALL_PALETTE = np.array(
    [
        [0.80, 0.74, 0.62],  # beige
        [0.72, 0.70, 0.66],  # warm grey
        [0.66, 0.48, 0.38],  # terracotta
        [0.80, 0.72, 0.50],  # ochre
        [0.58, 0.60, 0.64],  # blue grey
        [0.62, 0.44, 0.34],  # brick red
        [0.84, 0.82, 0.78],  # off-white
    ]
)
_UNIFORM_PALETTE = np.array([[0.86, 0.85, 0.82], [0.78, 0.78, 0.76], [0.83, 0.78, 0.68], [0.70, 0.72, 0.74]])
_ROOF_PALETTE = np.array([[0.36, 0.36, 0.37], [0.48, 0.47, 0.45], [0.50, 0.32, 0.26], [0.30, 0.31, 0.33]])
_FOLIAGE_PALETTE = np.array([[0.20, 0.36, 0.12], [0.26, 0.40, 0.14], [0.18, 0.30, 0.14], [0.32, 0.38, 0.16]])

# Foliage shape (relative radius modulation, spatial frequency 1/m). Changing these (or any
# geometry) changes the ground truth of recorded bags, e.g. bags/synth_orbit_s0.
_FOLIAGE_AMP = 0.25
_FOLIAGE_FREQ = 0.9


def _box_footprint_dist(boxes: NDArray[np.float64], x: float, y: float) -> float:
    """Smallest distance (m) from (x, y) to any box footprint (0 inside)."""
    if boxes.shape[0] == 0:
        return math.inf
    dx, dy = x - boxes[:, 0], y - boxes[:, 1]
    lx = boxes[:, 5] * dx + boxes[:, 6] * dy
    ly = -boxes[:, 6] * dx + boxes[:, 5] * dy
    qx = np.maximum(np.abs(lx) - boxes[:, 2], 0.0)
    qy = np.maximum(np.abs(ly) - boxes[:, 3], 0.0)
    return float(np.min(np.hypot(qx, qy)))


def _make_building(rng: np.random.Generator, cfg: SceneConfig, lot: tuple[float, float, float, float]):
    """One box (row of Scene.boxes) and its material inside lot (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = lot
    lw, lh = x1 - x0, y1 - y0
    w = lw * rng.uniform(0.55, 0.95)
    d = lh * rng.uniform(0.55, 0.95)
    ang = 0.0
    if rng.random() < cfg.rotated_fraction:
        ang = math.radians(rng.uniform(12.0, 40.0)) * (1 if rng.random() < 0.5 else -1)
        c, s = abs(math.cos(ang)), abs(math.sin(ang))
        scale = min(lw / (w * c + d * s), lh / (w * s + d * c), 1.0) * 0.95
        w, d = w * scale, d * scale
        ex, ey = (w * c + d * s) / 2, (w * s + d * c) / 2
    else:
        ex, ey = w / 2, d / 2
    cx = rng.uniform(x0 + ex, x1 - ex) if x1 - x0 > 2 * ex else (x0 + x1) / 2
    cy = rng.uniform(y0 + ey, y1 - ey) if y1 - y0 > 2 * ey else (y0 + y1) / 2
    hlo, hhi = cfg.building_height_m
    h = hlo + (hhi - hlo) * rng.random() ** 1.6
    box = [cx, cy, w / 2, d / 2, h, math.cos(ang), math.sin(ang)]

    uniform = rng.random() < cfg.low_texture_fraction
    if uniform:
        ftype = FACADE_UNIFORM
        wall = _UNIFORM_PALETTE[rng.integers(len(_UNIFORM_PALETTE))]
    else:
        ftype = FACADE_STONE if rng.random() < 0.35 else FACADE_WINDOWS
        wall = _WALL_PALETTE[rng.integers(len(_WALL_PALETTE))] * rng.uniform(0.9, 1.08)
    roof = _ROOF_PALETTE[rng.integers(len(_ROOF_PALETTE))] * rng.uniform(0.85, 1.15)
    floor_h = rng.uniform(2.9, 3.6)
    mat = [
        ftype,
        *np.clip(wall, 0, 1),
        *np.clip(roof, 0, 1),
        floor_h,
        rng.uniform(2.2, 3.6),
        rng.uniform(0.35, 0.65),
        rng.uniform(0.40, 0.62),
        float(rng.integers(1, 1 << 20)),
    ]
    return box, mat


def _make_tree(rng: np.random.Generator, cfg: SceneConfig, x: float, y: float, tree_id: int):
    """Trunk row, foliage sphere rows and albedo of one tree at (x, y)."""
    hlo, hhi = cfg.tree_height_m
    height = rng.uniform(hlo, hhi)
    rc = rng.uniform(0.22, 0.34) * height
    cz = height - rc * (1 + _FOLIAGE_AMP)
    trunk = [x, y, rng.uniform(0.14, 0.28), cz]
    spheres = []
    for _ in range(int(rng.integers(4, 8))):
        r = rc * rng.uniform(0.5, 0.75)
        ox, oy = rng.normal(0.0, 0.35 * rc, size=2)
        oz = rng.uniform(-0.35, 0.3) * rc
        sz = max(cz + oz, r * (1 + _FOLIAGE_AMP) + 1.2)
        sz = min(sz, height - r * (1 + _FOLIAGE_AMP))
        spheres.append([x + ox, y + oy, sz, r, tree_id])
    rgb = _FOLIAGE_PALETTE[rng.integers(len(_FOLIAGE_PALETTE))] * rng.uniform(0.8, 1.2, size=3)
    return trunk, spheres, np.clip(rgb, 0, 1)


def _build_grid(
    boxes: NDArray[np.float64],
    trees: NDArray[np.float64],
    trunks: NDArray[np.float64],
    lo: float,
    hi: float,
    cell: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """CSR cell lists and per-cell top heights over the square [lo, hi]^2 (see Scene)."""
    n = math.ceil((hi - lo) / cell)
    rects = []  # (id, xmin, ymin, xmax, ymax, top)
    for i, b in enumerate(boxes):
        ex = b[2] * abs(b[5]) + b[3] * abs(b[6])
        ey = b[2] * abs(b[6]) + b[3] * abs(b[5])
        rects.append((i, b[0] - ex, b[1] - ey, b[0] + ex, b[1] + ey, b[4]))
    nb = len(boxes)
    for i, (t, k) in enumerate(zip(trees, trunks)):
        r = max(t[3], k[2])
        x0, y0 = min(t[0], k[0]) - r, min(t[1], k[1]) - r
        rects.append((nb + i, x0, y0, max(t[0], k[0]) + r, max(t[1], k[1]) + r, t[2] + t[3]))
    lists: list[list[int]] = [[] for _ in range(n * n)]
    zmax = np.full(n * n, -1.0)
    for oid, x0, y0, x1, y1, top in rects:
        i0, i1 = max(int((x0 - lo) // cell), 0), min(int((x1 - lo) // cell), n - 1)
        j0, j1 = max(int((y0 - lo) // cell), 0), min(int((y1 - lo) // cell), n - 1)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                lists[j * n + i].append(oid)
                zmax[j * n + i] = max(zmax[j * n + i], top + 0.01)
    start = np.zeros(n * n + 1, dtype=np.int64)
    start[1:] = np.cumsum([len(c) for c in lists])
    items = np.array([o for c in lists for o in c], dtype=np.int64)
    return np.array([n, n], dtype=np.int64), start, items, zmax


def _build_sun_grid(
    boxes: NDArray[np.float64],
    trees: NDArray[np.float64],
    trunks: NDArray[np.float64],
    sun: NDArray[np.float64],
    cell: float,
):
    """Grid over the plane orthogonal to ``sun`` listing the objects projecting on each cell."""
    s = np.asarray(sun, dtype=np.float64)
    ref = np.array([0.0, 0.0, 1.0]) if abs(s[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, s)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(s, e1)
    proj = np.stack([e1, e2, s], axis=1)  # world point -> (a, b, d)
    objs = []  # (id, amin, bmin, amax, bmax, dmax)
    for i, b in enumerate(boxes):
        corners = []
        for sx in (-1, 1):
            for sy in (-1, 1):
                lx, ly = sx * b[2], sy * b[3]
                x, y = b[0] + b[5] * lx - b[6] * ly, b[1] + b[6] * lx + b[5] * ly
                corners += [[x, y, 0.0], [x, y, b[4]]]
        q = np.array(corners) @ proj
        objs.append((i, *q[:, :2].min(axis=0), *q[:, :2].max(axis=0), q[:, 2].max()))
    nb = len(boxes)
    for i, (t, k) in enumerate(zip(trees, trunks)):
        q = np.array([t[:3], [k[0], k[1], 0.0], [k[0], k[1], k[3]]]) @ proj
        r = np.array([t[3], k[2], k[2]])
        lo, hi = (q[:, :2] - r[:, None]).min(axis=0), (q[:, :2] + r[:, None]).max(axis=0)
        objs.append((nb + i, lo[0], lo[1], hi[0], hi[1], float((q[:, 2] + r).max())))
    if not objs:
        objs.append((-1, 0.0, 0.0, 0.0, 0.0, -math.inf))
    arr = np.array([o[1:] for o in objs])
    a0, b0 = arr[:, 0].min() - 1.0, arr[:, 1].min() - 1.0
    na = math.ceil((arr[:, 2].max() + 1.0 - a0) / cell)
    nbb = math.ceil((arr[:, 3].max() + 1.0 - b0) / cell)
    lists: list[list[tuple[int, float]]] = [[] for _ in range(na * nbb)]
    for oid, amin, bmin, amax, bmax, dmax in objs:
        if oid < 0:
            continue
        for j in range(int((bmin - b0) // cell), int((bmax - b0) // cell) + 1):
            for i in range(int((amin - a0) // cell), int((amax - a0) // cell) + 1):
                lists[j * na + i].append((oid, dmax))
    start = np.zeros(na * nbb + 1, dtype=np.int64)
    start[1:] = np.cumsum([len(c) for c in lists])
    items = np.array([o for c in lists for o, _ in c], dtype=np.int64)
    dmaxs = np.array([d for c in lists for _, d in c], dtype=np.float64)
    sun_f = np.array([a0, b0, cell, *e1, *e2])
    return sun_f, np.array([na, nbb], dtype=np.int64), start, items, dmaxs


def build_scene(cfg: SceneConfig) -> Scene:
    """Build the town described by ``cfg`` (deterministic in ``cfg.seed``)."""
    rng = np.random.default_rng(cfg.seed)
    e = float(cfg.extent_m)
    n_blocks = max(1, round(2 * e / cfg.block_m))
    sp = 2 * e / n_blocks
    roads = -e + sp * np.arange(n_blocks + 1)
    hw, sw = cfg.road_width_m / 2, cfg.sidewalk_m

    # Lots: blocks split into 1..3 x 1..3 parcels; park blocks hold only trees.
    lots: list[tuple[float, float, float, float]] = []
    parks: list[tuple[float, float, float, float]] = []
    for bj in range(n_blocks):
        for bi in range(n_blocks):
            x0, x1 = roads[bi] + hw + sw + 1.0, roads[bi + 1] - hw - sw - 1.0
            y0, y1 = roads[bj] + hw + sw + 1.0, roads[bj + 1] - hw - sw - 1.0
            if rng.random() < cfg.park_fraction:
                parks.append((x0, y0, x1, y1))
                continue
            nx, ny = int(rng.integers(1, 4)), int(rng.integers(1, 4))
            xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
            for j in range(ny):
                for i in range(nx):
                    lots.append((xs[i] + 0.8, ys[j] + 0.8, xs[i + 1] - 0.8, ys[j + 1] - 0.8))
    order = rng.permutation(len(lots))
    built = order[: cfg.n_buildings]
    yards = [lots[k] for k in order[cfg.n_buildings :]]
    boxes, mats = [], []
    for k in sorted(built):
        b, m = _make_building(rng, cfg, lots[k])
        boxes.append(b)
        mats.append(m)
    boxes_a = np.array(boxes, dtype=np.float64).reshape(-1, 7)
    mats_a = np.array(mats, dtype=np.float64).reshape(-1, len(MAT_COLS))

    # Tree sites: parks (dense), empty lots (sparser), street trees along some sidewalks.
    sites: list[tuple[float, float]] = []
    dens = max(cfg.tree_density, 0.0)
    for area_list, per_m2 in ((parks, 1 / 90), (yards, 1 / 160)):
        for x0, y0, x1, y1 in area_list:
            n = rng.poisson(dens * per_m2 * (x1 - x0) * (y1 - y0))
            for _ in range(n):
                sites.append((rng.uniform(x0 + 2, x1 - 2), rng.uniform(y0 + 2, y1 - 2)))
    for axis in (0, 1):
        for r in roads:
            if rng.random() > 0.5 * min(dens, 2.0):
                continue
            side = hw + sw * 0.55
            for sgn in (-1.0, 1.0):
                s = -e + rng.uniform(3, 10)
                while s < e:
                    if np.min(np.abs(roads - s)) > hw + sw + 3:
                        site = (r + sgn * side, s) if axis == 0 else (s, r + sgn * side)
                        sites.append(site)
                    s += rng.uniform(9.0, 14.0) / max(dens, 0.3)
    trunks: list[list[float]] = []
    sph: list[list[float]] = []
    rgbs: list[NDArray[np.float64]] = []
    for x, y in sites:
        if _box_footprint_dist(boxes_a, x, y) < 4.5:
            continue
        if trunks and np.min(np.hypot(np.array(trunks)[:, 0] - x, np.array(trunks)[:, 1] - y)) < 3.0:
            continue
        tr, ss, rgb = _make_tree(rng, cfg, x, y, len(trunks))
        trunks.append(tr)
        sph.extend(ss)
        rgbs.append(rgb)
    trunks_a = np.array(trunks, dtype=np.float64).reshape(-1, 4)
    sph_a = np.array(sph, dtype=np.float64).reshape(-1, 5)
    tree_rgb = np.array(rgbs, dtype=np.float64).reshape(-1, 3)
    sphere_tree = sph_a[:, 4].astype(np.int64)
    tree_start = np.searchsorted(sphere_tree, np.arange(len(trunks) + 1)).astype(np.int64)
    trees = np.zeros((len(trunks), 4))
    for i in range(len(trunks)):
        ss = sph_a[tree_start[i] : tree_start[i + 1], :4]
        c = ss[:, :3].mean(axis=0)
        trees[i, :3] = c
        trees[i, 3] = np.max(np.linalg.norm(ss[:, :3] - c, axis=1) + ss[:, 3] * (1 + _FOLIAGE_AMP)) + 1e-6

    # Hills: a ring of sunk ellipsoids plus a farther ring of mountains.
    hills = []
    if cfg.hills:
        r0, r1 = cfg.hill_ring_m
        for ring, (n, rad, ax, hz) in enumerate(
            (
                (26, (r0, r1), (160.0, 300.0), (35.0, 110.0)),
                (18, (2.2 * r1, 3.0 * r1), (500.0, 900.0), (180.0, 380.0)),
            )
        ):
            for k in range(n):
                phi = 2 * math.pi * (k + rng.uniform(-0.3, 0.3)) / n
                rr = rng.uniform(*rad)
                a = rng.uniform(*ax)
                b = a * rng.uniform(0.6, 1.0)
                peak = rng.uniform(*hz)
                c = peak / 0.6
                rr = max(rr, (r0 if ring == 0 else 2.2 * r1) + a)
                hills.append([rr * math.cos(phi), rr * math.sin(phi), peak - c, a, b, c, phi])
    hills_a = np.array(hills, dtype=np.float64).reshape(-1, 7)
    hill_rmin = float(np.min(np.hypot(hills_a[:, 0], hills_a[:, 1]) - hills_a[:, 3])) if len(hills) else 1e9

    az, el = math.radians(cfg.sun_azimuth_deg), math.radians(cfg.sun_elevation_deg)
    sun = [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    hr1 = 3.2 * cfg.hill_ring_m[1]
    p = dict.fromkeys(PARAM_NAMES, 0.0)
    p.update(
        extent=e,
        road_x0=float(roads[0]),
        road_sp=sp,
        road_n=float(n_blocks + 1),
        road_hw=hw,
        walk_w=sw,
        sun_x=sun[0],
        sun_y=sun[1],
        sun_z=sun[2],
        sun_r=1.0,
        sun_g=0.94,
        sun_b=0.84,
        amb_r=0.34,
        amb_g=0.38,
        amb_b=0.46,
        cloud_cover=cfg.cloud_cover,
        hill_rmin=hill_rmin,
        world_r=hr1 * 1.5,
        haze_r0=1.2 * e + 100.0,
        haze_r1=hr1,
        haze_max=0.85,
        foliage_amp=_FOLIAGE_AMP,
        foliage_freq=_FOLIAGE_FREQ,
        seed=float(cfg.seed % 100003),
    )
    for k, ch in enumerate('rgb'):
        p[f'zen_{ch}'] = cfg.sky_zenith_rgb[k]
        p[f'hor_{ch}'] = cfg.sky_horizon_rgb[k]
    params = np.array([p[n] for n in PARAM_NAMES], dtype=np.float64)

    lo, hi = -e - 25.0, e + 25.0
    cell = 12.0
    grid_n, start, items, cell_zmax = _build_grid(boxes_a, trees, trunks_a, lo, hi, cell)
    sun_f, sun_n, sun_start, sun_items, sun_dmax = _build_sun_grid(
        boxes_a, trees, trunks_a, np.array(sun), 4.0
    )
    zmax = max(
        float(boxes_a[:, 4].max()) if len(boxes_a) else 0.0,
        float((sph_a[:, 2] + sph_a[:, 3] * (1 + _FOLIAGE_AMP)).max()) if len(sph_a) else 0.0,
    )
    return Scene(
        config=cfg,
        boxes=boxes_a,
        box_mat=mats_a,
        spheres=np.ascontiguousarray(sph_a[:, :4]),
        sphere_tree=sphere_tree,
        tree_start=tree_start,
        trees=trees,
        trunks=trunks_a,
        tree_rgb=tree_rgb,
        hills=np.ascontiguousarray(hills_a[:, :6]),
        params=params,
        grid_f=np.array([lo, lo, cell, zmax + 0.01]),
        grid_n=grid_n,
        cell_start=start,
        cell_items=items,
        cell_zmax=cell_zmax,
        sun_f=sun_f,
        sun_n=sun_n,
        sun_start=sun_start,
        sun_items=sun_items,
        sun_dmax=sun_dmax,
    )
