# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Render a synthetic drone flight into a ROS 2 bag with ground truth (``ibr bag synth``).

Topics (header stamps equal the bag log times; frame ``camera_optical``, poses in ``map``, ENU):

* ``/camera/image_raw/compressed`` ``sensor_msgs/CompressedImage``: JPEG, RGB;
* ``/camera/camera_info`` ``sensor_msgs/CameraInfo``: exact intrinsics, no distortion;
* ``/camera/pose`` ``geometry_msgs/PoseStamped``: exact camera-to-map pose of the optical frame;
* ``/ground_truth/depth`` ``sensor_msgs/Image`` ``32FC1``: z-depth in metres, +inf = sky (REP-118),
  every ``depth_every``-th frame. With ``depth_mantissa_bits < 23`` the float32 mantissa is rounded
  to that many bits (relative error <= 2**-(bits+1), e.g. 4.9e-4 for 10 bits), which lets the
  MCAP chunk compression shrink it; 23 keeps the renderer's values exactly;
* ``/ground_truth/sky_mask`` ``sensor_msgs/Image`` ``mono8``: 255 = sky, 0 = not sky;
* ``/ground_truth/labels`` ``sensor_msgs/Image`` ``mono8``: class ids of
  :data:`ibr_ros.core.synth.LABEL_NAMES`.

Bags are deterministic: the same arguments give a byte-identical bag (stamps start at a fixed epoch).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

import msg_utils
from ibr_ros.bag.writer import BagWriter
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.synth import (
    LABEL_NAMES,
    SceneConfig,
    SynthFrame,
    TrajectoryKind,
    build_scene,
    flight_camera,
    render_flight,
    render_view,
)
from ibr_ros.errors import UserError

__all__ = [
    'START_NS',
    'TOPICS',
    'GroundTruthRenderer',
    'SynthBagResult',
    'load_sidecar',
    'quantize_depth',
    'write_synth_bag',
]

TOPICS = {
    'image': '/camera/image_raw/compressed',
    'camera_info': '/camera/camera_info',
    'pose': '/camera/pose',
    'depth': '/ground_truth/depth',
    'sky_mask': '/ground_truth/sky_mask',
    'labels': '/ground_truth/labels',
}
FRAME_ID = 'camera_optical'
WORLD_FRAME = 'map'
START_NS = 1_767_225_600 * 1_000_000_000  # 2026-01-01T00:00:00Z


@dataclass(frozen=True)
class SynthBagResult:
    """What was written."""

    path: Path
    frames: int
    depth_frames: int
    max_depth_rel_error: float


def quantize_depth(depth: np.ndarray, mantissa_bits: int) -> np.ndarray:
    """Round float32 depths to ``mantissa_bits`` mantissa bits (round half to even); inf/NaN/0 kept.

    Relative error is at most ``2**-(mantissa_bits + 1)``.
    """
    if not 1 <= mantissa_bits <= 23:
        raise ValueError(f'mantissa_bits must be in 1..23, got {mantissa_bits}')
    d = np.ascontiguousarray(depth, dtype=np.float32)
    if mantissa_bits == 23:
        return d.copy()
    drop = np.uint32(23 - mantissa_bits)
    bits = d.view(np.uint32)
    half = np.uint32(1) << (drop - np.uint32(1))
    lsb = (bits >> drop) & np.uint32(1)
    rounded = ((bits + half - np.uint32(1) + lsb) >> drop) << drop
    out = rounded.view(np.float32)
    keep = ~np.isfinite(d)
    out[keep] = d[keep]
    return out


