# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-view MVS depth: accuracy on synthetic ground truth, geometry, neighbours, filter, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth import mvs
from ibr_ros.core.depth.mvs import MvsBackendUnavailable, MvsOptions, MvsView
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.synth import (
    LABEL_BUILDING_WALL,
    SceneConfig,
    build_scene,
    flight_camera,
    make_trajectory,
    render_view,
    safe_altitude_range,
)

# (seed, trajectory kind): oblique flights at 15-80 m over the procedural town.
SCENES = [(1, 'orbit'), (2, 'lawnmower'), (3, 'forward'), (4, 'orbit')]
SIZE = (480, 270)
N_VIEWS = 5
SPACING_S = 2.0  # 16 m between views at 8 m/s


def sparse_points(frames, cam: PinholeCamera, poses, rng, n: int = 300) -> np.ndarray:
    """World points of ``n`` random non-sky pixels per view (stand-in for SfM points)."""
    pts = []
    for f, t in zip(frames, poses):
        yx = np.argwhere(np.isfinite(f.depth))
        yx = yx[rng.choice(len(yx), n, replace=False)]
        pc = cam.backproject(yx[:, ::-1].astype(float), f.depth[yx[:, 0], yx[:, 1]])
        pts.append(pc @ t[:3, :3].T + t[:3, 3])
    return np.concatenate(pts)


@pytest.fixture(scope='module')
def flights():
    """Per scene: frames (GT), cameras, poses, sparse points and compute_depth_maps results."""
    out = {}
    for seed, kind in SCENES:
        cfg = SceneConfig(seed=seed)
        scene = build_scene(cfg)
        traj = make_trajectory(
            kind, duration_s=N_VIEWS * SPACING_S, fps=1 / SPACING_S, seed=seed,
            altitude_range=safe_altitude_range(cfg), extent_m=cfg.extent_m,
        )  # fmt: skip
        cam = flight_camera(SIZE, 70.0)
        frames = [render_view(scene, cam, s.t_wc) for s in traj]
        poses = np.stack([s.t_wc for s in traj])
        pts = sparse_points(frames, cam, poses, np.random.default_rng(seed))
        calls = []
        results = mvs.compute_depth_maps(
            [MvsView(f.rgb, cam, p) for f, p in zip(frames, poses)],
            points_w=pts,
            progress=lambda done, total, calls=calls: calls.append((done, total)),
        )
        assert calls == [(i + 1, N_VIEWS) for i in range(N_VIEWS)]
        out[(seed, kind)] = (frames, cam, poses, pts, results)
    return out


def scores(frames, depths) -> tuple[float, float, int]:
    """(fraction of output pixels within 5% of GT, fraction of non-sky pixels with output, sky outputs)."""
    good = n_out = n_ground = sky_out = 0
    for f, d in zip(frames, depths):
        out = d > 0
        ok = out & ~f.sky
        err = np.abs(d[ok] - f.depth[ok]) / f.depth[ok]
        good += int((err < 0.05).sum())
        n_out += int(out.sum())
        n_ground += int((~f.sky).sum())
        sky_out += int((out & f.sky).sum())
    return good / max(n_out, 1), n_out / n_ground, sky_out


# --------------------------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize(('seed', 'kind'), SCENES)
def test_accuracy_on_synthetic_ground_truth(flights, seed, kind):
    frames, _, _, _, results = flights[(seed, kind)]
    acc, comp, sky = scores(frames, [r.depth for r in results])
    acc_p, comp_p, _ = scores(frames, [r.photometric_depth for r in results])
    print(f'{kind}{seed}: geometric {acc:.3f} within 5%, completeness {comp:.3f}; '
          f'photometric {acc_p:.3f}, {comp_p:.3f}')  # fmt: skip
    assert acc >= 0.90  # the target: >= 90% of the output within 5% of the true depth
    assert comp >= 0.2  # semi-dense: low-texture walls, edges, occlusions and far hills are holes
    assert acc_p >= 0.85  # before the geometric filter
    assert acc >= acc_p
    assert comp < comp_p  # the filter removes depth, mostly wrong depth
    assert sky == 0
    for r in results:
        assert r.reason == ''
        assert len(r.neighbours) >= 2
        assert r.depth.dtype == np.float32
        assert r.confidence.dtype == np.float32
        assert r.n_consistent.dtype == np.uint8
        assert np.all(r.n_consistent[r.depth > 0] >= 2)
        assert np.all(r.confidence[r.depth > 0] >= MvsOptions().min_zncc)
        assert np.all(r.confidence[r.depth == 0] == 0)
        assert np.all(np.isfinite(r.depth))
        assert r.depth.min() >= 0


