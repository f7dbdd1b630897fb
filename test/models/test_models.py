# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The shipped monocular depth + sky model: file, I/O convention, adapters and held-out quality."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import pytest

from ibr_ros.core.depth.mono import PRESETS, OnnxMonoDepth
from ibr_ros.core.depth.sky import SKY_PRESETS, OnnxSkySegmenter
from ibr_ros.errors import UserError
from ibr_ros.jobs.eval_mono import evaluate_sample, sparse_reference, spearman
from ibr_ros.jobs.mono_data import EVAL_SEED_BASE, TRAIN_SEED_BASE, render_samples
from ibr_ros.models import SHIPPED_MONO_MODEL

SPEC_JSON = SHIPPED_MONO_MODEL.with_suffix('.json')


@pytest.fixture(scope='module')
def depth_model() -> OnnxMonoDepth:
    return OnnxMonoDepth(replace(PRESETS['ibr_mono'], path=SHIPPED_MONO_MODEL))


@pytest.fixture(scope='module')
def sky_model() -> OnnxSkySegmenter:
    return OnnxSkySegmenter(replace(SKY_PRESETS['ibr_mono'], path=SHIPPED_MONO_MODEL))


@pytest.fixture(scope='module')
def held_out() -> list:
    """Four views of one held-out town (seed block never used for training), 384x224."""
    return render_samples([EVAL_SEED_BASE], 4, (384, 224))


def test_shipped_file_and_signature() -> None:
    assert SHIPPED_MONO_MODEL.is_file()
    assert SHIPPED_MONO_MODEL.stat().st_size <= 10e6
    model = onnx.load(str(SHIPPED_MONO_MODEL))
    onnx.checker.check_model(model)
    assert [i.name for i in model.graph.input] == ['image']
    assert [o.name for o in model.graph.output] == ['inverse_depth', 'sky_logit']
    dims = [d.dim_param or d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
    assert dims[:2] == [1, 3]
    assert all(isinstance(d, str) for d in dims[2:])  # dynamic height and width
    spec = json.loads(SPEC_JSON.read_text())
    assert spec['outputs'][0]['name'] == 'inverse_depth'
    assert spec['mean'] == list(PRESETS['ibr_mono'].mean)


@pytest.mark.parametrize('size', [(384, 224), (500, 333), (224, 400)])
def test_inference_shapes_and_types(
    depth_model: OnnxMonoDepth, sky_model: OnnxSkySegmenter, size: tuple
) -> None:
    w, h = size
    rgb = np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)
    near = depth_model.predict_nearness(rgb)
    assert near.shape == (h, w)
    assert near.dtype == np.float32
    assert np.isfinite(near).all()
    g = depth_model.predict_g(rgb)
    assert g.dtype == np.uint16
    assert g.shape == (h, w)
    sky = sky_model.predict(rgb)
    assert sky.shape == (h, w)
    assert sky.dtype == bool


def test_runtime_sanity(depth_model: OnnxMonoDepth) -> None:
    """One 384x224 depth pass takes well under a second on one thread (the benchmark measures it)."""
    rgb = np.zeros((224, 384, 3), np.uint8)
    depth_model.predict_nearness(rgb)  # warm-up
    t0 = time.perf_counter()
    depth_model.predict_nearness(rgb)
    assert time.perf_counter() - t0 < 1.0


def test_flip_average_is_mirror_equivariant(depth_model: OnnxMonoDepth) -> None:
    """With ``flip_average`` (on in the preset) a mirrored image gives the mirrored prediction."""
    assert depth_model.spec.flip_average
    rgb = np.random.default_rng(1).integers(0, 256, (160, 256, 3), dtype=np.uint8)
    a = depth_model.predict_nearness(rgb)
    b = depth_model.predict_nearness(np.ascontiguousarray(rgb[:, ::-1]))[:, ::-1]
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * float(np.abs(a).max()))
    single = OnnxMonoDepth(replace(depth_model.spec, flip_average=False)).predict_nearness(rgb)
    assert not np.allclose(single, a)


def test_seed_ranges_do_not_overlap() -> None:
    assert EVAL_SEED_BASE > TRAIN_SEED_BASE + 10_000


def test_spearman_and_sparse_reference() -> None:
    x = np.arange(100.0)
    assert spearman(x, x**3) == pytest.approx(1.0)
    assert spearman(x, -x) == pytest.approx(-1.0)
    d = np.full((10, 10), np.inf, np.float32)
    d[5:] = 7.0
    ref = sparse_reference(d, 0.2, seed=0)
    assert (ref > 0).sum() == 10
    assert np.all(ref[ref > 0] == 7.0)
    assert np.all(ref[:5] == 0)


