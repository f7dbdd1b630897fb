"""depth_refiner with the shipped ONNX model for monocular depth and sky, in this process.

Three keyframes of the shipped synthetic bag (frames 48, 72, 96, 320x180, all with stored ground
truth) go to a refiner started with ``mono:=onnx sky:=onnx`` (model ``ibr_mono``); each published
depth must be within 10% median relative error of the ground truth where both are valid. Bad model
parameters must stop the node at start-up with one readable error line naming the parameter.
"""

from __future__ import annotations

import contextlib
import threading
import time

import cv2
import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from sensor_msgs.msg import CameraInfo, Image

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.core.mono import PRESETS
from ibr_ros.core.sky import SKY_PRESETS
from ibr_ros.errors import UserError
from ibr_ros.jobs.synth_bag import TOPICS
from ibr_ros.models import SHIPPED_MONO_MODEL, mono_spec, sky_spec
from ibr_ros.nodes.common import EXIT_BAD_CONFIG, model_qos

FRAMES = (48, 72, 96)  # multiples of 3: ground-truth depth is stored
SIZE = (320, 180)


@pytest.fixture(scope='module')
def keyframes(repo) -> list[dict]:
    """stamp, rgb, camera, pose and ground-truth depth of FRAMES, resized to SIZE."""
    with open_bag(repo / 'bags' / 'synth_orbit_s0') as reader:
        stamps = [m.timestamp_ns for m in reader.messages([TOPICS['pose']])]
        index = {stamps[i]: k for k, i in enumerate(FRAMES)}
        out: list[dict] = [{'stamp': stamps[i]} for i in FRAMES]
        for m in reader.messages([TOPICS[k] for k in ('image', 'camera_info', 'pose', 'depth')]):
            if (k := index.get(m.timestamp_ns)) is None:
                continue
            if m.topic == TOPICS['image']:
                out[k]['rgb'] = msg_utils.compressed_image_to_numpy(m.msg)
            elif m.topic == TOPICS['camera_info']:
                out[k]['camera'] = msg_utils.camera_info_to_pinhole(m.msg)
            elif m.topic == TOPICS['pose']:
                out[k]['pose'] = msg_utils.pose_stamped_to_matrix(m.msg)
            else:
                out[k]['gt'] = msg_utils.depth_image_to_m(m.msg).copy()
    for f in out:
        cam = f['camera']
        f['rgb'] = np.ascontiguousarray(cv2.resize(f['rgb'], SIZE, interpolation=cv2.INTER_AREA))
        f['camera'] = cam.scaled(SIZE[0] / cam.width, SIZE[1] / cam.height)
        f['gt'] = cv2.resize(f['gt'], SIZE, interpolation=cv2.INTER_NEAREST)
    return out


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

    argv = ['depth_refiner', '--ros-args']
    for prm in params:
        argv += ['-p', prm]
    assert main(argv) == EXIT_BAD_CONFIG
    err = capfd.readouterr().err
    assert f'[depth_refiner]: cannot start: {error}' in err
    assert 'Traceback' not in err


def test_refiner_node_with_onnx_mono_and_sky(repo, keyframes):
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    args = ['--ros-args', '--params-file', str(repo / 'config' / 'depth_refiner.yaml')]
    for prm in ('mono:=onnx', 'mono_model:=ibr_mono', 'sky:=onnx', 'sky_model:=ibr_mono'):
        args += ['-p', prm]
    rclpy.init(args=args)
    executor = SingleThreadedExecutor()
    node = feeder = thread = None
    try:
        node = DepthRefinerNode()
        cfg = node.refiner.config
        assert (cfg.mono, cfg.sky) == ('onnx', 'onnx')
        assert cfg.mono_model.path == cfg.sky_model.path == SHIPPED_MONO_MODEL
        feeder = rclpy.create_node('onnx_refiner_feeder')
        depths: list[Image] = []
        feeder.create_subscription(Image, 'keyframes/depth', depths.append, model_qos())
        pubs = [feeder.create_publisher(t, f'keyframes/{n}', model_qos()) for t, n in
                ((Image, 'image'), (CameraInfo, 'camera_info'), (PoseStamped, 'pose'))]  # fmt: skip
        executor.add_node(node)
        executor.add_node(feeder)

        def spin() -> None:
            with contextlib.suppress(ExternalShutdownException):
                executor.spin()

        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        deadline = time.monotonic() + 30
        while not all(p.get_subscription_count() for p in pubs) and time.monotonic() < deadline:
            time.sleep(0.05)
        for f in keyframes:
            header = msg_utils.make_header(f['stamp'], 'camera_optical')
            pubs[0].publish(msg_utils.numpy_to_image(f['rgb'], 'rgb8', header))
            pubs[1].publish(msg_utils.pinhole_to_camera_info(f['camera'], header))
            pubs[2].publish(msg_utils.matrix_to_pose_stamped(f['pose'], stamp_ns=f['stamp'], frame_id='map'))
        deadline = time.monotonic() + 120
        refined = lambda: {msg_utils.stamp_to_ns(m.header.stamp) for m in depths}  # noqa: E731
        while len(refined()) < len(keyframes) and time.monotonic() < deadline:
            time.sleep(0.1)
        bad = dict(node.bad.counts)
    finally:
        executor.shutdown(timeout_sec=5)
        for n in (node, feeder):
            if n is not None:
                n.destroy_node()
        rclpy.try_shutdown()
        if thread is not None:
            thread.join(timeout=10)
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