def test_mean_completeness(flights):
    comps = [scores(v[0], [r.depth for r in v[4]])[1] for v in flights.values()]
    assert np.mean(comps) >= 0.3


def test_low_texture_walls_are_holes(flights):
    """Uniform facades have no depth (the paper's MVS holes) rather than wrong depth."""
    walls = out = 0
    for frames, _, _, _, results in flights.values():
        for f, r in zip(frames, results):
            flat = (f.label == LABEL_BUILDING_WALL) & (mvs._box_stats(f.rgb.mean(-1), 3)[1] < 1.0)
            walls += int(flat.sum())
            out += int((flat & (r.depth > 0)).sum())
    assert walls > 0
    assert out <= 0.02 * walls


# --------------------------------------------------------------------------------------------- geometry


def plane_views(size=(160, 120), depth=50.0, flat_half=False):
    """A fronto-parallel plane at ``depth`` m with a sum-of-sines texture (exact, point-sampled), seen
    by a reference at the origin and 4 cameras shifted by 3 m; with ``flat_half`` its x < 0 half is
    uniform grey."""
    cam = PinholeCamera.from_fov(size[0], size[1], 60.0)
    rng = np.random.default_rng(0)
    waves = rng.uniform(-2.5, 2.5, (8, 2)), rng.uniform(0, 2 * np.pi, 8)
    rays = cam.pixel_rays()

    def render(t_wc: np.ndarray) -> np.ndarray:
        xy = t_wc[:2, 3] + depth * rays[..., :2]
        grey = 128 + 12 * np.sin(xy @ waves[0].T + waves[1]).sum(-1)
        if flat_half:
            grey[xy[..., 0] < 0] = 120.0
        return np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[..., None], 3, -1)

    t_wr = np.eye(4)
    poses = []
    for dx, dy in ((3, 0), (-3, 0), (0, 3), (0, -3)):
        t_ws = np.eye(4)
        t_ws[:3, 3] = [dx, dy, 0.0]
        poses.append(t_ws)
    return cam, render(t_wr), t_wr, [render(p) for p in poses], np.stack(poses)


def test_plane_depth_is_exact():
    cam, ref, t_wr, srcs, poses = plane_views()
    r = mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(10.0, 500.0))
    inner = r.depth[10:-10, 10:-10]
    assert (inner > 0).mean() > 0.9
    err = np.abs(inner[inner > 0] / 50.0 - 1)
    assert np.median(err) < 0.002
    assert err.max() < 0.05
    assert r.neighbours == (0, 1, 2, 3)
    assert r.n_planes >= MvsOptions().min_planes
    assert r.depth_range == (10.0, 500.0)


def test_flat_texture_is_rejected():
    cam, ref, t_wr, srcs, poses = plane_views(flat_half=True)
    r = mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(10.0, 500.0))
    assert not r.depth[:, :70].any()
    assert (r.depth[10:-10, 90:-10] > 0).mean() > 0.9


def test_full_resolution_sweep_option():
    cam, ref, t_wr, srcs, poses = plane_views()
    o = MvsOptions(sweep_scale=1.0, n_planes=64, surface_passes=0, edge_trim_px=0)
    r = mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(10.0, 500.0), options=o)
    inner = r.depth[10:-10, 10:-10]
    assert r.n_planes == 64
    assert (inner > 0).mean() > 0.9
    assert np.median(np.abs(inner[inner > 0] / 50.0 - 1)) < 0.005