def write_synth_bag(
    out: Path,
    *,
    seed: int = 0,
    trajectory: TrajectoryKind = 'orbit',
    duration_s: float = 20.0,
    fps: float = 12.0,
    size: tuple[int, int] = (640, 360),
    hfov_deg: float = 70.0,
    pitch_range_deg: tuple[float, float] = (-60.0, -15.0),
    jpeg_quality: int = 90,
    depth_every: int = 1,
    depth_mantissa_bits: int = 23,
    labels: bool = True,
    overwrite: bool = False,
    scene: SceneConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SynthBagResult:
    """Render a flight and write it to the bag folder ``out`` (topics in the module docstring).

    ``pitch_range_deg`` bounds the camera pitch (degrees, negative = looking down; see
    :func:`ibr_ros.core.synth.trajectory.make_trajectory`).
    """
    if depth_every < 1:
        raise ValueError(f'depth_every must be >= 1, got {depth_every}')
    cfg = scene if scene is not None else SceneConfig(seed=seed)
    camera = flight_camera(size, hfov_deg)
    period_ns = round(1e9 / fps)
    frames = depth_frames = 0
    max_err = 0.0
    with BagWriter(Path(out), overwrite=overwrite) as bag:
        for i, (sample, frame) in enumerate(
            render_flight(
                cfg,
                trajectory,
                duration_s,
                fps,
                size,
                hfov_deg,
                progress=progress,
                pitch_range_deg=pitch_range_deg,
            )
        ):
            stamp = START_NS + i * period_ns
            header = msg_utils.make_header(stamp, FRAME_ID, flavor='rosbags')
            bag.write(
                TOPICS['image'],
                msg_utils.numpy_to_compressed_image(
                    frame.rgb, 'jpeg', encoding='rgb8', quality=jpeg_quality, header=header, flavor='rosbags'
                ),
                stamp,
            )
            bag.write(
                TOPICS['camera_info'],
                msg_utils.pinhole_to_camera_info(camera, header, flavor='rosbags'),
                stamp,
            )
            bag.write(
                TOPICS['pose'],
                msg_utils.matrix_to_pose_stamped(
                    sample.t_wc, stamp_ns=stamp, frame_id=WORLD_FRAME, flavor='rosbags'
                ),
                stamp,
            )
            if i % depth_every == 0:
                depth = quantize_depth(frame.depth, depth_mantissa_bits)
                finite = np.isfinite(frame.depth) & (frame.depth > 0)
                if finite.any():
                    rel = np.abs(depth[finite] - frame.depth[finite]) / frame.depth[finite]
                    max_err = max(max_err, float(rel.max()))
                bag.write(
                    TOPICS['depth'], msg_utils.numpy_to_image(depth, '32FC1', header, flavor='rosbags'), stamp
                )
                sky = np.where(frame.sky, np.uint8(255), np.uint8(0))
                bag.write(
                    TOPICS['sky_mask'],
                    msg_utils.numpy_to_image(sky, 'mono8', header, flavor='rosbags'),
                    stamp,
                )
                if labels:
                    bag.write(
                        TOPICS['labels'],
                        msg_utils.numpy_to_image(frame.label, 'mono8', header, flavor='rosbags'),
                        stamp,
                    )
                depth_frames += 1
            frames += 1
    _write_sidecar(
        Path(out),
        cfg,
        trajectory,
        duration_s,
        fps,
        size,
        hfov_deg,
        pitch_range_deg,
        depth_every,
        depth_mantissa_bits,
    )
    return SynthBagResult(Path(out), frames, depth_frames, max_err)


def _write_sidecar(out: Path, cfg: SceneConfig, *args: object) -> None:
    """``synth.json`` beside the MCAP: the scene and flight parameters, for reproduction."""
    names = (
        'trajectory',
        'duration_s',
        'fps',
        'size',
        'hfov_deg',
        'pitch_range_deg',
        'depth_every',
        'depth_mantissa_bits',
    )
    doc = {'scene': asdict(cfg), 'flight': dict(zip(names, args, strict=True)), 'labels': LABEL_NAMES}
    tmp = out / '.synth.json.tmp'
    tmp.write_text(json.dumps(doc, indent=2, sort_keys=True, default=list) + '\n')
    tmp.rename(out / 'synth.json')


def load_sidecar(bag: Path) -> tuple[SceneConfig, dict[str, object]]:
    """Scene configuration and flight parameters recorded in ``<bag>/synth.json``."""
    path = Path(bag) / 'synth.json'
    try:
        doc = json.loads(path.read_text())
        fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in doc['scene'].items()}
        return SceneConfig(**fields), dict(doc['flight'])
    except FileNotFoundError as exc:
        raise UserError(f'{bag}: no synth.json: not a synthetic bag made by `ibr bag synth`') from exc
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f'{path}: unreadable synth.json ({exc})') from exc


class GroundTruthRenderer:
    """Exact ground truth of a synthetic bag for any pose (re-renders its scene deterministically)."""

    def __init__(self, bag: Path) -> None:
        self.config, self.flight = load_sidecar(bag)
        self.scene = build_scene(self.config)

    @property
    def hfov_deg(self) -> float:
        """The flight camera's horizontal field of view (deg) as recorded; 70 when not recorded."""
        return float(str(self.flight.get('hfov_deg', 70.0)))

    def render(self, t_wc: np.ndarray, camera: PinholeCamera) -> SynthFrame:
        """Image, z-depth (+inf sky), sky mask and labels seen from ``t_wc`` with ``camera``."""
        return render_view(self.scene, camera, t_wc)
