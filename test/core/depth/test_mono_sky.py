# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Monocular depth adapters (ONNX conventions, ground-plane prior) and sky handling."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from onnx_models import channel_model, sky_logits_model

from ibr_ros.core.depth.mono import (
    PRESETS,
    GroundPlanePrior,
    MonoModelError,
    MonoModelSpec,
    OnnxMonoDepth,
    nearness_to_g,
)
from ibr_ros.core.depth.sky import OnnxSkySegmenter, SkySpec, apply_sky_depth, erode_sky, horizon_mask
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.plane import fit_ground_plane
from ibr_ros.core.geometry.transforms import look_at


def _gradient_image(h=60, w=80) -> np.ndarray:
    """Red increases left to right, green top to bottom, blue constant."""
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[..., 0] = np.linspace(10, 250, w, dtype=np.uint8)[None, :]
    rgb[..., 1] = np.linspace(10, 250, h, dtype=np.uint8)[:, None]
    rgb[..., 2] = 128
    return rgb


@pytest.mark.parametrize(
    ('preset', 'layout', 'fixed', 'out_rank'),
    [
        ('midas_v21_small', 'NCHW', (256, 256), 4),
        ('depth_anything_v2', 'NCHW', None, 3),
        ('dpt', 'NCHW', (384, 384), 4),
        ('megadepth', 'NCHW', (512, 384), 3),
    ],
)
def test_presets_with_stand_in_models(tmp_path, preset, layout, fixed, out_rank):
    # The stand-in returns the (normalised) red channel as the model's output kind.
    path = channel_model(tmp_path / f'{preset}.onnx', channel=0, layout=layout, size=fixed, out_rank=out_rank)
    model = OnnxMonoDepth(replace(PRESETS[preset], path=path))
    rgb = _gradient_image()
    g = model.predict_g(rgb)
    assert g.shape == rgb.shape[:2]
    assert g.dtype == np.uint16
    row = g[30].astype(int)
    # inverse depth: redder = nearer; log depth: redder = farther.
    if PRESETS[preset].output == 'inverse_depth':
        assert row[-1] > row[0]
        assert np.all(np.diff(row) >= 0)
    else:
        assert row[0] > row[-1]
        assert np.all(np.diff(row) <= 0)
    assert g.min() >= 1
    assert g.max() == 65535


def test_preprocess_convention_nhwc_bgr(tmp_path):
    spec = MonoModelSpec(
        path=channel_model(tmp_path / 'm.onnx', channel=2, layout='NHWC', add=1.0),
        layout='NHWC',
        color_order='BGR',
        mean=(0.5, 0.5, 0.5),
        std=(0.25, 0.25, 0.25),
        max_side=64,
        multiple_of=16,
        output='depth',
    )
    model = OnnxMonoDepth(spec)
    rgb = _gradient_image()
    x = model.preprocess(rgb)
    assert x.shape == (1, 48, 64, 3)  # 80x60 -> long side 64, multiples of 16
    # Channel 0 of a BGR input is blue = 128 -> (128/255 - 0.5) / 0.25.
    assert x[0, ..., 0] == pytest.approx((128 / 255 - 0.5) / 0.25, abs=1e-6)
    # Output 'depth' = channel 2 (red, normalised) + 1, all positive: nearness = 1 / depth.
    near = model.predict_nearness(rgb)
    red = (rgb[..., 0] / 255.0 - 0.5) / 0.25 + 1.0
    ok = red > 0.2
    assert np.corrcoef(near[ok], 1.0 / red[ok])[0, 1] > 0.99


def test_bad_model_specs(tmp_path):
    with pytest.raises(MonoModelError, match='not a file'):
        OnnxMonoDepth(MonoModelSpec(path=tmp_path / 'missing.onnx'))
    bad = tmp_path / 'bad.onnx'
    bad.write_bytes(b'garbage')
    with pytest.raises(MonoModelError, match='cannot load'):
        OnnxMonoDepth(MonoModelSpec(path=bad))
    with pytest.raises(MonoModelError, match='layout'):
        MonoModelSpec(layout='CHW')  # type: ignore[arg-type]
    with pytest.raises(MonoModelError, match='output'):
        MonoModelSpec(output='disparity')  # type: ignore[arg-type]


def test_nearness_to_g_robust_and_invalid():
    near = np.linspace(0, 1, 1000).reshape(20, 50)
    near[0, 0] = 1e9  # outlier is clipped, not stretching the range
    near[0, 1] = np.nan
    g = nearness_to_g(near)
    assert g[0, 1] == 0
    assert g[0, 0] == 65535
    assert np.count_nonzero(g == 65535) < 5
    assert np.all(nearness_to_g(np.full((3, 3), np.nan)) == 0)


def test_ground_plane_prior_matches_plane_depth():
    cam = PinholeCamera.from_fov(64, 48, 60)
    t_wc = look_at([0, -40, 30], [0, 0, 0])
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-50, 50, (300, 2)), np.zeros(300)]
    pts[:20, 2] = rng.uniform(5, 20, 20)  # outliers (trees, roofs)
    plane = fit_ground_plane(pts)
    assert plane[:3] == pytest.approx([0, 0, 1], abs=1e-6)
    prior = GroundPlanePrior(plane)
    z = prior.depth(cam, t_wc)
    # The centre pixel looks at the origin.
    centre = np.linalg.norm([0, -40, 30])
    assert z[23:25, 31:33].mean() == pytest.approx(centre, rel=0.02)
    # Looking above the horizon gives +inf and G = 0 there.
    t_up = look_at([0, 0, 30], [0, 100, 40])
    g = prior.predict_g(cam, t_up)
    assert np.isinf(prior.depth(cam, t_up)[0]).all()
    assert (g[0] == 0).all()
    assert (g[-1] > 0).all()
    # Nearer ground (bottom rows) has larger G.
    g2 = prior.predict_g(cam, t_wc)
    assert g2[-1].mean() > g2[0].mean()


def test_sky_model_and_erosion(tmp_path):
    spec = SkySpec(
        path=sky_logits_model(tmp_path / 'sky.onnx', size=(32, 24)), input_size=(32, 24), sky_class=0
    )
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:20] = (90, 140, 230)  # blue sky on top
    rgb[20:] = (140, 110, 60)  # brown ground
    sky = OnnxSkySegmenter(spec).predict(rgb)
    assert sky[:18].all()
    assert not sky[22:].any()
    eroded = erode_sky(sky, diag_fraction=0.1)  # disk of 8 px diameter
    assert eroded[:14].all()
    assert not eroded[17:].any()


def test_sky_depth_and_horizon():
    d_fused = np.full((4, 4), 5.0, np.float32)
    d_mvs = np.zeros((4, 4), np.float32)
    d_mvs[2:, :] = [[3, 4, 7, 6]] * 2
    sky = np.zeros((4, 4), bool)
    sky[0] = True
    out, sky_depth = apply_sky_depth(d_fused, sky, d_mvs)
    assert sky_depth == 14.0
    assert (out[0] == 14.0).all()
    assert (out[1:] == 5.0).all()
    with pytest.raises(ValueError, match='no valid depth'):
        apply_sky_depth(d_fused, sky, np.zeros_like(d_mvs))
    cam = PinholeCamera.from_fov(40, 30, 60)
    level = look_at([0, 0, 10], [100, 0, 10])
    h = horizon_mask(cam, level)
    assert h[:14].all()
    assert not h[16:].any()