@pytest.mark.parametrize(
    'kw',
    [
        {},
        {  # bench_mvs FAST
            'coarse_band': 2,
            'propagate_at_sweep_scale': True,
            'refine_steps': 2,
            'surface_passes': 2,
            'surface_steps': 1,
        },
        {'coarse_band': 1, 'surface_steps': 2},
    ],
)
def test_sweep_variants_are_exact_on_a_plane(kw):
    """The previous pipeline (every plane at sweep_scale, propagation at full resolution) and the
    coarse-to-fine one both find the plane."""
    cam, ref, t_wr, srcs, poses = plane_views((320, 240))
    r = mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(10.0, 500.0), options=MvsOptions(**kw))
    inner = r.depth[10:-10, 10:-10]
    assert (inner > 0).mean() > 0.9
    assert np.median(np.abs(inner[inner > 0] / 50.0 - 1)) < 0.002


def test_warp_rows_matches_a_float64_reference():
    """The float32 warp against numpy: homography per pixel (float64), bilinear, border clamped."""
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    a = np.array([[1.02, 0.03, -2.0], [-0.02, 0.98, 1.5], [1e-4, -2e-4, 1.0]])
    b = np.array([30.0, -10.0, 0.05])
    base = rng.uniform(-0.05, 0.2, (30, 60)).astype(np.float32)  # some rho <= 0: invalid
    ya, yb, y0, y1 = 3, 27, 5, 25
    out = np.empty((yb - ya, 60), np.float32)
    valid = np.empty((y1 - y0, 60), np.bool_)
    mvs._warp_rows(src, 40, 50, a, b, base, np.float32(0.01), ya, yb, out, valid, y0, y1)
    ys, xs = np.mgrid[ya:yb, 0:60].astype(np.float64)
    rho = base[ya:yb].astype(np.float64) + np.float64(np.float32(0.01))
    h = [a[i, 0] * xs + a[i, 1] * ys + a[i, 2] + rho * b[i] for i in range(3)]
    front = (h[2] > 1e-9) & (rho > 0)
    sx, sy = h[0] / h[2], h[1] / h[2]
    ok = front & (sx >= -0.5) & (sx <= 49.5) & (sy >= -0.5) & (sy <= 39.5)
    edge = (
        (np.abs(sx - 49.5) < 1e-3)
        | (np.abs(sy - 39.5) < 1e-3)
        | (np.abs(sx + 0.5) < 1e-3)
        | (np.abs(sy + 0.5) < 1e-3)
    )
    sx = np.where(front, np.clip(sx, 0, 50 - 1.001), 0)
    sy = np.where(front, np.clip(sy, 0, 40 - 1.001), 0)
    x0, yi = sx.astype(int), sy.astype(int)
    fx, fy = sx - x0, sy - yi
    top = src[yi, x0] + fx * (src[yi, x0 + 1] - src[yi, x0])
    bot = src[yi + 1, x0] + fx * (src[yi + 1, x0 + 1] - src[yi + 1, x0])
    want = top + fy * (bot - top)
    assert np.abs(out - want).max() < 0.05  # float32 positions: ~1e-4 px
    assert np.array_equal(valid | edge[y0 - ya : y1 - ya], ok[y0 - ya : y1 - ya] | edge[y0 - ya : y1 - ya])
    assert 0 < valid.mean() < 1


def _centred(ref: np.ndarray, srcs: np.ndarray, r: int) -> tuple[np.ndarray, ...]:
    """The sweep kernel's image inputs as ``_Stack.sweep`` passes them: the reference and the
    sources centred on ``_GREY_CENTRE``, the reference's window means (centred) and variances, float32."""
    c = np.float32(mvs._GREY_CENTRE)
    mr, vr = mvs._box_stats(ref, r)
    return ref - c, (mr - c).astype(np.float32), vr.astype(np.float32), (srcs - c).astype(np.float32)


def _zncc_truncated(ref: np.ndarray, src: np.ndarray, r: int) -> np.ndarray:
    """Windowed ZNCC by brute force (float64) over (2r+1)^2 boxes truncated at the image border;
    flat windows (variance product <= 1e-6, or a window variance <= ``_MIN_WINDOW_VAR``) score 0."""
    h, w = ref.shape
    out = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            a = ref[max(0, y - r) : y + r + 1, max(0, x - r) : x + r + 1].astype(np.float64)
            b = src[max(0, y - r) : y + r + 1, max(0, x - r) : x + r + 1].astype(np.float64)
            cov = (a * b).mean() - a.mean() * b.mean()
            den = a.var() * b.var()
            flat = min(a.var(), b.var()) <= mvs._MIN_WINDOW_VAR
            out[y, x] = cov / np.sqrt(den) if den > 1e-6 and not flat else 0.0
    return out


