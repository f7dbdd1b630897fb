"""``ibr process``: a whole bag through the node graph's pipeline in one process, into an output bag.

The same core code as the nodes, run synchronously in bag-time order (deterministic):

1. subsample: camera image (``Image`` or ``CompressedImage``), ``CameraInfo`` and pose
   (``PoseStamped`` or ``Odometry``) matched by identical header stamps, then blur score +
   :class:`~ibr_ros.core.keyframes.KeyframeSelector` with the frame_subsampler's parameters, frame
   by frame as live; or, with its ``target_keyframes`` > 0 (``ProcessOptions.target_keyframes``
   overrides it) on a bag with poses, :func:`~ibr_ros.core.keyframes.select_keyframes` over the
   whole flight: the same blur scores, ``KeyframeConfig`` and ``scene_depth_m``, with
   ``baseline_ratio`` and ``min_baseline_m`` scaled by the common factor that gives about
   ``target_keyframes`` (the frame_subsampler's ``expected_path_m`` is not used: the flight is
   known). Two passes over the bag: stamps, poses and blur scores of every frame, then the chosen
   frames' images (no other image decoded); the summary's ``keyframe_selection`` gives the method,
   and for a target the count and the scale;
2. MVS + refine: once the whole flight is known, every keyframe (oldest first) is refined once
   with the neighbours and depth range :class:`~ibr_ros.core.schedule.RefineScheduler` gives it
   (the depth_refiner's policy at the end of a flight), by
   :func:`~ibr_ros.core.mvs.compute_depth_maps` and
   :meth:`~ibr_ros.core.refine.DepthRefiner.refine_from_mvs`;
3. render: :class:`~ibr_ros.core.render.NovelViewRenderer` (the view_renderer's parameters) at
   ``views`` poses along the keyframe path (:func:`ibr_ros.jobs.demo.interpolate_path`).

SfM mode (the depth_refiner's ``sfm_mode``; ``ProcessOptions.sfm`` forces it): a bag without a
pose topic (``sfm_mode`` ``auto`` or ``always``; ``off`` refuses it), or any bag with ``sfm``
(its poses are then ignored). Keyframes are chosen without poses as the frame_subsampler does
after ``pose_timeout_s`` (which must be > 0): the sharpest unblurred frame of every
``poseless_interval_s`` window (:class:`~ibr_ros.core.keyframes.IntervalSelector`). With
``sfm_mode`` ``always`` on a bag with poses the keyframes are chosen by pose (as live) and their
poses ignored. Then all keyframes (at least ``sfm_min_keyframes``) are registered together by ONE
:meth:`~ibr_ros.core.sfm_session.SfmSession.update` (images downscaled to ``sfm_max_side``; no
incremental updates offline), with GPS positions from the bag's ``NavSatFix`` topic when there is
one (converted to ENU metres with the first usable fix as origin and interpolated linearly to the
keyframe stamps, at most :data:`GPS_MAX_GAP_S` from a fix, as ``ibr register`` does). Frame of
the result: ENU metres (frame_id ``map``) when the model could be aligned to >= 3 GPS positions,
else the documented ``sfm`` frame (frame_id ``sfm``; unit = the first keyframe baseline, or metres
with ``sfm_scale`` + ``sfm_scale_m``; without a scale ``depth_range`` and ``scene_depth_m`` are
ignored, like the node). Unregistered keyframes are dropped (logged, and listed in the summary).
The registered keyframes get SfM's refined shared camera (not the bag's CameraInfo, possibly an
initial guess) and are undistorted with it (:func:`~ibr_ros.core.undistort.undistort_image`,
valid pixels only, same size): MVS needs undistorted pinholes. From there on as for a posed bag.

Parameters: ``config/<node>.yaml`` of the three nodes, overridden by a ROS 2 params file
(sections ``/**``, ``<node>`` or ``/<ns>/<node>``), so live and offline runs agree.

Output folder: ``bag/`` (ROS 2 mcap bag, written atomically) with the graph's topics and types:
``/keyframes/image`` (rgb8; undistorted in SfM mode), ``/keyframes/camera_info``,
``/keyframes/pose`` (the bag's poses, or SfM's in frame ``map``/``sfm``), ``/keyframes/depth``
(32FC1 metres or ``sfm`` units, NaN unknown, REP-118; sky at 2 x the largest MVS depth, Eq. 14),
``/keyframes/depth/camera_info``, ``/novel_view/query`` (PoseStamped) and, for answered queries,
``/novel_view/image`` (rgb8) + ``/novel_view/camera_info`` with the query's stamp (the midpoint of
its two keyframes' stamps); log time = header stamp. ``previews/*.png``;
``summary.json`` and ``summary.md`` (counts, timings, seconds per keyframe, the SfM statistics
and, for a synthetic bag with ``synth.json``, depth and rephotography errors against the exact
ground truth; in SfM mode only when the bag has poses, after a similarity fit of the SfM camera
centres to them: depths are scaled by its scale, novel view poses moved by it).
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

import msg_utils
from ibr_ros.bag import BagReader, BagWriter, OfferedQos, detect_topics, open_bag
from ibr_ros.bag.detect import COMPRESSED_IMAGE, ODOMETRY, POSE_STAMPED
from ibr_ros.core.camera import CameraError, PinholeCamera
from ibr_ros.core.geometry import GeometryError
from ibr_ros.core.keyframes import (
    IntervalSelector,
    KeyframeConfig,
    KeyframeSelector,
    TargetSelection,
    blur_score,
    select_keyframes_for_target,
)
from ibr_ros.core.mono import MonoModelError
from ibr_ros.core.mvs import MvsOptions, MvsView, compute_depth_maps
from ibr_ros.core.refine import DepthRefiner, RefineError, RefinerConfig
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView
from ibr_ros.core.schedule import RefineScheduler, ScheduleConfig, parse_depth_range
from ibr_ros.core.sfm import SfmError, SfmOptions
from ibr_ros.core.sfm_session import ScaleHint, SfmSession, SfmUpdate
from ibr_ros.core.stamps import StampAssembler
from ibr_ros.core.undistort import undistort_image
from ibr_ros.errors import UserError
from ibr_ros.jobs.demo import interpolate_path
from ibr_ros.jobs.eval_depth import colour_depth, write_atomic
from ibr_ros.jobs.register_bag import fixes_to_enu
from ibr_ros.models import mono_spec, sky_spec

__all__ = [
    'GPS_MAX_GAP_S',
    'NODES',
    'OUT_TOPICS',
    'Keyframe',
    'NovelView',
    'ProcessOptions',
    'load_params',
    'process_bag',
]

LOG = logging.getLogger(__name__)

#: The nodes whose parameters ``ibr process`` reads.
NODES = ('frame_subsampler', 'depth_refiner', 'view_renderer')
#: Output topics (fully qualified: what the graph's relative names resolve to in the root namespace).
#: QoS the graph's publishers offer (ibr_ros.nodes.common.model_qos / reliable_qos), recorded per topic
#: so that bag_player and ros2 bag play offer it again (a late-joining renderer gets the whole model).
MODEL_QOS = OfferedQos('reliable', 'transient_local', depth=1000)
REPLY_QOS = OfferedQos('reliable', 'volatile', depth=10)

OUT_TOPICS = {
    'image': ('/keyframes/image', 'sensor_msgs/msg/Image'),
    'camera_info': ('/keyframes/camera_info', 'sensor_msgs/msg/CameraInfo'),
    'pose': ('/keyframes/pose', 'geometry_msgs/msg/PoseStamped'),
    'depth': ('/keyframes/depth', 'sensor_msgs/msg/Image'),
    'depth_info': ('/keyframes/depth/camera_info', 'sensor_msgs/msg/CameraInfo'),
    'query': ('/novel_view/query', 'geometry_msgs/msg/PoseStamped'),
    'view': ('/novel_view/image', 'sensor_msgs/msg/Image'),
    'view_info': ('/novel_view/camera_info', 'sensor_msgs/msg/CameraInfo'),
}
BAD_MESSAGE = (msg_utils.MessageError, CameraError, GeometryError, ValueError)
#: GPS positions are interpolated to keyframe stamps at most this far from a fix (s; ``ibr register``'s).
GPS_MAX_GAP_S = 2.0
SFM_MODES = ('auto', 'always', 'off')
SFM_SCALES = ('none', 'baseline', 'altitude', 'depth')
#: ``progress(stage, done, total)``; stages ``frames``, ``reread`` (target_keyframes: the second pass),
#: ``sfm``, ``keyframes``, ``views``, ``previews``.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ProcessOptions:
    """What ``ibr process`` does besides the node parameters.

    ``image_topic``/``info_topic``/``pose_topic``/``navsat_topic``: None = detect by type.
    ``sfm``: SfM mode even for a bag with poses (they are ignored: keyframes and poses as for a bag
    without). ``gps``: use the bag's NavSatFix positions in SfM mode. ``params``: ROS 2 params
    file overriding ``config/<node>.yaml``. ``views``: novel views along the keyframe path.
    ``width``/``height``/``hfov_deg``: output intrinsics of the novel views (None = the
    view_renderer's parameters; those 0 = the last keyframe's). ``max_keyframes``: stop reading
    the bag after this many keyframes (with a target: keep the first this many of the chosen ones).
    ``target_keyframes``: about this many keyframes over the whole flight (None = the
    frame_subsampler's parameter; 0 = off). ``threads``: numba/OpenCV threads (None = all cores).
    ``overwrite``: replace an existing ``OUT/bag``.
    """

    image_topic: str | None = None
    info_topic: str | None = None
    pose_topic: str | None = None
    navsat_topic: str | None = None
    sfm: bool = False
    gps: bool = True
    params: Path | None = None
    views: int = 16
    width: int | None = None
    height: int | None = None
    hfov_deg: float | None = None
    max_keyframes: int | None = None
    target_keyframes: int | None = None
    threads: int | None = None
    overwrite: bool = False


# ------------------------------------------------------------------------------------ parameters


def _section_targets(key: str) -> str | None:
    """The node a params-file section applies to (``'*'`` for wildcards), from its key."""
    key = str(key).strip()
    if key in ('/**', '**'):
        return '*'
    name = key.rstrip('/').rsplit('/', 1)[-1]
    return name or None


def _read_params_file(path: Path) -> list[tuple[str, dict[str, object]]]:
    """``[(target, {name: value})]`` of a ROS 2 params file, in file order."""
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    except OSError as exc:
        raise UserError(f'{path}: cannot read params file: {exc.strerror or exc}') from exc
    except yaml.YAMLError as exc:
        raise UserError(f'{path}: not a YAML params file: {exc}') from exc
    if not isinstance(doc, dict):
        raise UserError(f'{path}: a params file maps node names to {{ros__parameters: ...}}')
    out = []
    for key, section in doc.items():
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise UserError(f'{path}: section {key!r} has no ros__parameters mapping')
        if (target := _section_targets(key)) is not None:
            out.append((target, params))
    return out


def _coerce(path: Path, node: str, name: str, value: object, default: object) -> object:
    """``value`` as the type of the parameter's default (an integer is accepted for a float)."""
    kinds = {bool: 'true or false', float: 'a number', int: 'an integer', list: 'a list'}
    kind = kinds.get(type(default), 'a string')
    bad = UserError(f'{path}: {node}.{name} must be {kind} (default {default!r}), got {value!r}')
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad
        return float(value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if isinstance(default, list):
        if not isinstance(value, list):
            raise bad
        return value
    if not isinstance(value, type(default)):
        raise bad
    return value


def load_params(params_file: Path | None = None, config: Path | None = None) -> dict[str, dict[str, object]]:
    """Parameters of :data:`NODES`: ``config/<node>.yaml`` (``config`` folder, default the graph's),
    then the sections of ``params_file`` that apply to each node (wildcards first, in file order).

    Raises:
        UserError: Unreadable file, unknown parameter of a named node, a value of the wrong type.

    """
    from ibr_ros.graph import config_dir

    folder = Path(config) if config is not None else config_dir()
    params: dict[str, dict[str, object]] = {}
    for node in NODES:
        params[node] = {}
        for target, values in _read_params_file(folder / f'{node}.yaml'):
            if target in ('*', node):
                params[node].update(values)
    if params_file is None:
        return params
    sections = _read_params_file(Path(params_file))
    for target, values in sorted(sections, key=lambda s: s[0] != '*'):  # stable: wildcards first
        nodes = NODES if target == '*' else (target,) if target in NODES else ()
        if not nodes:
            LOG.info(
                '%s: section for %s ignored (ibr process runs %s)', params_file, target, ', '.join(NODES)
            )
            continue
        for name, value in values.items():
            known = [n for n in nodes if name in params[n]]
            if not known:
                where = nodes[0] if len(nodes) == 1 else 'any of ' + ', '.join(nodes)
                raise UserError(f'{params_file}: {name!r} is not a parameter of {where}')
            for n in known:
                params[n][name] = _coerce(Path(params_file), n, name, value, params[n][name])
    return params


@dataclass(frozen=True)
class _Configs:
    keyframes: KeyframeConfig
    subsampler_scene_depth: float
    target_keyframes: int  # 0 = off (the streaming selector)
    max_pending: int
    schedule: ScheduleConfig
    flush: bool
    refiner: RefinerConfig
    render: RenderConfig
    out_size: tuple[int, int, float]  # width, height, hfov_deg; 0 = the last keyframe's
    min_valid: float
    view_frame: str
    pose_timeout_s: float
    poseless_interval_s: float
    sfm_mode: str
    sfm_min_keyframes: int
    sfm_max_side: int
    sfm_scale: ScaleHint | None


def _configs(params: dict[str, dict[str, object]], o: ProcessOptions) -> _Configs:
    """The core configurations, mapped from the node parameters exactly as the nodes map them."""
    fs, dr, vr = (params[n] for n in NODES)
    try:
        kf = KeyframeConfig(
            **{k: float(fs[k]) for k in ('baseline_ratio', 'min_baseline_m', 'max_rotation_deg')},
            max_interval_s=float(fs['max_interval_s']),
            min_interval_s=float(fs['min_interval_s']),
            blur_ratio=float(fs['blur_ratio']),
        )
        mvs = MvsOptions(max_neighbours=int(dr['max_neighbours']))
        schedule = ScheduleConfig(
            min_neighbours=int(dr['min_neighbours']),
            depth_range=parse_depth_range(dr['depth_range']),  # type: ignore[arg-type]
            scene_depth_m=float(dr['scene_depth_m']),
            near_ratio=float(dr['near_ratio']),
            far_ratio=float(dr['far_ratio']),
            mvs=mvs,
        )
        sfm_mode, sfm_scale, sfm_scale_m = str(dr['sfm_mode']), str(dr['sfm_scale']), float(dr['sfm_scale_m'])
        if sfm_mode not in SFM_MODES:
            raise UserError(
                f"depth_refiner parameter sfm_mode must be 'auto', 'always' or 'off', got {sfm_mode!r}"
            )
        if sfm_scale not in SFM_SCALES:
            raise UserError(
                "depth_refiner parameter sfm_scale must be 'none', 'baseline', 'altitude' or 'depth', "
                f'got {sfm_scale!r}'
            )
        if sfm_scale != 'none' and sfm_scale_m <= 0:
            raise UserError(
                f'depth_refiner parameter sfm_scale_m must be > 0 with sfm_scale {sfm_scale!r}, '
                f'got {sfm_scale_m}'
            )
        sfm = {
            'pose_timeout_s': float(fs['pose_timeout_s']),
            'poseless_interval_s': float(fs['poseless_interval_s']),
            'sfm_mode': sfm_mode,
            'sfm_min_keyframes': int(dr['sfm_min_keyframes']),
            'sfm_max_side': int(dr['sfm_max_side']),
            'sfm_scale': ScaleHint(sfm_scale, sfm_scale_m) if sfm_scale != 'none' else None,  # type: ignore[arg-type]
        }
        if sfm['poseless_interval_s'] <= 0 or sfm['sfm_min_keyframes'] < 3 or sfm['sfm_max_side'] < 0:
            raise UserError(
                'need frame_subsampler poseless_interval_s > 0, depth_refiner sfm_min_keyframes >= 3 and '
                f'sfm_max_side >= 0, got {sfm["poseless_interval_s"]}, {sfm["sfm_min_keyframes"]}, '
                f'{sfm["sfm_max_side"]}'
            )
        mono, sky = str(dr['mono']), str(dr['sky'])
        if mono not in ('plane', 'onnx'):
            raise UserError(f"depth_refiner parameter mono must be 'plane' or 'onnx', got {mono!r}")
        if sky not in ('fallback', 'onnx', 'none'):
            raise UserError(f"depth_refiner parameter sky must be 'fallback', 'onnx' or 'none', got {sky!r}")
        refiner = RefinerConfig(
            mono=mono,  # type: ignore[arg-type]
            mono_model=mono_spec(str(dr['mono_model']), str(dr['mono_preset'])) if mono == 'onnx' else None,
            sky=sky,  # type: ignore[arg-type]
            sky_model=sky_spec(str(dr['sky_model']), str(dr['sky_preset'])) if sky == 'onnx' else None,
            mvs=mvs,
        )
        render = RenderConfig(
            renderer=str(vr['renderer']),  # type: ignore[arg-type]
            blend=str(vr['blend']),  # type: ignore[arg-type]
            n_views=int(vr['n_views']),
            n_segments=int(vr['n_segments']),
            max_axis_angle_deg=float(vr['max_axis_angle_deg']),
            far_factor=float(vr['far_factor']),
            max_cached_views=int(vr['max_cached_views']),
        )
    except (ValueError, TypeError, KeyError) as exc:
        raise UserError(f'bad node parameters: {exc}') from exc
    size = (
        int(vr['width']) if o.width is None else o.width,
        int(vr['height']) if o.height is None else o.height,
        float(vr['hfov_deg']) if o.hfov_deg is None else o.hfov_deg,
    )
    if size[0] < 0 or size[1] < 0 or not 0 <= size[2] < 180:
        raise UserError(f'novel view size {size[0]}x{size[1]}, hfov {size[2]} deg: need >= 0 and hfov < 180')
    target = int(fs['target_keyframes']) if o.target_keyframes is None else o.target_keyframes
    if target < 0:
        raise UserError(f'target_keyframes (--target-keyframes) must be >= 0 (0 = off), got {target}')
    return _Configs(
        keyframes=kf,
        subsampler_scene_depth=float(fs['scene_depth_m']),
        target_keyframes=target,
        max_pending=int(fs['max_pending']),
        schedule=schedule,
        flush=float(dr['flush_after_s']) > 0,
        refiner=refiner,
        render=render,
        out_size=size,
        min_valid=float(vr['min_valid_fraction']),
        view_frame=str(vr['frame_id']),
        **sfm,  # type: ignore[arg-type]
    )


# ------------------------------------------------------------------------------------ subsample


@dataclass
class Keyframe:
    """A selected keyframe: ``stamp`` (ns), rgb8 image, camera, camera-to-world pose, frames, reason.

    In SfM mode ``t_wc`` is NaN until registered, then SfM's (``pose_frame`` ``map`` or ``sfm``);
    ``bag_t_wc`` keeps the bag's pose at that stamp, if any (ground truth of a synthetic bag).
    """

    stamp: int
    rgb: np.ndarray
    camera: PinholeCamera
    t_wc: np.ndarray
    camera_frame: str
    pose_frame: str
    reason: str
    depth: np.ndarray | None = None  # refined, float32 metres (NaN unknown)
    neighbours: tuple[int, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)
    bag_t_wc: np.ndarray | None = None


@dataclass
class _Subsampled:
    keyframes: list[Keyframe]
    counts: Counter
    bad: Counter
    decisions: Counter
    topics: dict[str, str | None]
    sfm_why: str | None = None  # why SfM mode (None: the bag's poses are used)
    poseless: bool = False  # keyframes chosen without poses (IntervalSelector)
    fixes: list[msg_utils.GeoFix] = field(default_factory=list)
    stopped: bool = False  # at max_keyframes
    selection: dict[str, object] = field(default_factory=dict)  # how the keyframes were chosen


@dataclass
class _Frame:
    """A complete frame: image (None when not decoded: not wanted), camera, its frame id, pose."""

    stamp: int
    image: np.ndarray | None
    camera: PinholeCamera
    camera_frame: str
    pose: tuple[np.ndarray, str] | None  # None without poses (SfM mode)


@dataclass
class _Reading:
    """What one pass of :func:`_frames` counted and collected (``image_ok``: per image message, in bag
    order, whether it decoded).
    """

    counts: Counter = field(default_factory=Counter)
    bad: Counter = field(default_factory=Counter)
    fixes: list[msg_utils.GeoFix] = field(default_factory=list)
    bag_poses: dict[int, np.ndarray] = field(default_factory=dict)
    image_ok: list[bool] = field(default_factory=list)


def _frames(
    reader: BagReader,
    topics: dict[str, str | None],
    cfg: _Configs,
    poseless: bool,
    reading: _Reading,
    progress: Progress | None,
    *,
    stage: str = 'frames',
    wanted: set[int] | None = None,
    decoded: list[bool] | None = None,
) -> Iterator[_Frame]:
    """The bag's complete frames in bag-time order: image, camera_info and (unless ``poseless``) pose
    with identical header stamps, counted into ``reading``.

    ``wanted`` (a second pass): yield only the frames with these stamps and decode only their images;
    ``decoded`` (the first pass's ``image_ok``) says which other image messages to put undecoded, so
    that the frames are assembled exactly as in the first pass.
    """
    counts, bad = reading.counts, reading.bad

    def incomplete(detail: str) -> None:
        bad['incomplete'] += 1
        LOG.debug(detail)

    fields = ('image', 'camera_info') if poseless else ('image', 'camera_info', 'pose')
    assembler = StampAssembler(fields, cfg.max_pending, incomplete, supersede=True)
    compressed = topics['image_type'] == COMPRESSED_IMAGE
    to_pose = (
        msg_utils.odometry_to_matrix if topics['pose_type'] == ODOMETRY else msg_utils.pose_stamped_to_matrix
    )
    n_images = reader.topics[str(topics['image'])].count
    role = {str(topics[k]): k for k in ('image', 'camera_info', 'pose', 'navsat') if topics[k] is not None}
    for m in reader.messages(list(role)):
        field = role[m.topic]
        counts[field] += 1
        if field == 'image' and progress is not None:
            progress(stage, counts['image'], n_images)
        msg: Any = m.msg
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        try:
            if field == 'image':
                if wanted is not None and stamp not in wanted:
                    ok = decoded is None or (counts['image'] <= len(decoded) and decoded[counts['image'] - 1])
                    if not ok:
                        bad[field] += 1
                        continue
                    value: object = None  # not wanted: assembled as in the first pass, not decoded
                else:
                    rgb = (
                        msg_utils.compressed_image_to_numpy(msg)
                        if compressed
                        else msg_utils.image_to_rgb(msg)
                    )
                    value = np.ascontiguousarray(
                        np.repeat(rgb[..., None], 3, axis=2) if rgb.ndim == 2 else rgb
                    )
                reading.image_ok.append(True)
            elif field == 'camera_info':
                value = (msg.header.frame_id, msg_utils.camera_info_to_pinhole(msg))
            elif field == 'navsat':
                fix = msg_utils.navsatfix_to_fix(msg)
                if fix.status >= 0 and math.isfinite(fix.altitude_m):  # as ibr register
                    reading.fixes.append(fix)
                else:
                    bad['navsat (no fix or altitude)'] += 1
                continue
            else:
                value = (to_pose(msg), msg.header.frame_id or 'map')
        except BAD_MESSAGE as exc:
            bad[field] += 1
            if field == 'image':
                reading.image_ok.append(False)
            LOG.debug('bad %s message at %d ns: %s', field, stamp, exc)
            continue
        if field == 'pose' and poseless:  # ignored, but the ground truth of a synthetic bag
            reading.bag_poses[stamp] = value[0]  # type: ignore[index]
            continue
        if (f := assembler.put(stamp, field, value)) is None or (wanted is not None and stamp not in wanted):
            continue
        image, (camera_frame, camera) = f['image'], f['camera_info']
        if (camera.height, camera.width) != image.shape[:2]:
            bad['camera_info'] += 1
            LOG.debug(
                'CameraInfo %dx%d does not match the image at %d ns', camera.width, camera.height, stamp
            )
            continue
        counts['frames'] += 1
        yield _Frame(stamp, image, camera, camera_frame, None if poseless else f['pose'])


def _select_topics(
    reader: BagReader, o: ProcessOptions, cfg: _Configs
) -> tuple[dict[str, str | None], str | None]:
    """Image, camera_info, pose and NavSatFix topics (given or detected by type) and their types, and
    why SfM mode is used (None: it is not).
    """
    sel = detect_topics(
        reader, image=o.image_topic, camera_info=o.info_topic, pose=o.pose_topic, navsat=o.navsat_topic
    )
    topics = reader.topics
    where = f'{reader.path}: topics: ' + ', '.join(f'{t.name} ({t.msgtype})' for t in topics.values())
    if sel.image is None:
        raise UserError(
            f'no camera image topic (sensor_msgs/msg/Image or CompressedImage; --image-topic); {where}'
        )
    if sel.camera_info is None:
        raise UserError(f'no camera_info topic (sensor_msgs/msg/CameraInfo; --info-topic); {where}')
    if sel.pose is not None and sel.pose_type not in (POSE_STAMPED, ODOMETRY):
        raise UserError(
            f'pose topic {sel.pose} is {sel.pose_type}; ibr process reads geometry_msgs/msg/PoseStamped '
            f'or nav_msgs/msg/Odometry; {where}'
        )
    no_pose = 'no pose topic (geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry; --pose-topic)'
    if o.sfm:
        why: str | None = '--sfm'
    elif sel.pose is None and cfg.sfm_mode == 'off':
        raise UserError(
            f'{no_pose} and depth_refiner sfm_mode is off: frames without poses are not refined '
            f'(sfm_mode auto or --sfm registers them with SfM); {where}'
        )
    elif sel.pose is None and cfg.pose_timeout_s <= 0:
        raise UserError(
            f'{no_pose} and frame_subsampler pose_timeout_s is 0: it never selects keyframes without poses '
            f'(set it > 0 or pass --sfm); {where}'
        )
    elif sel.pose is None:
        why = 'no pose topic'
    else:
        why = "depth_refiner sfm_mode 'always'" if cfg.sfm_mode == 'always' else None
    out: dict[str, str | None] = {
        'image': sel.image,
        'camera_info': sel.camera_info,
        'pose': sel.pose,
        'navsat': sel.navsat if why is not None and o.gps else None,
        'image_type': topics[sel.image].msgtype,
        'pose_type': None if sel.pose is None else str(sel.pose_type),
    }
    return out, why


def _subsample(bag: Path, cfg: _Configs, o: ProcessOptions, progress: Progress | None) -> _Subsampled:
    """The frame_subsampler's decisions over the whole bag, in bag-time order (without poses in SfM
    mode, unless ``sfm_mode`` is ``always`` on a bag with poses); with ``target_keyframes`` and poses,
    :func:`~ibr_ros.core.keyframes.select_keyframes` over the whole flight instead (two passes).
    """
    decisions: Counter = Counter()
    keyframes: list[Keyframe] = []
    reading = _Reading()

    def keep(frame: _Frame, reason: str) -> bool:
        """Append a keyframe; True when ``max_keyframes`` are there."""
        pose = frame.pose
        t_wc, pose_frame = pose if pose is not None and sfm_why is None else (np.full((4, 4), np.nan), '')
        bag_pose = pose[0] if pose is not None else reading.bag_poses.get(frame.stamp)
        camera_frame = frame.camera_frame or 'camera_optical'
        image: np.ndarray = frame.image  # type: ignore[assignment]  # decoded: a wanted frame
        bag_t_wc = bag_pose if sfm_why is not None else None
        keyframes.append(
            Keyframe(
                frame.stamp, image, frame.camera, t_wc, camera_frame, pose_frame, reason, bag_t_wc=bag_t_wc
            )
        )
        return o.max_keyframes is not None and len(keyframes) >= o.max_keyframes

    stopped = False
    with open_bag(bag) as reader:
        topics, sfm_why = _select_topics(reader, o, cfg)
        poseless = topics['pose'] is None or o.sfm
        frames = _frames(reader, topics, cfg, poseless, reading, progress)
        scene_depth = cfg.subsampler_scene_depth or None
        if poseless:
            if cfg.target_keyframes:
                LOG.warning(
                    'target_keyframes %d ignored: keyframes chosen without poses', cfg.target_keyframes
                )
            selection: dict[str, object] = {'method': 'interval', 'interval_s': cfg.poseless_interval_s}
            interval = IntervalSelector(cfg.poseless_interval_s, cfg.keyframes)
            for f in frames:
                for _, chosen in interval.push(f.stamp, blur_score(f.image), f):  # type: ignore[arg-type]
                    stopped = stopped or keep(chosen, 'sharpest of its window')
                if stopped:
                    break
            if not stopped:
                for _, chosen in interval.flush():
                    keep(chosen, 'sharpest of its window')
            decisions.update({'keyframe (sharpest of its window)': len(keyframes), **interval.rejected})
            decisions['not chosen in its window'] = reading.counts['frames'] - sum(decisions.values())
            decisions = +decisions  # drop zero counts
            for k in keyframes:  # poses read after the frame's image
                if k.bag_t_wc is None and k.stamp in reading.bag_poses:
                    k.bag_t_wc = reading.bag_poses[k.stamp]
        elif cfg.target_keyframes:
            # First pass: stamps, poses and blur scores of every frame; the images are not kept.
            seen = [(f.stamp, f.pose[0], blur_score(f.image)) for f in frames]  # type: ignore[index, arg-type]
            t0 = time.perf_counter()
            chosen = select_keyframes_for_target(
                [s for s, _, _ in seen], [p for _, p, _ in seen], [b for _, _, b in seen],
                target=cfg.target_keyframes, scene_depth_m=[scene_depth] * len(seen), config=cfg.keyframes,
            ) if seen else TargetSelection([], 1.0, [])  # fmt: skip
            picked, scale, decided = chosen.indices, chosen.scale, chosen.decisions
            decisions.update(d.reason for d in decided)
            reasons = {seen[i][0]: decided[i].reason for i in picked}
            if o.max_keyframes is not None and len(picked) > o.max_keyframes:
                picked, stopped = picked[: o.max_keyframes], True
            selection = {
                'method': 'select_keyframes',
                'target': cfg.target_keyframes,
                'frames': len(seen),
                'selected': len(reasons),
                'scale': scale,
                'baseline_ratio': cfg.keyframes.baseline_ratio * scale,
                'min_baseline_m': cfg.keyframes.min_baseline_m * scale,
                'scene_depth_m': scene_depth,
                'seconds': time.perf_counter() - t0,
            }
            # Second pass: the chosen frames' images (the others are not decoded).
            wanted = {seen[i][0] for i in picked}
            again = _frames(
                reader, topics, cfg, poseless, _Reading(), progress,
                stage='reread', wanted=wanted, decoded=reading.image_ok,
            )  # fmt: skip
            for f in again:
                keep(f, reasons[f.stamp])
                if len(keyframes) == len(wanted):
                    break
            if len(keyframes) != len(wanted):
                raise UserError(
                    f'{bag}: changed while read: {len(keyframes)} of {len(wanted)} keyframes found again'
                )
        else:
            selection = {'method': 'streaming'}
            selector = KeyframeSelector(cfg.keyframes)
            for f in frames:
                d = selector.decide(f.stamp, f.pose[0], blur_score(f.image), scene_depth)  # type: ignore[index, arg-type]
                decisions[d.reason] += 1
                if d.keep and keep(f, d.reason):
                    stopped = True
                    break
    counts, bad = reading.counts, reading.bad
    if not keyframes:
        needed = ('image', 'camera_info') if poseless else ('image', 'camera_info', 'pose')
        missing = [k for k in needed if not counts[k]]
        if missing:
            why = f'no {", ".join(missing)} message read'
        elif not counts['frames']:
            why = (
                f'no frame has {" and ".join(needed)} with identical header stamps '
                f'({counts["image"]} images, {counts["camera_info"]} camera_info, {counts["pose"]} poses '
                f'read; bad or incomplete: {dict(bad) or "none"})'
            )
        else:
            why = f'no keyframe among {counts["frames"]} frames ({dict(decisions)})'
        names = ', '.join(str(topics[k]) for k in needed if topics[k] is not None)
        raise UserError(f'{bag}: {why} (topics {names})')
    return _Subsampled(
        keyframes, counts, bad, decisions, topics, sfm_why, poseless, reading.fixes, stopped, selection
    )


# ------------------------------------------------------------------------------------ SfM mode


def _camera_dict(cam: PinholeCamera) -> dict[str, object]:
    return {'width': cam.width, 'height': cam.height, 'fx': cam.fx, 'fy': cam.fy, 'cx': cam.cx, 'cy': cam.cy,
            'd': cam.d.tolist(), 'distortion_model': cam.distortion_model}  # fmt: skip


def _sparse_depth(u: SfmUpdate, stamps: list[int]) -> float | None:
    """Median over the registered views of the median depth (world units) of the points each observes."""
    res = u.result
    per_view = []
    for i, s in enumerate(stamps):
        t_wc = u.poses.get(s)
        if res is None or t_wc is None or i >= len(res.observation_ids) or not len(res.observation_ids[i]):
            continue
        z = (u.points[res.observation_ids[i]] - t_wc[:3, 3]) @ t_wc[:3, 2]
        if (z := z[z > 0]).size:
            per_view.append(float(np.median(z)))
    return float(np.median(per_view)) if per_view else None


def _register(
    sub: _Subsampled, cfg: _Configs, threads: int | None, progress: Progress | None
) -> tuple[list[Keyframe], _Configs, dict[str, object]]:
    """SfM mode: register all keyframes with ONE :meth:`SfmSession.update`; the registered keyframes
    (undistorted, with SfM's camera and pose), the configurations to refine them with, and the stats.
    """
    keyframes, n = sub.keyframes, len(sub.keyframes)
    if n < cfg.sfm_min_keyframes:
        raise UserError(
            f'SfM mode ({sub.sfm_why}): {n} keyframes, the depth_refiner registers at least '
            f'sfm_min_keyframes = {cfg.sfm_min_keyframes} (a longer bag, a smaller poseless_interval_s or a '
            'larger --max-keyframes)'
        )
    t0 = time.perf_counter()
    prior = keyframes[0].camera  # the bag's CameraInfo: SfM's initial intrinsics
    gps, origin = fixes_to_enu(sub.fixes, np.array([k.stamp for k in keyframes], np.int64), GPS_MAX_GAP_S)
    session = SfmSession(
        options=SfmOptions(num_threads=threads) if threads is not None else None,
        scale_hint=cfg.sfm_scale,
        max_side=cfg.sfm_max_side,
        redefine=False,
    )
    dropped: dict[int, str] = {}
    for i, k in enumerate(keyframes):
        g = gps[i] if gps is not None and np.all(np.isfinite(gps[i])) else None
        try:
            session.add(k.stamp, k.rgb, k.camera, g)
        except SfmError as exc:
            dropped[k.stamp] = f'not registered: {exc}'
    if progress is not None:
        progress('sfm', 0, 1)
    u = session.update()
    if progress is not None:
        progress('sfm', 1, 1)
    if not u.accepted or u.camera is None:
        raise UserError(f'SfM mode ({sub.sfm_why}): registration of {n} keyframes failed: {u.reason}')
    frame_id = 'map' if u.frame == 'enu' else 'sfm'
    kept: list[Keyframe] = []
    for k in keyframes:
        t_wc = u.poses.get(k.stamp)
        if k.stamp not in dropped and t_wc is None:
            dropped[k.stamp] = 'not registered by SfM (too few matches with the registered keyframes)'
        if k.stamp in dropped:
            LOG.warning('keyframe %d ns dropped: %s', k.stamp, dropped[k.stamp])
            continue
        k.rgb, k.camera = undistort_image(k.rgb, u.camera)  # type: ignore[assignment]
        k.rgb = np.ascontiguousarray(k.rgb)
        k.t_wc, k.pose_frame = t_wc, frame_id  # type: ignore[assignment]
        kept.append(k)
    if not u.metric:
        schedule = cfg.schedule
        if schedule.depth_range is not None or schedule.scene_depth_m:
            LOG.warning(
                'SfM frame without a scale (set sfm_scale): depth_range and scene_depth_m are ignored'
            )
        cfg = replace(cfg, schedule=replace(schedule, depth_range=None, scene_depth_m=0.0))
    # Better than the scheduler's guess from the optical axes or the keyframe spacing (nadir: 3-6x off).
    unset = cfg.schedule.depth_range is None and not cfg.schedule.scene_depth_m
    if (sparse_depth := _sparse_depth(u, session.stamps) if unset else None) is not None:
        cfg = replace(cfg, schedule=replace(cfg.schedule, scene_depth_m=sparse_depth))
        LOG.info('SfM mode: scene depth %.3g (median depth of the sparse points) for MVS', sparse_depth)
    res, a = u.result, (u.result.alignment if u.result is not None else None)
    unit = 'm' if u.frame == 'enu' else 'm (sfm_scale)' if u.metric else 'first keyframe baseline'
    LOG.info(
        'SfM: %d/%d keyframes registered in %.1f s (frame %s, unit %s; reprojection error %.2f px%s)',
        u.num_registered, n, u.seconds, frame_id, unit,
        res.mean_reprojection_error_px if res is not None else math.nan,
        f'; GPS alignment RMS {a.rms_m:.2f} m' if a is not None else '',
    )  # fmt: skip
    info: dict[str, object] = {
        'why': sub.sfm_why,
        'keyframe_selection': 'sharpest per poseless_interval_s window' if sub.poseless else 'by pose',
        'keyframes': n,
        'registered': len(kept),
        'dropped': {str(s): why for s, why in sorted(dropped.items())},
        'frame': u.frame,
        'frame_id': frame_id,
        'metric': u.metric,
        'unit': unit,
        'scale_hint': None
        if cfg.sfm_scale is None
        else {'kind': cfg.sfm_scale.kind, 'metres': cfg.sfm_scale.metres},
        'max_side': cfg.sfm_max_side,
        'mean_reprojection_error_px': res.mean_reprojection_error_px if res is not None else None,
        'points': len(u.points),
        'scene_depth_from_sparse_points': sparse_depth,
        'matching': res.matching if res is not None else None,
        'camera_prior': _camera_dict(prior),
        'camera': _camera_dict(u.camera),
        'gps': None
        if gps is None
        else {
            'topic': sub.topics['navsat'],
            'fixes': len(sub.fixes),
            'keyframes_with_gps': int(np.isfinite(gps[:, 0]).sum()),
            'enu_origin': list(origin) if origin is not None else None,
            'max_gap_s': GPS_MAX_GAP_S,
            'alignment_rms_m': a.rms_m if a is not None else None,
            'alignment_max_m': a.max_m if a is not None else None,
            'alignment_inliers': len(a.inliers) if a is not None else None,
        },
        'update_s': u.seconds,
        'timing_s': dict(u.timing),
        'seconds': time.perf_counter() - t0,
    }
    return kept, cfg, info


# ------------------------------------------------------------------------------------ refine


def _refine_all(keyframes: list[Keyframe], cfg: _Configs, progress: Progress | None) -> dict[str, object]:
    """MVS + refinement of every keyframe, oldest first, with the whole flight known."""
    by_stamp = {k.stamp: k for k in keyframes}
    scheduler = RefineScheduler(cfg.schedule)
    for k in keyframes:
        scheduler.add(k.stamp, MvsView(k.rgb, k.camera, k.t_wc))
    try:
        refiner = DepthRefiner(cfg.refiner)  # loads the ONNX models of mono/sky 'onnx'
    except MonoModelError as exc:
        raise UserError(f'depth_refiner mono_model/sky_model: {exc}') from exc
    failures: dict[int, str] = {}
    attempts = 0
    if progress is not None:
        progress('keyframes', 0, len(keyframes))
    while True:
        try:
            job = scheduler.next_job(flush=cfg.flush)
        except BAD_MESSAGE as exc:  # a degenerate keyframe set (e.g. coincident cameras)
            raise UserError(f'cannot choose MVS neighbours: {exc}') from exc
        for w in scheduler.pop_warnings():
            LOG.warning(w)
        if job is None:
            break
        attempts += 1
        kf = by_stamp[job.stamp]
        t0 = time.perf_counter()
        mvs = compute_depth_maps(job.views, options=cfg.refiner.mvs, depth_range=job.depth_range)[0]
        t1 = time.perf_counter()
        try:
            r = refiner.refine_from_mvs(job.view, mvs.depth)
        except RefineError as exc:
            scheduler.failed(job)
            failures[job.stamp] = f'{len(job.neighbours)} neighbours, MVS {mvs.reason or "ok"}: {exc}'
            LOG.warning('keyframe %d ns not refined: %s', job.stamp, failures[job.stamp])
            kf.timings_s = {'mvs': t1 - t0, 'refine': time.perf_counter() - t1}
            continue
        t2 = time.perf_counter()
        scheduler.done(job)
        failures.pop(job.stamp, None)
        kf.depth = np.where(r.depth > 0, r.depth, np.float32(np.nan)).astype(np.float32)
        kf.neighbours = job.neighbours
        kf.timings_s = {'mvs': t1 - t0, 'refine': t2 - t1}
        if progress is not None:
            progress('keyframes', len(scheduler.refined()), len(keyframes))
    for s in scheduler.unrefined():
        failures.setdefault(s, 'no neighbour with enough overlap and parallax')
    return {'attempts': attempts, 'not_refined': {str(s): why for s, why in sorted(failures.items())}}


# ------------------------------------------------------------------------------------ render


@dataclass
class NovelView:
    """One query along the path: ``stamp`` (ns), pose, and the reply (None when unanswered)."""

    stamp: int
    t_wc: np.ndarray
    camera: PinholeCamera | None = None
    rgb: np.ndarray | None = None
    valid: np.ndarray | None = None
    reason: str | None = None
    render_s: float = 0.0


def _path_stamps(stamps: list[int], n: int) -> list[int]:
    """Stamps of :func:`interpolate_path`'s poses: the midpoints of the same keyframe pairs."""
    mids = [(a + b) // 2 for a, b in itertools.pairwise(stamps)]
    if not mids:
        return []
    pick = np.unique(np.linspace(0, len(mids) - 1, min(n, len(mids))).round().astype(int))
    return [mids[i] for i in pick]


def _render_all(
    keyframes: list[Keyframe], cfg: _Configs, n_views: int, progress: Progress | None
) -> tuple[list[NovelView], dict[str, object]]:
    """The view_renderer's model of the refined keyframes and its replies to the path queries."""
    model = [k for k in keyframes if k.depth is not None]
    unusable: dict[str, str] = {}
    info: dict[str, object] = {'model_views': len(model), 'unusable_views': unusable}
    if not model:
        return [], info
    model_frame = model[0].pose_frame
    renderer = NovelViewRenderer([], cfg.render)
    t0 = time.perf_counter()
    for k in model:
        if k.pose_frame != model_frame:
            unusable[str(k.stamp)] = f'frame {k.pose_frame!r}, the model is in {model_frame!r}'
            continue
        i = renderer.add_view(
            SourceView(k.rgb, k.depth, k.camera, k.t_wc, name=str(k.stamp), stamp=k.stamp * 1e-9)
        )
        renderer.prepare([i])
        if (why := renderer.skip_reason(i)) is not None:
            unusable[str(k.stamp)] = why
    info['prepare_s'] = time.perf_counter() - t0
    last = model[-1].camera
    w, h, hfov = cfg.out_size
    camera = (
        PinholeCamera(last.width, last.height, last.k)
        if not (w or h or hfov)
        else PinholeCamera.from_fov(w or last.width, h or last.height, hfov or last.hfov_deg)
    )
    poses = interpolate_path([k.t_wc for k in model], n_views)
    stamps = _path_stamps([k.stamp for k in model], n_views)
    views = [NovelView(s, t) for s, t in zip(stamps, poses, strict=True)]
    for j, v in enumerate(views):
        t1 = time.perf_counter()
        out = renderer.render(v.t_wc, camera)
        v.render_s = time.perf_counter() - t1
        if out.reason is not None:
            v.reason = f'unrenderable: {out.reason}'
        elif (frac := float(out.valid.mean())) < cfg.min_valid:
            v.reason = f'incomplete: {frac:.0%} rendered (< min_valid_fraction {cfg.min_valid})'
        else:
            v.camera, v.rgb, v.valid = camera, out.rgb, out.valid
        if progress is not None:
            progress('views', j + 1, len(views))
    info['model_frame'] = model_frame
    info['camera'] = {'width': camera.width, 'height': camera.height, 'hfov_deg': camera.hfov_deg}
    return views, info


# ------------------------------------------------------------------------------------ outputs


def _write_bag(
    path: Path,
    keyframes: list[Keyframe],
    views: list[NovelView],
    cfg: _Configs,
    model_frame: str,
    overwrite: bool,
) -> dict[str, int]:
    """The output bag, every message logged at its header stamp, in time order."""
    rb = {'flavor': 'rosbags'}
    events: list[tuple[int, int, str, object]] = []
    for k in keyframes:
        header = msg_utils.make_header(k.stamp, k.camera_frame, **rb)
        events.append((k.stamp, 0, 'image', msg_utils.numpy_to_image(k.rgb, 'rgb8', header, **rb)))
        events.append((k.stamp, 1, 'camera_info', msg_utils.pinhole_to_camera_info(k.camera, header, **rb)))
        pose = msg_utils.matrix_to_pose_stamped(k.t_wc, stamp_ns=k.stamp, frame_id=k.pose_frame, **rb)
        events.append((k.stamp, 2, 'pose', pose))
        if k.depth is not None:
            events.append((k.stamp, 3, 'depth', msg_utils.numpy_to_image(k.depth, '32FC1', header, **rb)))
            events.append(
                (k.stamp, 4, 'depth_info', msg_utils.pinhole_to_camera_info(k.camera, header, **rb))
            )
    for v in views:
        query = msg_utils.matrix_to_pose_stamped(v.t_wc, stamp_ns=v.stamp, frame_id=model_frame, **rb)
        events.append((v.stamp, 5, 'query', query))
        if v.rgb is not None and v.camera is not None:
            header = msg_utils.make_header(v.stamp, cfg.view_frame, **rb)
            events.append((v.stamp, 6, 'view', msg_utils.numpy_to_image(v.rgb, 'rgb8', header, **rb)))
            events.append((v.stamp, 7, 'view_info', msg_utils.pinhole_to_camera_info(v.camera, header, **rb)))
    events.sort(key=lambda e: (e[0], e[1]))
    counts: Counter = Counter()
    with BagWriter(path, overwrite=overwrite) as writer:
        for name, msgtype in OUT_TOPICS.values():
            writer.add_topic(name, msgtype, MODEL_QOS if name.startswith('/keyframes/') else REPLY_QOS)
        for stamp, _, key, msg in events:
            writer.write(OUT_TOPICS[key][0], msg, stamp)
            counts[OUT_TOPICS[key][0]] += 1
    return {name: counts[name] for name, _ in OUT_TOPICS.values()}


def _png(path: Path, bgr: np.ndarray) -> None:
    ok, buf = cv2.imencode('.png', bgr)
    if not ok:
        raise UserError(f'{path}: PNG encoding failed')
    write_atomic(path, buf.tobytes())


def _depth_limits(*depths: np.ndarray) -> tuple[float, float]:
    vals = np.concatenate([d[np.isfinite(d) & (d > 0)] for d in depths])
    if not vals.size:
        return 1.0, 2.0
    lo, hi = np.percentile(vals, (1, 99))
    return float(max(lo, 1e-3)), float(max(hi, lo * 1.01, 1e-3 * 1.01))


def _label(bgr: np.ndarray, text: str) -> np.ndarray:
    out = np.ascontiguousarray(bgr)
    scale = max(0.35, out.shape[1] / 900)
    cv2.putText(
        out,
        text,
        (6, int(18 * scale / 0.6)),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    return out


def _move(m: np.ndarray, t_wc: np.ndarray) -> np.ndarray:
    """``t_wc`` moved by the similarity ``m`` (4x4 ``[[s R, t], [0, 1]]``), still rigid."""
    s = float(np.cbrt(np.linalg.det(m[:3, :3])))
    out = np.eye(4)
    out[:3, :3] = m[:3, :3] / s @ t_wc[:3, :3]
    out[:3, 3] = m[:3, :3] @ t_wc[:3, 3] + m[:3, 3]
    return out


def _sfm_to_truth(keyframes: list[Keyframe]) -> tuple[np.ndarray, dict[str, object]] | None:
    """SfM mode: the similarity from SfM's frame to the bag's poses (ground truth), None without them.

    Rotation from the camera orientations (well determined even for a near-collinear path, where
    centres alone leave the roll about the path free), then scale and shift from the centres.
    """
    pairs = [(k.t_wc, k.bag_t_wc) for k in keyframes if k.bag_t_wc is not None]
    if len(pairs) < 3 or len(pairs) < len(keyframes):
        LOG.info('SfM mode: the bag has no poses for all keyframes: no ground-truth evaluation')
        return None
    est, ref = (np.array([p[i][:3, 3] for p in pairs]) for i in (0, 1))
    u, _, vt = np.linalg.svd(sum(g[:3, :3] @ e[:3, :3].T for e, g in pairs))
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    xs, xd = est - est.mean(0), ref - ref.mean(0)
    scale = float(np.sum((xs @ r.T) * xd) / max(float(np.sum(xs**2)), 1e-12))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = scale * r, ref.mean(0) - scale * r @ est.mean(0)
    rms = float(np.sqrt(np.mean(np.sum((est @ m[:3, :3].T + m[:3, 3] - ref) ** 2, axis=1))))
    rot = [
        math.degrees(math.acos(np.clip((np.trace((r @ e[:3, :3]).T @ g[:3, :3]) - 1) / 2, -1.0, 1.0)))
        for e, g in pairs
    ]
    return m, {
        'scale': scale,
        'centre_rms_m': rms,
        'rotation_rms_deg': float(np.sqrt(np.mean(np.square(rot)))),
    }


def _evaluate(
    bag: Path,
    keyframes: list[Keyframe],
    views: list[NovelView],
    previews: Path,
    progress: Progress | None,
    sfm: bool = False,
) -> dict[str, object] | None:
    """Previews, and errors against the exact ground truth when ``bag`` is a synthetic bag (in SfM
    mode after a similarity fit of SfM's camera centres to the bag's poses, when it has them).
    """
    from ibr_ros.core.rephoto import score
    from ibr_ros.jobs.synth_bag import GroundTruthRenderer

    gt = GroundTruthRenderer(bag) if (bag / 'synth.json').is_file() else None
    align = _sfm_to_truth(keyframes) if gt is not None and sfm else None
    if sfm and align is None:
        gt = None
    scale = align[1]['scale'] if align is not None else 1.0
    total = len(keyframes) + len(views)
    depth_rows, view_rows = [], []
    for i, k in enumerate(keyframes):
        tiles = [_label(cv2.cvtColor(k.rgb, cv2.COLOR_RGB2BGR), f'keyframe {i}')]
        truth_pose = k.bag_t_wc if align is not None else k.t_wc
        truth = gt.render(truth_pose, k.camera) if gt is not None and truth_pose is not None else None
        depth = k.depth * np.float32(scale) if k.depth is not None else None
        maps = [m for m in (depth, truth.depth if truth is not None else None) if m is not None]
        lo, hi = _depth_limits(*maps) if maps else (1.0, 2.0)
        if depth is not None:
            tiles.append(_label(colour_depth(depth, lo, hi), 'refined depth'))
        if truth is not None:
            tiles.append(_label(colour_depth(truth.depth, lo, hi), 'ground truth'))
            if depth is not None:
                d = depth
                ok = np.isfinite(truth.depth) & ~truth.sky & np.isfinite(d) & (d > 0)
                rel = np.abs(d[ok] - truth.depth[ok]) / truth.depth[ok]
                depth_rows.append({
                    'keyframe': i, 'stamp': k.stamp,
                    'median_abs_rel': float(np.median(rel)) if rel.size else None,
                    'mean_abs_rel': float(np.mean(rel)) if rel.size else None,
                    'coverage': float(ok.mean()),
                })  # fmt: skip
        _png(previews / f'keyframe_{i:03d}.png', np.hstack(tiles))
        if progress is not None:
            progress('previews', i + 1, total)
    for j, v in enumerate(views):
        tiles = []
        if gt is not None:
            cam = v.camera
            if cam is None:  # unanswered: still show what the query looked at
                cam = next(
                    (k.camera for k in reversed(keyframes) if k.depth is not None), keyframes[-1].camera
                )
            truth = gt.render(_move(align[0], v.t_wc) if align is not None else v.t_wc, cam)
            tiles.append(_label(cv2.cvtColor(truth.rgb, cv2.COLOR_RGB2BGR), 'ground truth'))
            if v.rgb is not None:
                s = score(truth.rgb, v.rgb, valid_mask=v.valid, patch=7, shift=2)
                view_rows.append({'view': j, 'stamp': v.stamp, 'auc': s.auc, 'tail': s.tail,
                                  'median': s.median, 'completeness': s.completeness})  # fmt: skip
        if v.rgb is not None:
            tiles.append(_label(cv2.cvtColor(v.rgb, cv2.COLOR_RGB2BGR), f'novel view {j}'))
        if tiles:
            _png(previews / f'novel_view_{j:03d}.png', np.hstack(tiles))
        if progress is not None:
            progress('previews', len(keyframes) + j + 1, total)
    if gt is None:
        return None

    def mean(rows: list[dict], key: str, f: Callable = np.mean) -> float | None:
        vals = [r[key] for r in rows if r[key] is not None]
        return float(f(vals)) if vals else None

    return {
        'depth_median_abs_rel': mean(depth_rows, 'median_abs_rel', np.median),
        'depth_mean_abs_rel': mean(depth_rows, 'mean_abs_rel'),
        'depth_coverage_mean': mean(depth_rows, 'coverage'),
        'rephoto_auc_mean': mean(view_rows, 'auc'),
        'rephoto_tail_mean': mean(view_rows, 'tail'),
        'rephoto_completeness_mean': mean(view_rows, 'completeness'),
        'sfm_alignment': align[1] if align is not None else None,
        'per_keyframe_depth': depth_rows,
        'per_view': view_rows,
    }


def _selection_line(sel: dict) -> str:
    """How the keyframes were chosen, for ``summary.md``."""
    if sel['method'] == 'interval':
        return f'without poses, the sharpest frame per {sel["interval_s"]:g} s window'
    if sel['method'] == 'streaming':
        return 'KeyframeSelector frame by frame (as the live frame_subsampler; no target_keyframes)'
    scale = (
        f'baseline scale {sel["scale"]:.3g} (baseline_ratio {sel["baseline_ratio"]:.3g}, '
        f'min_baseline_m {sel["min_baseline_m"]:.3g})'
    )
    return (
        f'select_keyframes over the whole flight, target {sel["target"]}: {sel["selected"]} of '
        f'{sel["frames"]} frames, {scale}'
    )


def _markdown(s: dict) -> str:
    t, pk = s['timings_s'], s['seconds_per_keyframe']

    def f(v: object, fmt: str = '.3f') -> str:
        return 'n/a' if v is None else format(v, fmt)

    tp = s['topics']
    pose = f'{tp["pose"]} ({tp["pose_type"]})' if tp['pose'] else 'no pose topic'
    lines = [
        f'# ibr process on `{s["bag"]}`',
        '',
        f'- input: {tp["image"]} ({tp["image_type"]}), {tp["camera_info"]}, {pose}'
        + (f', {tp["navsat"]} (NavSatFix)' if tp.get('navsat') else ''),
        f'- frames: {s["frames"]["complete"]} complete of {s["frames"]["images"]} images; '
        f'decisions {s["frames"]["decisions"]}; bad or incomplete {s["frames"]["bad"]}',
        f'- keyframes: {s["keyframes"]}, refined: {s["refined"]}; novel views: {s["views_answered"]}/'
        f'{s["views_requested"]} answered',
        f'- keyframe selection: {_selection_line(s["keyframe_selection"])}',
        f'- output bag: `{s["output"]["bag"]}` ({sum(s["output"]["topics"].values())} messages)',
    ]
    if (sfm := s.get('sfm')) is not None:
        gps = sfm['gps']
        lines.append(
            f'- SfM mode ({sfm["why"]}; keyframes {sfm["keyframe_selection"]}): {sfm["registered"]}/'
            f'{sfm["keyframes"]} keyframes registered, frame `{sfm["frame_id"]}` (unit {sfm["unit"]}), '
            f'reprojection error {f(sfm["mean_reprojection_error_px"], ".2f")} px, '
            + (
                'no GPS'
                if gps is None
                else f'GPS for {gps["keyframes_with_gps"]} keyframes, alignment RMS '
                f'{f(gps["alignment_rms_m"], ".2f")} m'
            )
            + f'; {sfm["seconds"]:.1f} s'
        )
    lines += [
        '',
        '| stage | seconds | seconds per keyframe |',
        '| --- | --- | --- |',
    ]
    for stage in (
        'subsample',
        *(('sfm',) if s.get('sfm') is not None else ()),
        'schedule',
        'mvs',
        'refine',
        'render',
        'write',
        'pipeline',
        'evaluate',
        'total',
    ):
        lines.append(f'| {stage} | {t[stage]:.2f} | {f(pk[stage])} |')
    if (gt := s.get('ground_truth')) is not None:
        lines += [
            '',
            f'- refined depth vs ground truth: median abs rel {f(gt["depth_median_abs_rel"], ".4f")} '
            f'(median over keyframes), coverage {f(gt["depth_coverage_mean"], ".2f")}'
            + (
                f" (SfM poses fitted to the bag's: scale {gt['sfm_alignment']['scale']:.4g}, centre RMS "
                f'{gt["sfm_alignment"]["centre_rms_m"]:.3f} m, rotation RMS '
                f'{gt["sfm_alignment"]["rotation_rms_deg"]:.2f} deg)'
                if gt.get('sfm_alignment')
                else ''
            ),
            f'- novel views vs ground truth (7x7, shift 2): mean AUC {f(gt["rephoto_auc_mean"], ".2f")}, '
            f'mean worst-1% {f(gt["rephoto_tail_mean"], ".2f")}, completeness '
            f'{f(gt["rephoto_completeness_mean"], ".2f")}',
        ]
    return '\n'.join(lines) + '\n'


# ------------------------------------------------------------------------------------ job


def process_bag(
    bag: Path, out: Path, options: ProcessOptions | None = None, progress: Progress | None = None
) -> dict[str, object]:
    """Process ``bag`` into the folder ``out`` (see the module docstring); returns the summary.

    Raises:
        UserError: Unreadable bag, missing topics, no frames or keyframes, bad parameters, an
            existing ``out/bag`` without ``overwrite``.

    """
    o = options or ProcessOptions()
    bag, out = Path(bag), Path(out)
    if o.views < 0:
        raise UserError(f'--views must be >= 0, got {o.views}')
    if o.max_keyframes is not None and o.max_keyframes < 1:
        raise UserError(f'--max-keyframes must be >= 1, got {o.max_keyframes}')
    if (out / 'bag').exists() and not o.overwrite:
        raise UserError(f'{out / "bag"} exists already (pass --overwrite to replace it)')
    params = load_params(o.params)
    cfg = _configs(params, o)
    threads = _set_threads(o.threads)
    t_start = time.perf_counter()
    sub = _subsample(bag, cfg, o, progress)
    keyframes = sub.keyframes
    t_sub = time.perf_counter()
    sfm_info = None
    if sub.sfm_why is not None:
        keyframes, cfg, sfm_info = _register(sub, cfg, o.threads, progress)
    t_sfm = time.perf_counter()
    refine_info = _refine_all(keyframes, cfg, progress)
    t_ref = time.perf_counter()
    views, render_info = _render_all(keyframes, cfg, o.views, progress)
    t_render = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    model_frame = str(render_info.get('model_frame', keyframes[0].pose_frame))
    topic_counts = _write_bag(out / 'bag', keyframes, views, cfg, model_frame, o.overwrite)
    t_write = time.perf_counter()
    previews = out / 'previews'
    previews.mkdir(exist_ok=True)
    for old in previews.glob('*.png'):  # a previous run's previews would mix with these
        old.unlink()
    gt = _evaluate(bag, keyframes, views, previews, progress, sfm=sfm_info is not None)
    t_eval = time.perf_counter()

    refined = [k for k in keyframes if k.depth is not None]
    mvs_s = sum(k.timings_s.get('mvs', 0.0) for k in keyframes)
    refine_s = sum(k.timings_s.get('refine', 0.0) for k in keyframes)
    timings = {
        'subsample': t_sub - t_start,
        'sfm': t_sfm - t_sub,
        'mvs': mvs_s,
        'refine': refine_s,
        'schedule': (t_ref - t_sfm) - mvs_s - refine_s,
        'render': t_render - t_ref,
        'write': t_write - t_render,
        'pipeline': t_write - t_start,
        'evaluate': t_eval - t_write,
        'total': t_eval - t_start,
    }
    n = len(keyframes)
    answered = [v for v in views if v.rgb is not None]
    summary: dict[str, object] = {
        'bag': str(bag),
        'topics': sub.topics,
        'params': params,
        'threads': threads,
        'frames': {
            'images': sub.counts['image'],
            'camera_info': sub.counts['camera_info'],
            'poses': sub.counts['pose'],
            'complete': sub.counts['frames'],
            'decisions': dict(sorted(sub.decisions.items())),
            'bad': dict(sorted(sub.bad.items())),
            'stopped_at_max_keyframes': sub.stopped,
        },
        'keyframe_selection': sub.selection,
        'sfm': sfm_info,
        'keyframes': n,
        'refined': len(refined),
        'refine': refine_info,
        'views_requested': len(views),
        'views_answered': len(answered),
        'unanswered': {str(v.stamp): v.reason for v in views if v.rgb is None},
        'render': render_info,
        'render_ms_median': float(np.median([1e3 * v.render_s for v in views])) if views else None,
        'output': {'bag': str(out / 'bag'), 'topics': topic_counts},
        'timings_s': timings,
        'seconds_per_keyframe': {k: v / n for k, v in timings.items()},
        'per_keyframe': [
            {
                'stamp': k.stamp,
                'reason': k.reason,
                'refined': k.depth is not None,
                'neighbours': list(k.neighbours),
                **{f'{s}_s': t for s, t in k.timings_s.items()},
            }
            for k in keyframes
        ],
        'ground_truth': gt,
    }
    write_atomic(out / 'summary.json', json.dumps(summary, indent=2, default=_json_default) + '\n')
    write_atomic(out / 'summary.md', _markdown(summary))
    return summary


def _json_default(value: object) -> object:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    raise TypeError(f'not JSON serialisable: {type(value).__name__}')


def _set_threads(threads: int | None) -> int:
    """Use ``threads`` numba and OpenCV threads (None: numba's default, all cores); returns the count."""
    import numba

    if threads is not None:
        if not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
            raise UserError(f'--threads must be in 1..{numba.config.NUMBA_NUM_THREADS}, got {threads}')
        numba.set_num_threads(threads)
        cv2.setNumThreads(threads)
    return int(numba.get_num_threads())
