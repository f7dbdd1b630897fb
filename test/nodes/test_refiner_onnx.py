# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""depth_refiner with the shipped ONNX model for monocular depth and sky, in this process.

Three keyframes of the shipped synthetic bag (frames 48, 72, 96, 320x180, all with stored ground
truth) go to a refiner started with ``mono:=onnx sky:=onnx`` (model ``ibr_mono``); each published
depth must be within 10% median relative error of the ground truth where both are valid. Bad model
parameters must stop the node at start-up with one readable error line naming the parameter.
"""

from __future__ import annotations

import numpy as np
import pytest
from node_harness import (
    assert_refuses_to_start,
    in_process,
    keyframe_topics,
    publish_frame,
    shipped_frames,
)
from sensor_msgs.msg import Image

import msg_utils
from ibr_ros.core.depth.mono import PRESETS
from ibr_ros.core.depth.sky import SKY_PRESETS
from ibr_ros.errors import UserError
from ibr_ros.models import SHIPPED_MONO_MODEL, mono_spec, sky_spec
from ibr_ros.nodes.common import model_qos

pytestmark = pytest.mark.dds

FRAMES = (48, 72, 96)  # multiples of 3: ground-truth depth is stored
SIZE = (320, 180)


@pytest.fixture(scope='module')
def keyframes(repo) -> list[dict]:
    """stamp, rgb, camera, pose and ground-truth depth of FRAMES, resized to SIZE."""
    return shipped_frames(repo, FRAMES, SIZE)


def test_model_parameters_resolve_names_paths_and_presets(tmp_path):
    spec = mono_spec('ibr_mono')
    assert spec.path == SHIPPED_MONO_MODEL
    assert spec.max_side == PRESETS['ibr_mono'].max_side
    assert mono_spec(str(SHIPPED_MONO_MODEL), 'midas_v21_small').input_size == (256, 256)
    assert sky_spec('ibr_mono').output == SKY_PRESETS['ibr_mono'].output == 'sky_logit'
    with pytest.raises(UserError, match=r"parameter mono_preset must name .* mono_model '.*ibr_mono.onnx'"):
        mono_spec(str(SHIPPED_MONO_MODEL))  # a path needs its I/O convention
    with pytest.raises(UserError, match=r"parameter mono_preset 'nope': unknown preset; one of .*midas"):
        mono_spec('ibr_mono', 'nope')
    with pytest.raises(UserError, match=r"parameter mono_model '.*missing.onnx': no such file"):
        mono_spec(str(tmp_path / 'missing.onnx'), 'dpt')
    with pytest.raises(UserError, match="parameter mono_model 'midas': neither a known model"):
        mono_spec('midas')
    with pytest.raises(UserError, match=r"parameter sky_model 'midas_v21_small': .* has no sky output"):
        sky_spec('midas_v21_small')


@pytest.mark.parametrize(
    ('params', 'error'),
    [
        (['mono:=onnx', 'mono_model:=/nonexistent/depth.onnx', 'mono_preset:=dpt'],
         "parameter mono_model '/nonexistent/depth.onnx': no such file"),
        (['sky:=onnx', 'sky_model:=README.md', 'sky_preset:=ibr_mono'],
         "parameter sky_model 'README.md': neither a known model"),
        (['sky:=clouds'], "parameter sky must be 'fallback', 'onnx' or 'none', got 'clouds'"),
    ],
)  # fmt: skip
def test_bad_model_parameters_stop_the_node_with_one_line(params, error, capfd):
    from ibr_ros.nodes.depth_refiner import main

    assert_refuses_to_start(main, 'depth_refiner', params, error, capfd)


def test_refiner_node_with_onnx_mono_and_sky(repo, keyframes):
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    config = repo / 'config' / 'depth_refiner.yaml'
    onnx = {'mono': 'onnx', 'mono_model': 'ibr_mono', 'sky': 'onnx', 'sky_model': 'ibr_mono'}
    with in_process(DepthRefinerNode, config, 'onnx_refiner_feeder', **onnx) as h:
        node = h.node
        cfg = node.refiner.config
        assert (cfg.mono, cfg.sky) == ('onnx', 'onnx')
        assert cfg.mono_model.path == cfg.sky_model.path == SHIPPED_MONO_MODEL
        depths = h.collect(Image, 'keyframes/depth', model_qos())
        pubs = h.publishers(keyframe_topics(model_qos()))
        for f in keyframes:
            publish_frame(pubs, f)
        refined = lambda: {msg_utils.stamp_to_ns(m.header.stamp) for m in depths}  # noqa: E731
        h.wait(lambda: len(refined()) >= len(keyframes), 120)
        bad = dict(node.bad.counts)
    assert bad == {}
    by_stamp = {msg_utils.stamp_to_ns(m.header.stamp): m for m in depths}
    assert set(by_stamp) == {f['stamp'] for f in keyframes}
    rels = []
    for f in keyframes:
        d = msg_utils.image_to_numpy(by_stamp[f['stamp']])
        assert d.shape == (SIZE[1], SIZE[0])
        gt = f['gt']
        ok = np.isfinite(gt) & (gt > 0) & np.isfinite(d) & (d > 0)
        assert ok.mean() > 0.5
        rel = float(np.median(np.abs(d[ok] - gt[ok]) / gt[ok]))
        rels.append(rel)
    print('median relative error per keyframe', [round(r, 4) for r in rels])
    assert max(rels) < 0.1, rels