@pytest.mark.parametrize(('r', 'top_k'), [(1, 1), (2, 2), (3, 1), (3, 2), (3, 3), (4, 2)])
def test_sweep_kernel_scores_the_mean_of_the_best_sources(r, top_k):
    """``_sweep`` with an identity warp and one hypothesis: its score is the mean of the ``top_k``
    best per-source ZNCCs (brute force, truncated boxes), for the 7-pixel window's direct taps and
    the running sums of the other windows, across strips of 8 rows (the last one partial)."""
    rng = np.random.default_rng(10 * r + top_k)
    h, w, n = 37, 45, 3
    ref = rng.uniform(0, 255, (h, w)).astype(np.float32)
    ref[25:35, 28:40] = 100.0 + rng.normal(0, 0.1, (10, 12))  # about flat (variance 0.01): 0
    srcs = np.stack([ref * rng.uniform(-1, 1) + rng.normal(0, 60, (h, w)) for _ in range(n)])
    srcs = srcs.astype(np.float32)
    srcs[1, 10:20, 10:20] = 7.0  # a flat patch: those windows score 0
    srcs[2, 20:30, 5:15] = 90.0 + rng.normal(0, 0.1, (10, 10))  # about flat (variance 0.01): 0 too
    sizes = np.array([[h, w]] * n, np.int64)
    a = np.stack([np.eye(3)] * n)
    b = np.zeros((n, 3))
    base = np.full((1, h, w), 0.1, np.float32)
    ref_c, mr, vr, srcs_c = _centred(ref, srcs, r)
    pos, best, second = mvs._sweep(
        ref_c, mr, vr, srcs_c, sizes, a, b, base, np.zeros(1, np.float32), r, top_k, 8, True, 2
    )
    # the identity warp, border clamped as the kernel's bilinear lookup (at most W - 1.001, H - 1.001)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    sx, sy = np.minimum(xs, np.float32(w - 1.001)), np.minimum(ys, np.float32(h - 1.001))
    x0, y0 = sx.astype(int), sy.astype(int)
    fx, fy = sx - x0, sy - y0
    warped = [
        (1 - fy) * (g[y0, x0] + fx * (g[y0, x0 + 1] - g[y0, x0]))
        + fy * (g[y0 + 1, x0] + fx * (g[y0 + 1, x0 + 1] - g[y0 + 1, x0]))
        for g in srcs
    ]
    z = np.sort(np.stack([_zncc_truncated(ref, g, r) for g in warped]), axis=0)[::-1]
    want = z[:top_k].mean(axis=0)
    assert np.abs(best - want).max() < 1e-4
    assert (pos == 0).all()
    assert (second == -1).all()  # no hypothesis more than 2 planes away


def test_sweep_kernel_running_sums_hold_across_a_wide_bright_row():
    """Windows other than 7 px sum rows serially: over 1200 columns of bright, weakly textured
    grey levels (variance ~4, the least min_std lets through) the ZNCC still matches brute force."""
    rng = np.random.default_rng(5)
    h, w, r = 12, 1200, 4
    ref = (230.0 + rng.normal(0, 2.0, (h, w))).astype(np.float32)
    src = (ref + rng.normal(0, 1.0, (h, w))).astype(np.float32)[None]
    ref_c, mr, vr, src_c = _centred(ref, src, r)
    _, best, _ = mvs._sweep(
        ref_c, mr, vr, src_c, np.array([[h, w]], np.int64), np.eye(3)[None], np.zeros((1, 3)),
        np.full((1, h, w), 0.1, np.float32), np.zeros(1, np.float32), r, 1, 8, False, 2,
    )  # fmt: skip
    ys, xs = np.mgrid[0:h, 0:w]
    sx, sy = np.minimum(xs, np.float32(w - 1.001)), np.minimum(ys, np.float32(h - 1.001))
    x0, y0 = sx.astype(int), sy.astype(int)
    g = src[0]
    fx, fy = sx - x0, sy - y0
    warped = (1 - fy) * (g[y0, x0] + fx * (g[y0, x0 + 1] - g[y0, x0])) + fy * (
        g[y0 + 1, x0] + fx * (g[y0 + 1, x0 + 1] - g[y0 + 1, x0])
    )
    want = _zncc_truncated(ref, warped, r)
    assert np.abs(best - want).max() < 2e-3


