"""``depth_refiner``: MVS + refined depth for every keyframe, shardable over several processes.

Subscribes (reliable, transient local): ``keyframes/image`` (``sensor_msgs/Image``),
``keyframes/camera_info`` and ``keyframes/pose`` (``geometry_msgs/PoseStamped``), matched by
identical header stamps.

Also subscribes ``keyframes/status`` (``diagnostic_msgs/DiagnosticStatus``, latched; the
frame_subsampler's :class:`~ibr_ros.core.flight.status.FlightStatus`): whether the flight has poses (SfM mode
below) and whether the camera stream ended.

A keyframe is refined once :func:`~ibr_ros.core.depth.mvs.select_neighbours` finds ``min_neighbours``
source views for it among the keyframes received so far, or, with at least one neighbour, once the
status says the camera stream ended (the end of a flight; or, with ``flush_after_s`` > 0, when that
long passed without a new keyframe). With ``refine_again`` it is
refined again whenever more neighbours (up to ``max_neighbours``) become available. This policy is
:class:`~ibr_ros.core.depth.schedule.RefineScheduler`, shared with ``ibr process``. Refinement:
:func:`~ibr_ros.core.depth.mvs.compute_depth_maps` on the keyframe and its neighbours, then
:meth:`~ibr_ros.core.depth.refine.DepthRefiner.refine_from_mvs`.

Depth range of the MVS sweep: ``depth_range`` ``[near, far]`` (m) when set; else
``[near_ratio, far_ratio] x s`` with ``s`` the scene depth at the image centre: ``scene_depth_m``
when set, else the median distance along the keyframe's optical axis to where it passes closest
to the optical axes of the other keyframes (axes 3-90 deg apart, the point in front of both
cameras; oblique and orbit flights), else (parallel axes, e.g. a nadir survey) 12.5 x the mean
distance to the two nearest keyframes (the inverse of the frame_subsampler's 0.08 baseline
ratio), with a warning to set ``scene_depth_m``.

Monocular depth (fills the MVS holes after the per-view LUT remap): ``mono`` ``'plane'`` (default,
:class:`~ibr_ros.core.depth.GroundPlanePrior`, no model) or ``'onnx'`` with ``mono_model``: ``'ibr_mono'``
(the shipped ``ibr_ros/models/ibr_mono.onnx``), a model of ``ibr models list`` fetched into the cache,
or a path to an ``.onnx`` file; ``mono_preset`` names its I/O convention in
:data:`~ibr_ros.core.depth.mono.PRESETS` (``''``: the named model's own; required for a path). Sky mask:
``sky`` ``'fallback'`` (default; horizon + colour cues + no MVS depth), ``'onnx'`` with ``sky_model``
/ ``sky_preset`` likewise (:data:`~ibr_ros.core.depth.sky.SKY_PRESETS`; ``'ibr_mono'`` is the shipped
model's sky head) or ``'none'``. A bad value (unknown name or preset, missing or unloadable file)
stops the node at start-up with one error line naming the parameter and value (exit status 2).

Publishes (reliable, transient local): ``keyframes/depth`` (``sensor_msgs/Image`` ``32FC1``
metres, REP-118: NaN unknown) and ``keyframes/depth/camera_info``, both with the keyframe's stamp,
and, with ``mirror_model`` (default), the keyframe's ``keyframes/image``, ``keyframes/camera_info``
and ``keyframes/pose`` too: the model then outlives the frame_subsampler (a renderer restarted after
it died still gets everything). Depth published by another refiner is mirrored the same way, once.
With ``publish_debug`` (reliable, volatile): ``depth/mvs``, ``depth/mono_remapped`` (``32FC1``),
``depth/sky_mask`` (``mono8``, 255 = sky), ``depth/preview`` and ``depth/mvs/preview`` (``rgb8``
turbo-coloured inverse depth).

Sharding: with ``num_workers`` > 1 every process receives all keyframes (they are everybody's
neighbours) but refines only those whose stamp hashes to its ``worker_index``
(:func:`~ibr_ros.core.depth.schedule.shard_of`, independent of arrival order), so each keyframe is
refined once. Workers publish a heartbeat on ``refiners/heartbeat`` (``DiagnosticStatus``, every
``worker_lease_s`` / 3 s); a worker not heard from for ``worker_lease_s`` is dead and its
unrefined keyframes go to the live ones (:class:`~ibr_ros.core.flight.status.ShardMembership`). Every worker
subscribes ``keyframes/depth``: a keyframe whose depth is already published (by a live worker, or
mirrored from a dead one) is never refined again, so a restarted worker picks up where it stopped.

SfM mode (keyframes without poses): with ``sfm_mode`` ``'always'``, or ``'auto'`` once the
frame_subsampler's status says the flight has no poses (never on a timer: until the status comes,
keyframes wait for their poses, however late), keyframes are registered by
:class:`~ibr_ros.core.registration.SfmSession` (pycolmap on the CPU, the CameraInfo intrinsics as the
prior, images downscaled to ``sfm_max_side``) instead of waiting for ``keyframes/pose``, which is
then ignored (it carries this node's own poses). The first registration runs once
``sfm_min_keyframes`` keyframes are there, the next ones after every ``sfm_every`` new keyframes and
when the flight is flushed (see above). Each newly registered keyframe's pose is published once on
``keyframes/pose`` (frame_id ``sfm``, stamp = the keyframe's; later registrations are aligned to the
earlier ones, so the published poses keep one frame) and the keyframe is then refined like a posed
one. The ``sfm`` frame: z up (the ground plane of the sparse points), origin on the ground below the
first registered keyframe, x its viewing direction; unit: the distance between the first two
registered keyframes, or metres with ``sfm_scale`` (``'baseline'``: that distance, ``'altitude'``:
the first keyframe's height above the ground, ``'depth'``: the median depth of the sparse points) =
``sfm_scale_m``. Depth maps are in the same unit; without a scale, ``depth_range`` and
``scene_depth_m`` (metres) are ignored. SfM runs on the worker thread; with ``num_workers`` > 1,
``'always'`` is a start-up error (one registration per graph) and ``'auto'`` acts as ``'off'``. With
``'off'`` frames without a pose are not refined. Registration runs again when the camera stream
ended.

The heavy work runs on one worker thread; the executor thread only stores messages.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import replace
from functools import partial

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

import msg_utils
from ibr_ros.core.depth.mono import MonoModelError
from ibr_ros.core.depth.mvs import MvsOptions, MvsView, compute_depth_maps
from ibr_ros.core.depth.refine import DepthRefiner, RefineError
from ibr_ros.core.depth.schedule import RefineJob, RefineScheduler, ScheduleConfig, parse_depth_range
from ibr_ros.core.flight.status import FlightStatus, ShardMembership
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.registration.sfm import SfmError
from ibr_ros.core.registration.sfm_session import SfmSession
from ibr_ros.errors import UserError
from ibr_ros.jobs.warmup import warm_up_refiner
from ibr_ros.node_config.depth_refiner import refiner_config, sfm_settings
from ibr_ros.nodes.common import (
    BAD_MESSAGE,
    BadInput,
    StampAssembler,
    declare,
    known_depth,
    latched_qos,
    model_qos,
    reliable_qos,
    run_node,
    size_mismatch,
    subscribe_field,
)

#: Longest wait at shutdown for the worker's current step (an SfM registration of a long flight).
STOP_TIMEOUT_S = 120.0

DEBUG_TOPICS = ('depth/mvs', 'depth/mono_remapped', 'depth/sky_mask', 'depth/preview', 'depth/mvs/preview')


def colourise(depth: np.ndarray) -> np.ndarray:
    """rgb8 turbo colouring of inverse depth (2-98th percentile), black where unknown."""
    ok = np.isfinite(depth) & (depth > 0)
    out = np.zeros((*depth.shape, 3), np.uint8)
    if not ok.any():
        return out
    inv = 1.0 / depth[ok]
    lo, hi = np.percentile(inv, (2, 98))
    grey = np.zeros(depth.shape, np.uint8)
    grey[ok] = np.clip((inv - lo) / max(hi - lo, 1e-12) * 255, 0, 255).astype(np.uint8)
    out[:] = cv2.cvtColor(cv2.applyColorMap(grey, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    out[~ok] = 0
    return out


class DepthRefinerNode(Node):
    """Keyframe depth refinement node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('depth_refiner')
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.num_workers = int(
            p('num_workers', 1, 'refiner processes sharing the keyframes', limits=(1, 1024))
        )
        self.worker_index = int(p('worker_index', 0, 'this process: 0 .. num_workers - 1', limits=(0, 1023)))
        min_neighbours = int(p('min_neighbours', 2, 'neighbours needed to refine', limits=(1, 16)))
        max_nb = int(p('max_neighbours', 4, 'MVS source views per keyframe', limits=(1, 16)))
        self.flush_after_s = float(
            p('flush_after_s', 0.0, 'also flush after this long without keyframes (s), 0 = at the end only',
              limits=(0.0, 1e6))
        )  # fmt: skip
        lease = float(p('worker_lease_s', 3.0, 'a sharded worker silent this long is dead (s)',
                        limits=(0.1, 1e6)))  # fmt: skip
        self.mirror = bool(
            p('mirror_model', True, 'republish the keyframes that have depth (model survives)')
        )
        refine_again = bool(p('refine_again', False, 'refine again when more neighbours arrive'))
        rng = p('depth_range', [0.0, 0.0], 'MVS [near, far] in metres; [0, 0] = automatic')
        scene_depth = float(p('scene_depth_m', 0.0, 'scene depth hint (m), 0 = estimate', limits=(0.0, 1e6)))
        near_ratio = float(p('near_ratio', 0.25, 'near = this x scene depth', limits=(1e-3, 1.0)))
        far_ratio = float(p('far_ratio', 4.0, 'far = this x scene depth', limits=(1.0, 1e4)))
        self.publish_debug = bool(p('publish_debug', False, 'publish depth/* debug images'))
        self.max_pending = int(
            p('max_pending', 30, 'frames waiting for their other messages', limits=(1, 10000))
        )
        max_mb = float(p('max_pending_mb', 128.0, 'MiB of pending frames at most', limits=(1.0, 1e6)))
        mono = str(p('mono', 'plane', "monocular depth: 'plane' (ground-plane prior) or 'onnx' (mono_model)"))
        mono_model = str(
            p('mono_model', 'ibr_mono', "'ibr_mono' (shipped), a fetched model or an .onnx path")
        )
        mono_preset = str(p('mono_preset', '', "I/O convention of mono_model (a PRESETS name); '' = its own"))
        sky = str(p('sky', 'fallback', "sky mask: 'fallback' (horizon + colour), 'onnx' (sky_model), 'none'"))
        sky_model = str(p('sky_model', 'ibr_mono', "with sky 'onnx': 'ibr_mono' (shipped) or an .onnx path"))
        sky_preset = str(
            p('sky_preset', '', "I/O convention of sky_model (a SKY_PRESETS name); '' = its own")
        )
        self.sfm_mode = str(
            p('sfm_mode', 'auto', "register keyframes without poses: 'auto', 'always' or 'off'")
        )
        self.sfm_min_keyframes = int(
            p('sfm_min_keyframes', 4, 'keyframes of the first SfM registration', limits=(3, 10000))
        )
        self.sfm_every = int(
            p('sfm_every', 2, 'register again after this many new keyframes', limits=(1, 10000))
        )
        sfm_max_side = int(p('sfm_max_side', 640, 'longest image side for SfM (px), 0 = as received',
                             limits=(0, 100000)))  # fmt: skip
        sfm_scale = str(p('sfm_scale', 'none', "SfM scale: 'none', 'baseline', 'altitude' or 'depth'"))
        sfm_scale_m = float(p('sfm_scale_m', 0.0, 'the sfm_scale length in metres', limits=(0.0, 1e7)))
        scale_hint = sfm_settings(self.sfm_mode, sfm_scale, sfm_scale_m)
        if self.num_workers > 1 and self.sfm_mode == 'always':
            raise UserError(
                f"parameter sfm_mode 'always' needs num_workers 1 (one SfM registration per graph), "
                f'got num_workers {self.num_workers}'
            )
        if self.num_workers > 1 and self.sfm_mode == 'auto':
            self.sfm_mode = 'off'
            self.get_logger().info(
                'num_workers > 1: sfm_mode auto acts as off (one SfM registration per graph)'
            )
        self.sfm = SfmSession(
            scale_hint=scale_hint,
            max_side=sfm_max_side,
            redefine=False,  # published poses must keep their frame
        )
        self.sfm_active = self.sfm_mode == 'always'
        self.unit = 'm'  # of poses and depth: 'sfm units' in an SfM frame without a scale
        self.sfm_times: list[float] = []
        self._sfm_queue: list[int] = []  # stamps of keyframes waiting for SfmSession.add()
        self._sfm_views: dict[int, tuple[np.ndarray, PinholeCamera, str]] = {}  # image, camera, frame_id
        self.mvs = MvsOptions(max_neighbours=max_nb)
        self.schedule = RefineScheduler(
            ScheduleConfig(
                num_workers=self.num_workers,
                worker_index=self.worker_index,
                min_neighbours=min_neighbours,
                refine_again=refine_again,
                depth_range=parse_depth_range(rng),
                scene_depth_m=scene_depth,
                near_ratio=near_ratio,
                far_ratio=far_ratio,
                mvs=self.mvs,
            )
        )
        self.refiner = self._make_refiner(mono, mono_model, mono_preset, sky, sky_model, sky_preset)
        self.bad = BadInput(self)
        self.frames = StampAssembler(
            ('image', 'camera_info', 'pose'),
            self.max_pending,
            lambda detail: self.bad('incomplete', detail),
            what='keyframe',
            max_bytes=round(max_mb * 2**20),
        )
        self.frame_ids: dict[int, str] = {}  # header frame_id of each scheduled keyframe
        self.pose_frames: dict[int, str] = {}  # frame_id of each keyframe's pose (posed flights)
        self.refine_times: list[float] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._version = 0
        self._last_arrival = time.monotonic()
        self._poseless: set[int] = set()  # frames with image and camera_info before any pose was seen
        self.poses_seen = 0
        self.flight: FlightStatus | None = None  # the frame_subsampler's latest status
        self._ended = False  # the camera stream ended: flush
        self._published: set[int] = set()  # stamps whose depth this process published (own or mirrored)
        self._others: dict[int, dict[str, object]] = {}  # depth messages of other workers, by stamp
        self._lease = lease
        qos = model_qos()
        for msg_type, field, convert in (
            (Image, 'image', lambda m: np.array(msg_utils.image_to_rgb(m))),  # a copy, detached from m
            (
                CameraInfo,
                'camera_info',
                lambda m: (m.header.frame_id or 'camera_optical', msg_utils.camera_info_to_pinhole(m)),
            ),
            (
                PoseStamped,
                'pose',
                lambda m: (msg_utils.pose_stamped_to_matrix(m), m.header.frame_id or 'map'),
            ),
        ):
            if field == 'pose' and self.sfm_mode == 'always':
                continue  # keyframes/pose carries this node's own poses
            subscribe_field(self, msg_type, f'keyframes/{field}', qos, field, convert, self._put, self.bad)
        self.pub_pose = (
            self.create_publisher(PoseStamped, 'keyframes/pose', qos) if self.sfm_mode != 'off' else None
        )
        self.pub_depth = self.create_publisher(Image, 'keyframes/depth', qos)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/depth/camera_info', qos)
        self.pub_kf = (
            {
                'image': self.create_publisher(Image, 'keyframes/image', qos),
                'camera_info': self.create_publisher(CameraInfo, 'keyframes/camera_info', qos),
                'pose': self.pub_pose or self.create_publisher(PoseStamped, 'keyframes/pose', qos),
            }
            if self.mirror
            else {}
        )
        self.create_subscription(DiagnosticStatus, 'keyframes/status', self._on_status, latched_qos())
        for msg_type, topic in ((Image, 'keyframes/depth'), (CameraInfo, 'keyframes/depth/camera_info')):
            self.create_subscription(msg_type, topic, partial(self._on_depth, topic), qos)
        if self.num_workers > 1:
            self.pub_beat = self.create_publisher(DiagnosticStatus, 'refiners/heartbeat', reliable_qos())
            self.create_subscription(
                DiagnosticStatus, 'refiners/heartbeat', self._on_heartbeat, reliable_qos()
            )
            self.create_timer(lease / 3, self._beat)
        self.debug = {
            n: self.create_publisher(Image, n, reliable_qos()) for n in DEBUG_TOPICS if self.publish_debug
        }
        if bool(p('warmup', True, 'run MVS and refinement on a tiny scene at start-up (kernels load once)')):
            self.get_logger().info(
                f'warm-up MVS + refinement in {warm_up_refiner(self.mvs, self.refiner):.2f} s'
            )
        # The lease starts now, after the warm-up (tens of seconds when the kernels are not cached yet).
        self.members = ShardMembership(self.num_workers, self.worker_index, self._lease, time.monotonic())
        self._live = self.members.live(time.monotonic())
        self._worker = threading.Thread(target=self._work, name='depth_refiner_worker', daemon=True)
        self._worker.start()
        self.get_logger().info(
            f'worker {self.worker_index}/{self.num_workers}: refining keyframes with >= '
            f'{min_neighbours} of up to {max_nb} neighbours; '
            f'depth range {self.schedule.config.depth_range or "automatic"}; SfM mode {self.sfm_mode}'
        )

    def _make_refiner(
        self, mono: str, mono_model: str, mono_preset: str, sky: str, sky_model: str, sky_preset: str
    ) -> DepthRefiner:
        """The refiner with the monocular and sky backends of the parameters; UserError naming the bad one."""
        config = refiner_config(mono, mono_model, mono_preset, sky, sky_model, sky_preset, self.mvs)
        mono_spec, sky_spec = config.mono_model, config.sky_model
        try:
            refiner = DepthRefiner(config)  # loads the mono model first, then the sky model
        except MonoModelError as exc:
            if mono_spec is not None and str(exc).startswith(str(mono_spec.path)):
                bad, path = f'mono_model {mono_model!r}', mono_spec.path
            else:
                bad, path = f'sky_model {sky_model!r}', (sky_spec or mono_spec).path
            raise UserError(f'parameter {bad}: {str(exc).removeprefix(f"{path}: ")}') from exc
        used = [f'mono {mono}' + (f' ({mono_spec.path.name})' if mono_spec else '')]
        used.append(f'sky {sky}' + (f' ({sky_spec.path.name})' if sky_spec else ''))
        self.get_logger().info(f'depth refinement with {", ".join(used)}')
        return refiner

    # -- input ----------------------------------------------------------------------------------
    def _put(self, stamp: int, field: str, value: object) -> None:
        with self._lock:
            if stamp in self.schedule or stamp in self._sfm_views:
                return  # a keyframe already here, again (a mirror's copy, a late duplicate)
        if field == 'pose':
            if self.sfm_active:
                return  # this node's own poses (or another source's, which SfM mode ignores)
            self.poses_seen += 1
        if (f := self.frames.put(stamp, field, value)) is None:
            partial = self.frames.partial(stamp)
            if 'image' in partial and 'camera_info' in partial and not self.poses_seen:
                if self.sfm_active:
                    self.frames.discard(stamp)
                    self._add_poseless(stamp, partial['image'], *partial['camera_info'])
                    return
                if stamp in self._poseless:
                    return
                self._poseless.add(stamp)
                if len(self._poseless) == 3:
                    self.get_logger().info(
                        'keyframes arrive before their keyframes/pose: '
                        + (
                            'frames without poses are not refined (sfm_mode off)'
                            if self.sfm_mode == 'off'
                            else 'waiting for their poses (SfM mode starts only when keyframes/status '
                            'says the flight has no poses)'
                        )
                    )
            return
        image, (frame_id, camera), (pose, pose_frame) = f['image'], f['camera_info'], f['pose']
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        with self._lock:
            if not self.schedule.add(stamp, MvsView(image, camera, pose)):
                self.get_logger().debug(f'keyframe {stamp} ns received again: ignored')
                return
            self.frame_ids[stamp] = frame_id
            self.pose_frames[stamp] = pose_frame
            self._version += 1
            self._last_arrival = time.monotonic()
        self._mirror(stamp)  # another worker's depth may have come first
        self._wake.set()

    # -- SfM mode -------------------------------------------------------------------------------
    def _add_poseless(self, stamp: int, image: np.ndarray, frame_id: str, camera: PinholeCamera) -> None:
        """Queue a keyframe without a pose for registration (executor thread; the worker adds it)."""
        if mismatch := size_mismatch(camera.width, camera.height, image.shape, stamp):
            self.bad('camera_info', mismatch)
            return
        with self._lock:
            if stamp in self._sfm_views or stamp in self.schedule:
                self.get_logger().debug(f'keyframe {stamp} ns received again: ignored')
                return
            self._sfm_views[stamp] = (image, camera, frame_id)
            self._sfm_queue.append(stamp)
            self._last_arrival = time.monotonic()
        self._wake.set()

    # -- what the graph states --------------------------------------------------------------------
    def _on_status(self, msg: DiagnosticStatus) -> None:
        """The frame_subsampler's flight status: SfM mode when it has no poses; flush when it ended."""
        try:
            status = FlightStatus.from_pairs(msg_utils.status_to_pairs(msg))
        except (msg_utils.MessageError, ValueError) as exc:
            self.bad('status', f'keyframes/status from {msg.name!r}: {exc}')
            return
        self.flight = status
        if status.pose_source == 'none' and self.sfm_mode == 'auto' and not self.sfm_active:
            if self.poses_seen:
                self.get_logger().warning(
                    'keyframes/status says the flight has no poses, but poses arrived: staying with them'
                )
            else:
                self._start_sfm()
        elif status.pose_source == 'pose' and self.sfm_active and self.sfm_mode == 'auto':
            self.get_logger().warning(
                'keyframes/status says poses arrive now: this flight stays in SfM mode (its frame is fixed)',
                once=True,
            )
        ended = status.camera == 'ended'
        if ended != self._ended:
            self._ended = ended
            if ended:
                self.get_logger().info(
                    f'the camera stream ended after {status.keyframes} keyframes: refining what is left'
                )
            self._wake.set()

    def _start_sfm(self) -> None:
        """'auto' and a flight without poses: register the keyframes here (waiting ones first)."""
        self.sfm_active = True
        self.get_logger().warning(
            'keyframes/status: the flight has no poses: SfM mode, keyframes are registered here and '
            'their poses published on keyframes/pose'
        )
        for stamp in sorted(self._poseless):
            partial = self.frames.partial(stamp)
            if 'image' in partial and 'camera_info' in partial:
                self.frames.discard(stamp)
                self._add_poseless(stamp, partial['image'], *partial['camera_info'])

    def _on_depth(self, topic: str, msg: Image | CameraInfo) -> None:
        """Depth (or its camera_info) on keyframes/depth: another worker's is noted and mirrored once."""
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        with self._lock:
            if stamp in self._published:  # this process's own (or already mirrored): no decoding
                self._others.pop(stamp, None)
                return
        if topic == 'keyframes/depth':
            try:
                depth = msg_utils.depth_image_to_m(msg)
            except BAD_MESSAGE as exc:
                self.bad('depth', f'keyframes/depth at {stamp} ns: {exc}')
                return
            if not known_depth(depth):
                self.bad('depth', f'keyframes/depth at {stamp} ns has no known value: ignored')
                return
        with self._lock:
            if stamp in self._published:
                self._others.pop(stamp, None)
                return  # this process's own (or already mirrored)
            if topic == 'keyframes/depth':
                self.schedule.published_elsewhere(stamp)
            if not self.mirror:
                return  # noted; nothing to mirror
            rec = self._others.setdefault(stamp, {})
            rec[topic] = msg
            while len(self._others) > self.max_pending:  # e.g. depth of keyframes this one never gets
                dropped = min(self._others)
                del self._others[dropped]
                self.bad('mirror', f'depth at {dropped} ns not mirrored: its keyframe did not arrive')
        self._mirror(stamp)

    def _mirror(self, stamp: int) -> None:
        """Republish another worker's depth (and its keyframe) once both and the keyframe are here."""
        with self._lock:
            view = self.schedule.view(stamp)
            rec = self._others.get(stamp, {})
            if view is None or len(rec) < 2 or stamp in self._published:
                return
            self._published.add(stamp)
            del self._others[stamp]
        self.pub_depth.publish(rec['keyframes/depth'])
        self.pub_info.publish(rec['keyframes/depth/camera_info'])
        self._publish_keyframe(stamp, view)

    def _publish_keyframe(self, stamp: int, view: MvsView) -> None:
        """With ``mirror_model``: the keyframe's image, camera_info and (posed flights) pose, once."""
        if not self.pub_kf:
            return
        header = msg_utils.make_header(stamp, self.frame_ids.get(stamp, 'camera_optical'))
        self.pub_kf['image'].publish(msg_utils.numpy_to_image(view.rgb, 'rgb8', header))
        self.pub_kf['camera_info'].publish(msg_utils.pinhole_to_camera_info(view.camera, header))
        if not self.sfm_active:  # SfM poses went out when they were registered
            frame = self.pose_frames.get(stamp, 'map')
            self.pub_kf['pose'].publish(
                msg_utils.matrix_to_pose_stamped(view.t_wc, stamp_ns=stamp, frame_id=frame)
            )

    def _beat(self) -> None:
        """Heartbeat of this worker; takes over the keyframes of workers that went silent."""
        with self._lock:
            published = sorted(self._published)
        self.pub_beat.publish(
            msg_utils.pairs_to_status(
                self.get_fully_qualified_name(),
                [
                    ('worker_index', str(self.worker_index)),
                    ('num_workers', str(self.num_workers)),
                    ('published', ','.join(map(str, published))),
                ],
            )
        )
        self._check_members()

    def _on_heartbeat(self, msg: DiagnosticStatus) -> None:
        values = dict(msg_utils.status_to_pairs(msg))
        try:
            worker, n = int(values['worker_index']), int(values['num_workers'])
            published = [int(x) for x in values.get('published', '').split(',') if x]
        except (KeyError, ValueError):
            self.bad('heartbeat', f'refiners/heartbeat from {msg.name!r} without worker_index/num_workers')
            return
        if n != self.num_workers:
            self.bad(
                'heartbeat',
                f'refiners/heartbeat from {msg.name!r}: num_workers {n}, this one {self.num_workers}',
            )
            return
        with self._lock:
            for stamp in published:
                if stamp not in self._published:
                    self.schedule.published_elsewhere(stamp)
        self.members.heard(worker, time.monotonic())
        self._check_members()

    def _check_members(self) -> None:
        live = self.members.live(time.monotonic())
        if live == self._live:
            return
        gone, back = sorted(set(self._live) - set(live)), sorted(set(live) - set(self._live))
        self._live = live
        with self._lock:
            gained = self.schedule.reassign(lambda s: self.members.owner(s, live) == self.worker_index)
            self._version += 1
        self.get_logger().warning(
            f'refiner workers alive: {list(live)}'
            + (f'; gone: {gone}' if gone else '')
            + (f'; back: {back}' if back else '')
            + f'; this worker takes over {len(gained)} keyframes'
        )
        self._wake.set()

    def _sfm_due(self, flush: bool) -> bool:
        """Whether the worker should register now (called with the lock held)."""
        added = len(self._sfm_queue)
        if not self.sfm_active or added == 0:
            return False
        if self.sfm.frame is None:
            return len(self.sfm) + added >= self.sfm_min_keyframes
        return added >= self.sfm_every or flush

    def _register(self) -> None:
        """Run one SfM update over all pose-less keyframes; publish and schedule the new poses (worker)."""
        with self._lock:
            queue, self._sfm_queue = self._sfm_queue, []
        for stamp in queue:
            image, camera, _ = self._sfm_views[stamp]
            try:
                self.sfm.add(stamp, image, camera)
            except SfmError as exc:
                self.bad('sfm', str(exc))
        first = self.sfm.frame is None
        u = self.sfm.update()
        self.sfm_times.append(u.seconds)
        if not u.accepted:
            self.get_logger().warning(
                f'SfM: {u.num_views} keyframes, none newly registered in {u.seconds:.2f} s: {u.reason}'
            )
            return
        if first and not u.metric:
            cfg = self.schedule.config
            if cfg.depth_range is not None or cfg.scene_depth_m:
                self.get_logger().warning(
                    'SfM frame without a scale (set sfm_scale): depth_range and scene_depth_m are ignored'
                )
            with self._lock:
                self.schedule = RefineScheduler(replace(cfg, depth_range=None, scene_depth_m=0.0))
            self.unit = 'sfm units'
        world = 'map' if u.frame == 'enu' else 'sfm'
        with self._lock:
            for stamp in u.new:
                image, camera, frame_id = self._sfm_views[stamp]
                t_wc = u.poses[stamp]
                self.pub_pose.publish(msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp, frame_id=world))
                self.schedule.add(stamp, MvsView(image, camera, t_wc))
                self.frame_ids[stamp] = frame_id
            if u.new:
                self._version += 1
        unit = 'metres' if u.metric else 'unit = first baseline'
        self.get_logger().info(
            f'SfM: {u.num_registered}/{u.num_views} keyframes registered in {u.seconds:.2f} s '
            f'({len(u.new)} new; frame {world}, {unit}; frame RMS {u.frame_rms:.3g})'
        )

    def _work(self) -> None:
        seen = -1
        while not self._stop.is_set():
            self._wake.wait(timeout=0.25)
            self._wake.clear()
            with self._lock:
                flush_due = self._ended or (
                    self.flush_after_s > 0 and time.monotonic() - self._last_arrival >= self.flush_after_s
                )
                sfm_due = self._sfm_due(flush_due)
            if sfm_due:
                try:
                    self._register()
                except Exception as exc:  # the worker survives a failed registration
                    if self._stop.is_set():
                        return
                    self.get_logger().error(f'SfM registration failed: {exc!r}')
            if not self.members.synced(time.monotonic()):
                continue  # a worker presumed alive has not said yet what it refined
            with self._lock:
                if self._version == seen and not flush_due:
                    continue
                version = self._version
                try:
                    job = self.schedule.next_job(flush=flush_due)
                except BAD_MESSAGE as exc:  # a degenerate keyframe set (e.g. coincident cameras)
                    self.bad('neighbours', str(exc))
                    job = None
                for warning in self.schedule.pop_warnings():
                    self.get_logger().warning(warning)
                idle = job is None and self._ended
                if job is None:
                    seen = version
                    if flush_due and not self._ended:  # nothing left to do until new keyframes arrive
                        self._last_arrival = math.inf
            if idle:
                self._wake.wait()  # until something changes (a keyframe, a status, a stop)
            if job is None:
                continue
            try:
                ok = self._refine(job)
            except Exception as exc:  # the worker survives any one keyframe
                if self._stop.is_set():
                    return
                self.get_logger().error(f'refining keyframe {job.stamp} ns failed: {exc!r}')
                ok = False
            with self._lock:
                (self.schedule.done if ok else self.schedule.failed)(job)
            self._wake.set()  # look for the next job straight away

    # -- refinement -----------------------------------------------------------------------------
    def _refine(self, job: RefineJob) -> bool:
        """Refine and publish ``job``; False when the refinement failed (counted as bad input)."""
        t0 = time.perf_counter()
        n, rng = len(job.neighbours), job.depth_range
        mvs = compute_depth_maps(job.views, options=self.mvs, depth_range=rng)[0]
        t1 = time.perf_counter()
        try:
            r = self.refiner.refine_from_mvs(job.view, mvs.depth)
        except RefineError as exc:
            self.bad('refine', f'keyframe {job.stamp} ns ({n} neighbours, MVS {mvs.reason or "ok"}): {exc}')
            return False
        t2 = time.perf_counter()
        if self._stop.is_set():
            return False
        if not known_depth(r.depth):
            self.bad('refine', f'keyframe {job.stamp} ns ({n} neighbours): no pixel has a known depth')
            return False
        header = msg_utils.make_header(job.stamp, self.frame_ids[job.stamp])
        with self._lock:
            first = job.stamp not in self._published
            if not first and not job.again:  # another worker's depth came (and was mirrored) meanwhile
                self.get_logger().info(f'keyframe {job.stamp} ns: refined by another worker meanwhile')
                return True
            self._published.add(job.stamp)
            self._others.pop(job.stamp, None)
        self.pub_depth.publish(msg_utils.depth_m_to_image(r.depth, header))
        info = msg_utils.pinhole_to_camera_info(job.view.camera, header)
        self.pub_info.publish(info)
        if first:
            self._publish_keyframe(job.stamp, job.view)
        if self.debug:
            out = {
                'depth/mvs': msg_utils.depth_m_to_image(r.mvs, header),
                'depth/mono_remapped': msg_utils.depth_m_to_image(r.mono_remapped, header),
                'depth/sky_mask': msg_utils.numpy_to_image(r.sky.astype(np.uint8) * 255, 'mono8', header),
                'depth/preview': msg_utils.numpy_to_image(colourise(r.depth), 'rgb8', header),
                'depth/mvs/preview': msg_utils.numpy_to_image(colourise(r.mvs), 'rgb8', header),
            }
            for name, msg in out.items():
                self.debug[name].publish(msg)
        again = ' again' if job.again else ''
        self.refine_times.append(t2 - t0)
        flags = f', flags {",".join(r.flags)}' if r.flags else ''
        self.get_logger().info(
            f'refined{again} keyframe {job.stamp} ns with {n} neighbours in {t2 - t0:.2f} s '
            f'(MVS {t1 - t0:.2f} s, refine {t2 - t1:.2f} s; MVS completeness {r.mvs_completeness:.2f}, '
            f'range {rng[0]:.1f}-{rng[1]:.1f} {self.unit}{flags})'
        )
        return True

    def destroy_node(self) -> None:
        """Stop the worker once its current step (an MVS sweep, an SfM registration) is done: a process
        that exits under pycolmap's or numba's threads aborts (std::terminate)."""
        self._stop.set()
        self._wake.set()
        self._worker.join(timeout=0.5)
        if self._worker.is_alive():
            print(f'{self.get_name()}: stopping after the current refinement step', file=sys.stderr)
            self._worker.join(timeout=STOP_TIMEOUT_S)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(DepthRefinerNode, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