def test_held_out_quality(held_out: list, depth_model: OnnxMonoDepth, sky_model: OnnxSkySegmenter) -> None:
    """On a town never used for training: depth ordering, sky IoU and LUT-remapped Abs Rel (4 views)."""
    rows = [evaluate_sample(s, depth_model, sky_model, 0.05, i)[0] for i, s in enumerate(held_out)]
    inter = sum(r['sky_inter'] for r in rows)
    union = sum(r['sky_union'] for r in rows)
    assert union > 0, 'the held-out views should show some sky'
    assert inter / union >= 0.9
    assert np.mean([r['spearman_model'] for r in rows]) > 0.7
    model = np.mean([r['abs_rel_model'] for r in rows])
    assert model < 0.5 * np.mean([r['abs_rel_constant'] for r in rows])


def test_beats_the_ground_plane_prior_on_held_out_towns(
    depth_model: OnnxMonoDepth, sky_model: OnnxSkySegmenter
) -> None:
    """The issue's bar, on the held-out set of ``ibr eval mono`` (8 towns x 4 views, 384x224).

    Mean Abs Rel after the LUT remap, model vs the geometric ground-plane prior fitted to the same
    reference pixels (measured: 0.117 vs 0.137; on the next seed block 0.084 vs 0.104), plus the
    pooled sky IoU (measured 0.989).
    """
    samples = render_samples([EVAL_SEED_BASE + i for i in range(8)], 4, (384, 224))
    rows = [evaluate_sample(s, depth_model, sky_model, 0.05, i)[0] for i, s in enumerate(samples)]
    model = np.mean([r['abs_rel_model'] for r in rows])
    prior = np.mean([r['abs_rel_ground_plane'] for r in rows])
    assert model < prior
    assert np.mean([r['spearman_model'] for r in rows]) > np.mean([r['spearman_ground_plane'] for r in rows])
    assert sum(r['sky_inter'] for r in rows) / sum(r['sky_union'] for r in rows) >= 0.9


def test_real_mvs_evaluation_scores_held_out_mvs_pixels(
    tmp_path: Path, held_out: list, depth_model: OnnxMonoDepth
) -> None:
    """``evaluate_real_mvs`` on an npz as tools/real_mvs_data.py writes (synthetic views, GT as MVS)."""
    from ibr_ros.jobs.eval_mono import evaluate_real_mvs

    depth = np.stack([np.where(np.isfinite(s.depth), s.depth, 0) for s in held_out]).astype(np.float32)
    depth[:, ::2] = 0  # sparse, like MVS
    depth[0] = 0  # a view without MVS depth is skipped
    path = tmp_path / 'real.npz'
    np.savez(
        path,
        rgb=np.stack([s.rgb for s in held_out]),
        depth=depth,
        k=np.stack([s.camera.k for s in held_out]),
        t_wc=np.stack([s.t_wc for s in held_out]),
    )
    rows = evaluate_real_mvs(path, depth_model)
    assert [r['view'] for r in rows] == [1, 2, 3]
    for r in rows:
        assert 0 <= r['abs_rel_model'] < r['abs_rel_constant']
        assert np.isfinite(r['abs_rel_ground_plane'])
    (tmp_path / 'bad.npz').write_bytes(b'not an npz')
    with pytest.raises(UserError, match='real-MVS npz'):
        evaluate_real_mvs(tmp_path / 'bad.npz', depth_model)


def test_eval_mono_writes_reports(tmp_path: Path, repo: Path) -> None:
    from ibr_ros.jobs.eval_mono import MonoEvalOptions, evaluate_mono

    opts = MonoEvalOptions(
        scenes=1, views=2, size=(256, 160), photos_bag=repo / 'bags' / 'brighton_beach', photos=1
    )
    summary = evaluate_mono(SHIPPED_MONO_MODEL, tmp_path, opts)
    assert summary['views'] == 2
    for name in (
        'mono_eval.md',
        'mono_eval.json',
        'view_000.png',
        'view_001.png',
        'photo_brighton_beach_00.png',
    ):
        assert (tmp_path / name).is_file(), name
    assert json.loads((tmp_path / 'mono_eval.json').read_text())['views'] == 2
    assert 'Abs Rel' in (tmp_path / 'mono_eval.md').read_text()
    pytest.importorskip('skimage')
    assert (tmp_path / 'photo_skimage_camera.png').is_file()
    assert (tmp_path / 'photo_skimage_rocket.png').is_file()