def test_sweep_kernel_with_a_base_per_hypothesis_scores_each_as_alone():
    """``_sweep`` with one base map per hypothesis (the propagation candidates in one call) scores
    each as a call of its own would, and its winner is the first best (as the sequential
    ``np.where(score > best)`` it replaced)."""
    rng = np.random.default_rng(3)
    h, w, n, r = 41, 52, 3, 3
    ref = rng.uniform(0, 255, (h, w)).astype(np.float32)
    srcs = np.stack([np.roll(ref, k + 1, axis=1) + rng.normal(0, 20, (h, w)) for k in range(n)]).astype(
        np.float32
    )
    ref, mr, vr, srcs = _centred(ref, srcs, r)
    sizes = np.array([[h, w]] * n, np.int64)
    a = np.stack([np.eye(3)] * n)
    b = np.stack([[50.0 * (k + 1), 0.0, 0.0] for k in range(n)])  # disparity 50 (k + 1) rho px
    bases = rng.uniform(0.0, 0.05, (4, h, w)).astype(np.float32)
    bases[2, :10] = bases[0, :10]  # equal scores: the first wins
    offs = np.zeros(4, np.float32)
    pos, best, _ = mvs._sweep(ref, mr, vr, srcs, sizes, a, b, bases, offs, r, 2, 8, False, 2)
    alone = np.stack(
        [
            mvs._sweep(ref, mr, vr, srcs, sizes, a, b, bases[k : k + 1], offs[:1], r, 2, 8, False, 2)[1]
            for k in range(4)
        ]
    )
    np.testing.assert_array_equal(best, alone.max(axis=0))
    want = np.where(alone.max(axis=0) > -1, np.argmax(alone, axis=0), -1)
    np.testing.assert_array_equal(pos, want)
    assert (pos[:7] != 2).all()  # windows within the equal rows


# --------------------------------------------------------------------------------------------- neighbours


def test_select_neighbours_rule():
    cam = PinholeCamera.from_fov(320, 240, 60.0)
    target = np.zeros(3)

    def at(x, y, z):
        return look_at([x, y, z], target)

    poses = np.stack([
        at(0, -100, 60),  # 0 reference (~117 m from the target)
        at(0, -100, 60),  # 1 same pose: no triangulation angle
        at(15, -100, 60),  # 2 ~7 deg
        at(-25, -100, 60),  # 3 ~12 deg
        at(40, -95, 60),  # 4 ~20 deg
        at(110, 0, 60),  # 5 ~60 deg: too wide (and looking across)
        look_at([0, -100, 60], [0, -200, 60]),  # 6 facing away
        at(-8, -100, 60),  # 7 ~4 deg
    ])  # fmt: skip
    pts = np.random.default_rng(0).uniform([-20, -20, 0], [20, 20, 5], (500, 3))
    got = mvs.select_neighbours(0, poses, cam, points_w=pts)
    assert set(got) == {2, 3, 4, 7}
    assert got[0] in (2, 3)  # nearest to the 10 deg target first
    assert mvs.select_neighbours(0, poses, cam, points_w=pts, max_neighbours=2) == got[:2]
    # Without sparse points: a pixel grid at the geometric mean of the depth range.
    assert set(mvs.select_neighbours(0, poses, cam, depth_range=(80.0, 170.0))) == {2, 3, 4, 7}
    with pytest.raises(ValueError, match='depth_range or points_w'):
        mvs.select_neighbours(0, poses, cam)
    with pytest.raises(ValueError, match='ref_index'):
        mvs.select_neighbours(8, poses, cam, points_w=pts)
    with pytest.raises(ValueError, match='cameras'):
        mvs.select_neighbours(0, poses, [cam, cam], points_w=pts)


