# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""A small synthetic model as an ``ibr process`` output bag: keyframes of the synthetic town's orbit
with exact depth, for the web viewer's test and benchmark."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import msg_utils
from ibr_ros.bag import BagWriter
from ibr_ros.core.render import SourceView
from ibr_ros.core.synth import (
    SceneConfig,
    build_scene,
    flight_camera,
    make_trajectory,
    render_view,
    safe_altitude_range,
)
from ibr_ros.jobs.process.output import MODEL_QOS, OUT_TOPICS

#: Frames of the 3 s orbit (as bench_render) used as keyframes.
FRAMES = (24, 27, 30, 33, 36)


def model_views(size: tuple[int, int] = (640, 360)) -> list[SourceView]:
    """The keyframes (``size`` = width, height), oldest first, named and stamped as in the bag."""
    cfg = SceneConfig(seed=3)
    scene = build_scene(cfg)
    camera = flight_camera(size)
    samples = make_trajectory('orbit', duration_s=3.0, seed=cfg.seed, altitude_range=safe_altitude_range(cfg))
    views = []
    for k, i in enumerate(FRAMES):
        frame = render_view(scene, camera, samples[i].t_wc)
        stamp = 1_000_000_000 + k * 100_000_000
        views.append(SourceView(frame.rgb, frame.depth.astype(np.float32), camera, samples[i].t_wc,
                                name=str(stamp), stamp=stamp * 1e-9))  # fmt: skip
    return views


def write_model_bag(path: Path, views: list[SourceView]) -> Path:
    """``views`` as the model topics of an output bag at ``path`` (keyframes/* with their QoS)."""
    with BagWriter(path) as writer:
        for key in ('image', 'camera_info', 'pose', 'depth'):
            writer.add_topic(OUT_TOPICS[key][0], OUT_TOPICS[key][1], MODEL_QOS)
        for v in views:
            stamp = int(v.name)
            header = msg_utils.make_header(stamp, 'camera_optical', flavor='rosbags')
            msgs = {
                'image': msg_utils.numpy_to_image(v.rgb, 'rgb8', header, flavor='rosbags'),
                'camera_info': msg_utils.pinhole_to_camera_info(v.camera, header, flavor='rosbags'),
                'pose': msg_utils.matrix_to_pose_stamped(
                    v.t_wc, stamp_ns=stamp, frame_id='map', flavor='rosbags'
                ),
                'depth': msg_utils.depth_m_to_image(v.depth, header, flavor='rosbags'),
            }
            for key, msg in msgs.items():
                writer.write(OUT_TOPICS[key][0], msg, stamp)
    return path