def test_select_neighbours_surrounds_the_reference_and_prefers_its_viewing_direction():
    cam = PinholeCamera.from_fov(320, 240, 60.0)
    target = np.zeros(3)

    def at(x, look=target):
        return look_at([x, -100, 60], look)

    pts = np.random.default_rng(0).uniform([-20, -20, 0], [20, 20, 5], (500, 3))
    # Three candidates right of the reference near the 10 deg target, one left and farther (~15 deg).
    poses = np.stack([at(0), at(16), at(20), at(24), at(-30)])
    assert mvs.select_neighbours(0, poses, cam, points_w=pts, max_neighbours=2, side_spread=0) == [2, 1]
    assert mvs.select_neighbours(0, poses, cam, points_w=pts, max_neighbours=2) == [2, 4]
    assert mvs.select_neighbours(0, poses, cam, points_w=pts) == [2, 4, 1, 3]
    # Same overlap (all probes), the right view nearer the target angle but pitched 17 deg up.
    wide = PinholeCamera.from_fov(320, 240, 80.0)
    poses = np.stack([at(0), at(-15), at(20, [0, -40, 30])])
    assert mvs.select_neighbours(0, poses, wide, points_w=pts, view_angle_scale_deg=0) == [2, 1]
    assert mvs.select_neighbours(0, poses, wide, points_w=pts) == [1, 2]
    with pytest.raises(ValueError, match='side_spread'):
        MvsOptions(side_spread=1.0)
    with pytest.raises(ValueError, match='view_angle_scale_deg'):
        MvsOptions(view_angle_scale_deg=-1.0)


def _select_neighbours_loop(
    ref,
    poses,
    cam,
    rng,
    max_n=4,
    min_a=2.0,
    max_a=30.0,
    target=10.0,
    min_ov=0.3,
    max_view=60.0,
    spread=0.5,
    scale=30.0,
):
    """select_neighbours' rule written as a plain loop per candidate (the test's oracle)."""
    import math

    def angle(a, b):
        c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
        return math.degrees(math.acos(min(1.0, max(-1.0, c))))

    t_ref = poses[ref]
    probes = mvs.probe_points(cam, t_ref, math.sqrt(rng[0] * rng[1]))
    centroid = probes.mean(axis=0)
    cands = []
    for j, t in enumerate(poses):
        va = angle(t_ref[:3, 2], t[:3, 2])
        if j == ref or va > max_view:
            continue
        uv, z = cam.project((probes - t[:3, 3]) @ t[:3, :3])
        with np.errstate(invalid='ignore'):
            vis = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5)
            vis &= (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5)
        if vis.mean() < min_ov or not vis.any():
            continue
        tri = float(np.median([angle(t_ref[:3, 3] - p, t[:3, 3] - p) for p in probes[vis]]))
        if min_a <= tri <= max_a:
            s = vis.mean() * math.exp(-0.5 * ((tri - target) / target) ** 2)
            s *= math.exp(-0.5 * (va / scale) ** 2)
            b = ((t[:3, 3] - t_ref[:3, 3]) @ t_ref[:3, :3])[:2]
            cands.append((s, j, b / np.linalg.norm(b) if np.linalg.norm(b) > 1e-9 else np.zeros(2)))
    picked = []
    while cands and len(picked) < max_n:
        scores = []
        for s, j, side in cands:
            for k, _ in picked:
                s *= min(1.0, angle(poses[j][:3, 3] - centroid, poses[k][:3, 3] - centroid) / min_a)
            if picked:
                s *= 1.0 - spread * (1.0 + max(float(side @ sk) for _, sk in picked)) / 2.0
            scores.append(s)
        _, j, side = cands.pop(int(np.argmax(scores)))
        picked.append((j, side))
    return [j for j, _ in picked]


@pytest.mark.parametrize('kind', ['lawnmower', 'orbit', 'forward'])
def test_select_neighbours_matches_the_rule_as_a_loop(kind):
    """The vectorised selection picks what the per-candidate loop of its docstring picks."""
    cam = PinholeCamera(width=640, height=360, k=np.array([[500.0, 0, 320], [0, 500.0, 180], [0, 0, 1]]))
    poses = np.array([s.t_wc for s in make_trajectory(kind, duration_s=40.0, fps=2.0, seed=5)])
    for ref in range(0, len(poses), 4):
        for rng in [(10.0, 200.0), (30.0, 60.0)]:
            assert mvs.select_neighbours(ref, poses, cam, depth_range=rng) == _select_neighbours_loop(
                ref, poses, cam, rng
            ), (ref, rng)


# --------------------------------------------------------------------------------------------- filter


def test_geometric_filter_keeps_consistent_and_drops_wrong(flights):
    frames, cam, poses, _, _ = flights[(2, 'lawnmower')]
    gt = [np.where(f.sky, 0, f.depth).astype(np.float32) for f in frames]
    kept, counts = mvs.geometric_filter(gt, cam, poses)
    for c in counts:
        assert c.dtype == np.uint8
        assert c.max() <= len(frames) - 1
    # The middle view has 2 partners nearly everywhere: all but occlusions and frustum edges agree.
    assert (kept[2] > 0).sum() >= 0.85 * (gt[2] > 0).sum()
    assert np.all(kept[2][kept[2] > 0] == gt[2][kept[2] > 0])
    wrong = [d.copy() for d in gt]
    wrong[2][100:150, 200:300] *= 1.05
    kept, _ = mvs.geometric_filter(wrong, cam, poses, max_rel_depth_err=0.01)
    assert not kept[2][100:150, 200:300].any()
    assert (kept[2][160:] > 0).mean() > 0.8
    # The same result through the pairs of compute_depth_maps, and the clamp to the partner count.
    one, _ = mvs.geometric_filter(gt[:2], cam, poses[:2], min_consistent=2)
    assert (one[0] > 0).sum() > 0.5 * (gt[0] > 0).sum()


# --------------------------------------------------------------------------------------------- bad input


def test_bad_input_is_named():
    cam, ref, t_wr, srcs, poses = plane_views()
    rng = (10.0, 500.0)
    with pytest.raises(ValueError, match=r'src_rgbs\[1\]'):
        mvs.mvs_depth(ref, cam, t_wr, [srcs[0], srcs[1][:-1]], cam, poses[:2], depth_range=rng)
    with pytest.raises(ValueError, match='ref_rgb'):
        mvs.mvs_depth(ref[:, :-1], cam, t_wr, srcs, cam, poses, depth_range=rng)
    with pytest.raises(ValueError, match='src_poses'):
        mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses[:3], depth_range=rng)
    with pytest.raises(ValueError, match='src_cams'):
        mvs.mvs_depth(ref, cam, t_wr, srcs, [cam] * 3, poses, depth_range=rng)
    with pytest.raises(ValueError, match='depth_range or points_w'):
        mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses)
    with pytest.raises(ValueError, match='depth_range'):
        mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(50.0, 10.0))
    with pytest.raises(ValueError, match='ref_pose'):
        mvs.mvs_depth(ref, cam, 2 * np.eye(4), srcs, cam, poses, depth_range=rng)
    distorted = PinholeCamera(cam.width, cam.height, cam.k, d=[0.1, 0, 0, 0, 0])
    with pytest.raises(ValueError, match='undistort'):
        mvs.mvs_depth(ref, distorted, t_wr, srcs, cam, poses, depth_range=rng)
    with pytest.raises(ValueError, match=r'MvsOptions\.window'):
        MvsOptions(window=4)
    with pytest.raises(ValueError, match=r'MvsOptions\.backend'):
        MvsOptions(backend='gpu')
    with pytest.raises(ValueError, match=r'views\[0\]'):
        mvs.compute_depth_maps([(ref, cam, t_wr)], depth_range=rng)
    with pytest.raises(ValueError, match=r'depths\[0\]'):
        mvs.geometric_filter([np.zeros((5, 5))], cam, poses[:1])


def test_degenerate_views_give_empty_depth_with_a_reason():
    cam, ref, t_wr, srcs, poses = plane_views()
    rng = (10.0, 500.0)
    r = mvs.mvs_depth(ref, cam, t_wr, [], cam, np.zeros((0, 4, 4)), depth_range=rng)
    assert r.reason == mvs.REASON_NO_SOURCES
    assert not r.depth.any()
    assert r.depth.shape == ref.shape[:2]
    away = look_at([0, 0, 0], [0, 0, -1.0], up=(0, 1, 0))  # looking backwards
    r = mvs.mvs_depth(ref, cam, t_wr, srcs[:1], cam, away[None], depth_range=rng)
    assert r.reason == mvs.REASON_NO_OVERLAP
    assert not r.depth.any()
    r = mvs.mvs_depth(ref, cam, t_wr, [ref], cam, t_wr[None], depth_range=rng)
    assert r.reason == mvs.REASON_NO_PARALLAX
    assert not r.depth.any()
    r = mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, points_w=np.array([[0.0, 0.0, -10.0]]))
    assert r.reason == mvs.REASON_NO_DEPTH_RANGE
    assert not r.depth.any()
    # A single view, and a set whose second view sees nothing of the first.
    [one] = mvs.compute_depth_maps([MvsView(ref, cam, t_wr)], depth_range=rng)
    assert one.reason == mvs.REASON_NO_SOURCES
    assert not one.depth.any()
    assert one.neighbours == ()
    far = np.eye(4)
    far[:3, 3] = [5000.0, 0, 0]
    both = mvs.compute_depth_maps([MvsView(ref, cam, t_wr), MvsView(srcs[0], cam, far)], depth_range=rng)
    assert [b.reason for b in both] == [mvs.REASON_NO_SOURCES] * 2
    assert mvs.compute_depth_maps([], depth_range=rng) == []


# --------------------------------------------------------------------------------------------- COLMAP


def test_colmap_backend_without_cuda_is_a_clean_error(monkeypatch):
    import pycolmap

    monkeypatch.setattr(pycolmap, 'has_cuda', False, raising=False)
    cam, ref, t_wr, srcs, poses = plane_views()
    o = MvsOptions(backend='colmap')
    with pytest.raises(MvsBackendUnavailable, match=r"pycolmap was built without CUDA; use backend='cpu'"):
        mvs.mvs_depth(ref, cam, t_wr, srcs, cam, poses, depth_range=(10.0, 500.0), options=o)
    views = [MvsView(ref, cam, t_wr)] + [MvsView(s, cam, p) for s, p in zip(srcs, poses)]
    with pytest.raises(RuntimeError, match='CUDA'):
        mvs.compute_depth_maps(views, depth_range=(10.0, 500.0), options=o)


def test_colmap_backend_workspace_round_trip(monkeypatch):
    """With CUDA faked: the sparse model, patch-match.cfg and the depth map files COLMAP reads/writes."""
    import pycolmap

    cam, ref, t_wr, srcs, poses = plane_views()
    seen = {}

    def fake_patch_match_stereo(ws, workspace_format='COLMAP', options=None, **_):
        rec = pycolmap.Reconstruction(ws / 'sparse')
        seen['cfg'] = (ws / 'stereo' / 'patch-match.cfg').read_text().split('\n')
        seen['range'] = (options.depth_min, options.depth_max)
        for image in rec.images.values():
            t_cw = np.eye(4)
            t_cw[:3] = image.cam_from_world().matrix()
            seen[image.name] = (np.linalg.inv(t_cw), rec.cameras[image.camera_id].params.copy())
            h, w = rec.cameras[image.camera_id].height, rec.cameras[image.camera_id].width
            for kind, value in (('geometric', image.image_id), ('photometric', -1.0)):
                path = ws / 'stereo' / 'depth_maps' / f'{image.name}.{kind}.bin'
                data = np.full((h, w), value, np.float32)
                path.write_bytes(f'{w}&{h}&1&'.encode() + data.tobytes())

    monkeypatch.setattr(pycolmap, 'has_cuda', True, raising=False)
    monkeypatch.setattr(pycolmap, 'patch_match_stereo', fake_patch_match_stereo)
    views = [MvsView(ref, cam, t_wr)] + [MvsView(s, cam, p) for s, p in zip(srcs, poses)]
    out = mvs.compute_depth_maps(views, depth_range=(10.0, 500.0), options=MvsOptions(backend='colmap'))
    assert seen['range'] == (10.0, 500.0)
    assert seen['cfg'][0] == '00000.png'
    assert set(seen['cfg'][1].split(', ')) == {f'0000{i}.png' for i in range(1, 5)}
    np.testing.assert_allclose(seen['00002.png'][0], poses[1], atol=1e-9)
    np.testing.assert_allclose(seen['00000.png'][1], [cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5])
    for i, r in enumerate(out):
        assert r.depth.shape == ref.shape[:2]
        assert np.all(r.depth == i + 1)
        assert not r.photometric_depth.any()  # negative depth is unknown
