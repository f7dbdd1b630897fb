# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``depth_refiner``: MVS + refined depth for every keyframe, shardable over several processes.

Topics, parameters and behaviour: the ``depth_refiner`` section of ``doc/nodes.md`` (generated from
:data:`~ibr_ros.node_config.depth_refiner.DEPTH_REFINER`). The policy is in core:
:class:`~ibr_ros.core.depth.schedule.RefineScheduler` (which keyframe, when, with which
neighbours; shared with ``ibr process``), :func:`~ibr_ros.core.depth.refine.refine_job` (MVS, then
refinement), :class:`~ibr_ros.core.registration.trigger.SfmTrigger` (SfM mode) and
:class:`~ibr_ros.core.flight.status.ShardMembership` (live workers). This node converts messages,
keeps the keyframes and publishes.

The heavy work (MVS, refinement, SfM registration) runs on one worker thread; the executor thread
only stores messages.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

import msg_utils
from ibr_ros.core.depth.colour import colour_depth
from ibr_ros.core.depth.job_mvs import PhotometricCache
from ibr_ros.core.depth.mono import MonoModelError
from ibr_ros.core.depth.mvs import MvsView
from ibr_ros.core.depth.refine import DepthRefiner, RefinerConfig, known_depth, refine_job
from ibr_ros.core.depth.schedule import RefineJob, RefineScheduler
from ibr_ros.core.diagnostics import Queue
from ibr_ros.core.flight.status import FlightStatus, ShardMembership
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.registration.sfm import SfmError
from ibr_ros.core.registration.sfm_session import SfmSession
from ibr_ros.core.registration.trigger import SfmMode, SfmTrigger
from ibr_ros.errors import UserError
from ibr_ros.jobs.warmup import warm_up_refiner
from ibr_ros.node_config.depth_refiner import DEBUG_TOPICS, DEPTH_REFINER
from ibr_ros.node_config.table import Value
from ibr_ros.nodes.common import (
    BAD_MESSAGE,
    BadInput,
    StampAssembler,
    declare_table,
    latched_qos,
    model_qos,
    reliable_qos,
    run_node,
    size_mismatch,
    start_diagnostics,
    subscribe_field,
)

#: Longest wait at shutdown for the worker's current step (an SfM registration of a long flight).
STOP_TIMEOUT_S = 120.0


class DepthRefinerNode(Node):
    """Keyframe depth refinement node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('depth_refiner')
        values = declare_table(self, DEPTH_REFINER)
        cfg = DEPTH_REFINER.build(values)
        for note in cfg.notes:
            self.get_logger().info(note)
        self.config = cfg
        self.num_workers, self.worker_index = cfg.schedule.num_workers, cfg.schedule.worker_index
        self.flush_after_s = cfg.flush_after_s
        self.mirror = cfg.mirror_model
        self.max_pending = cfg.max_pending
        self.schedule = RefineScheduler(cfg.schedule)
        self.photometric = PhotometricCache.for_flight(cfg.schedule.reuse_neighbour_depth)
        self.trigger = SfmTrigger(cfg.sfm)
        self.sfm = SfmSession(scale_hint=cfg.sfm.scale, max_side=cfg.sfm.max_side, redefine=False)
        self.unit = 'm'  # of poses and depth: 'sfm units' in an SfM frame without a scale
        self.sfm_times: list[float] = []
        self._sfm_views: dict[int, tuple[np.ndarray, PinholeCamera, str]] = {}  # image, camera, frame_id
        self.refiner = self._make_refiner(cfg.refiner, values)
        self.bad = BadInput(self)
        self.frames = StampAssembler(
            ('image', 'camera_info', 'pose'),
            self.max_pending,
            lambda detail: self.bad('incomplete', detail),
            what='keyframe',
            max_bytes=cfg.max_pending_bytes,
        )
        self.frame_ids: dict[int, str] = {}  # header frame_id of each scheduled keyframe
        self.pose_frames: dict[int, str] = {}  # frame_id of each keyframe's pose (posed flights)
        self.refine_times: list[float] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._version = 0
        self._last_arrival = time.monotonic()
        self.flight: FlightStatus | None = None  # the frame_subsampler's latest status
        self._ended = False  # the camera stream ended: flush
        self._published: set[int] = set()  # stamps whose depth this process published (own or mirrored)
        self._others: dict[int, dict[str, object]] = {}  # depth messages of other workers, by stamp
        self._mirrored: dict[int, bool] = {}  # stamps mirrored here -> whether with their confidence
        self.model_bytes = 0  # of the keyframe images in the schedule
        self.diag = start_diagnostics(self, DEPTH_REFINER.diagnostics, self._diagnostics)
        self._create_topics()
        if cfg.warmup:
            seconds = warm_up_refiner(cfg.mvs, self.refiner)
            self.get_logger().info(f'warm-up MVS + refinement in {seconds:.2f} s')
        # The lease of workers never heard from starts with the first keyframe message, not at start-up.
        self.members = ShardMembership(self.num_workers, self.worker_index, cfg.worker_lease_s)
        self._live = self.members.live(time.monotonic())
        self._worker = threading.Thread(target=self._work, name='depth_refiner_worker', daemon=True)
        self._worker.start()
        self.get_logger().info(
            f'worker {self.worker_index}/{self.num_workers}: refining keyframes with >= '
            f'{cfg.schedule.min_neighbours} of up to {cfg.mvs.max_neighbours} neighbours; '
            f'depth range {cfg.schedule.depth_range or "automatic"}; SfM mode {self.sfm_mode}'
        )

    def _create_topics(self) -> None:
        """Subscriptions, publishers and the heartbeat timer of this configuration."""
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
            subscribe_field(
                self, msg_type, f'keyframes/{field}', qos, field, convert, self._put, self.bad, self.diag
            )
        self.pub_pose = (
            self.create_publisher(PoseStamped, 'keyframes/pose', qos) if self.sfm_mode != 'off' else None
        )
        self.pub_depth = self.create_publisher(Image, 'keyframes/depth', qos)
        self.pub_info = self.create_publisher(CameraInfo, 'keyframes/depth/camera_info', qos)
        self.pub_conf = self.create_publisher(Image, 'keyframes/depth/confidence', qos)
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
        for msg_type, topic in (
            (Image, 'keyframes/depth'),
            (CameraInfo, 'keyframes/depth/camera_info'),
            (Image, 'keyframes/depth/confidence'),
        ):
            self.create_subscription(msg_type, topic, partial(self._on_depth, topic), qos)
        if self.num_workers > 1:
            self.pub_beat = self.create_publisher(DiagnosticStatus, 'refiners/heartbeat', reliable_qos())
            self.create_subscription(
                DiagnosticStatus, 'refiners/heartbeat', self._on_heartbeat, reliable_qos()
            )
            self.create_timer(self.config.worker_lease_s / 3, self._beat)
        self.debug = {
            n: self.create_publisher(Image, n, reliable_qos())
            for n in DEBUG_TOPICS
            if self.config.publish_debug
        }

    def _make_refiner(self, config: RefinerConfig, values: Mapping[str, Value]) -> DepthRefiner:
        """The refiner with the monocular and sky backends of the parameters; UserError naming the bad one."""
        mono_spec, sky_spec = config.mono_model, config.sky_model
        try:
            refiner = DepthRefiner(config)  # loads the mono model first, then the sky model
        except MonoModelError as exc:
            if mono_spec is not None and str(exc).startswith(str(mono_spec.path)):
                bad, path = f'mono_model {values["mono_model"]!r}', mono_spec.path
            else:
                spec = sky_spec or mono_spec
                bad, path = f'sky_model {values["sky_model"]!r}', spec.path if spec is not None else None
            raise UserError(f'parameter {bad}: {str(exc).removeprefix(f"{path}: ")}') from exc
        used = [f'mono {config.mono}' + (f' ({mono_spec.path.name})' if mono_spec and mono_spec.path else '')]
        used.append(f'sky {config.sky}' + (f' ({sky_spec.path.name})' if sky_spec and sky_spec.path else ''))
        self.get_logger().info(f'depth refinement with {", ".join(used)}')
        return refiner

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        with self._lock:
            queues = {
                'pending_keyframes': Queue(len(self.frames), self.frames.max_pending),
                'pending_bytes': Queue(self.frames.pending_bytes, self.frames.max_bytes or 0),
                'unrefined': Queue(len(self.schedule.unrefined())),
                'sfm_queue': Queue(len(self.trigger.queue)),
                'mirror_pending': Queue(len(self._others), self.max_pending),
            }
            model = {
                'keyframes': len(self.schedule),
                'refined': len(self.schedule.refined()),
                'published': len(self._published),
                'bytes': self.model_bytes,
                'sfm_mode': self.sfm_mode,
                'sfm_active': str(self.sfm_active).lower(),
            }
        return {'rejected': self.bad.counts, 'queues': queues, 'model': model}

    # -- SfM mode state (the SfmTrigger's), by the names the tests and the log use ------------------
    @property
    def sfm_mode(self) -> SfmMode:
        """'auto', 'always' or 'off' (the parameter; 'auto' acts as 'off' with num_workers > 1)."""
        return self.trigger.mode

    @property
    def sfm_active(self) -> bool:
        """SfM mode: keyframes without poses are registered here."""
        return self.trigger.active

    @property
    def poses_seen(self) -> int:
        return self.trigger.poses_seen

    @property
    def _sfm_queue(self) -> list[int]:
        """Stamps of keyframes waiting for SfmSession.add()."""
        return self.trigger.queue

    @property
    def _poseless(self) -> set[int]:
        """Frames with image and camera_info before any pose was seen."""
        return self.trigger.waiting

    @_poseless.setter
    def _poseless(self, stamps: set[int]) -> None:
        self.trigger.waiting = set(stamps)

    # -- input ----------------------------------------------------------------------------------
    def _put(self, stamp: int, field: str, value: object) -> None:
        self.members.data_arrived(time.monotonic())
        with self._lock:
            if stamp in self.schedule or stamp in self._sfm_views:
                return  # a keyframe already here, again (a mirror's copy, a late duplicate)
            if field == 'pose' and not self.trigger.pose():
                return  # SfM mode: this node's own poses (or another source's, which it ignores)
        if (f := self.frames.put(stamp, field, value)) is None:
            partial = self.frames.partial(stamp)
            if 'image' in partial and 'camera_info' in partial:
                self._without_pose(stamp, partial)
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
            self.model_bytes += image.nbytes
            self.diag.started(stamp)
            self._version += 1
            self._last_arrival = time.monotonic()
        self._mirror(stamp)  # another worker's depth may have come first
        self._wake.set()

    def _without_pose(self, stamp: int, partial: dict[str, object]) -> None:
        """A keyframe with image and camera_info but no pose: registered in SfM mode, else it waits."""
        with self._lock:
            register = self.trigger.active
            third = not register and self.trigger.wait_for_pose(stamp)
        if register:
            self.frames.discard(stamp)
            # the assembler's fields: an rgb array and (frame_id, camera), as their converters make them
            self._add_poseless(stamp, partial['image'], *partial['camera_info'])  # type: ignore[arg-type,misc]
        elif third:
            self.get_logger().info(
                'keyframes arrive before their keyframes/pose: '
                + (
                    'frames without poses are not refined (sfm_mode off)'
                    if self.sfm_mode == 'off'
                    else 'waiting for their poses (SfM mode starts only when keyframes/status '
                    'says the flight has no poses)'
                )
            )

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
            self.trigger.add(stamp)
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
        with self._lock:
            decision = self.trigger.status(status.pose_source)
        if decision == 'keep_poses':
            self.get_logger().warning(
                'keyframes/status says the flight has no poses, but poses arrived: staying with them'
            )
        elif decision == 'start':
            self._start_sfm()
        elif decision == 'keep_sfm':
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
        """SfM mode started ('auto', a flight without poses): register the waiting keyframes first."""
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
        """Depth (its camera_info, its confidence) on keyframes/depth: another worker's is noted and
        mirrored once; a confidence that comes after its depth was mirrored follows it."""
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        with self._lock:
            late = topic == 'keyframes/depth/confidence' and self._mirrored.get(stamp) is False
            if late:
                self._mirrored[stamp] = True
            if stamp in self._published:  # this process's own (or already mirrored): no decoding
                self._others.pop(stamp, None)
                if not late:
                    return
        if late:
            self.pub_conf.publish(msg)
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
            both = 'keyframes/depth' in rec and 'keyframes/depth/camera_info' in rec
            if view is None or not both or stamp in self._published:
                return
            self._published.add(stamp)
            del self._others[stamp]
            conf = rec.get('keyframes/depth/confidence')
            self._mirrored[stamp] = conf is not None
        if conf is not None:
            self.pub_conf.publish(conf)
        self.pub_depth.publish(rec['keyframes/depth'])
        self.pub_info.publish(rec['keyframes/depth/camera_info'])
        self.diag.published('mirrored')
        self.diag.discard(stamp)  # its depth is another worker's
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
        return self.trigger.due(flush, registered=len(self.sfm), framed=self.sfm.frame is not None)

    def _register(self) -> None:
        """Run one SfM update over all pose-less keyframes; publish and schedule the new poses (worker)."""
        with self._lock:
            queue = self.trigger.take()
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
                self.photometric.clear()
            self.unit = 'sfm units'
        world = 'map' if u.frame == 'enu' else 'sfm'
        with self._lock:
            for stamp in u.new:
                image, camera, frame_id = self._sfm_views[stamp]
                t_wc = u.poses[stamp]
                if t_wc is None or self.pub_pose is None:  # cannot happen: new keyframes are registered
                    self.bad('sfm', f'keyframe {stamp} ns: SfM reported it new without a pose')
                    continue
                self.pub_pose.publish(msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp, frame_id=world))
                self.diag.published('sfm_pose')
                if self.schedule.add(stamp, MvsView(image, camera, t_wc)):
                    self.model_bytes += image.nbytes
                    self.diag.started(stamp)
                self.frame_ids[stamp] = frame_id
            if len(u.points):  # they bound each keyframe's depth range and seed its depth from now on
                self.schedule.set_points(u.points, u.observed_points(self.sfm.stamps))
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
        n, rng = len(job.neighbours), job.depth_range
        result = refine_job(self.refiner, job, self.schedule.config.mvs, self.photometric)
        if self._stop.is_set():
            return False
        if (r := result.refined) is None:
            self.bad('refine', f'keyframe {job.stamp} ns ({result.context}): {result.error}')
            return False
        header = msg_utils.make_header(job.stamp, self.frame_ids[job.stamp])
        depth_msg = msg_utils.depth_m_to_image(r.depth, header)  # built before the stamp counts as published
        conf_msg = None if r.confidence is None else msg_utils.confidence_to_image(r.confidence, header)
        with self._lock:
            first = job.stamp not in self._published
            if not first and not job.again:  # another worker's depth came (and was mirrored) meanwhile
                self.get_logger().info(f'keyframe {job.stamp} ns: refined by another worker meanwhile')
                return True
            self._published.add(job.stamp)
            self._others.pop(job.stamp, None)
        if conf_msg is not None:  # before the depth: a renderer has it when the depth arrives
            self.pub_conf.publish(conf_msg)
        self.pub_depth.publish(depth_msg)
        info = msg_utils.pinhole_to_camera_info(job.view.camera, header)
        self.pub_info.publish(info)
        self.diag.published('depth')
        self.diag.finished(job.stamp)
        if first:
            self._publish_keyframe(job.stamp, job.view)
        if self.debug:
            out = {
                'depth/mvs': msg_utils.depth_m_to_image(r.mvs, header),
                'depth/mono_remapped': msg_utils.depth_m_to_image(r.mono_remapped, header),
                'depth/sky_mask': msg_utils.numpy_to_image(r.sky.astype(np.uint8) * 255, 'mono8', header),
                'depth/preview': msg_utils.numpy_to_image(colour_depth(r.depth), 'rgb8', header),
                'depth/mvs/preview': msg_utils.numpy_to_image(colour_depth(r.mvs), 'rgb8', header),
            }
            for name, msg in out.items():
                self.debug[name].publish(msg)
        again = ' again' if job.again else ''
        self.refine_times.append(result.seconds)
        flags = f', flags {",".join(r.flags)}' if r.flags else ''
        t = result.timings_s
        self.get_logger().info(
            f'refined{again} keyframe {job.stamp} ns with {n} neighbours in {result.seconds:.2f} s '
            f'(MVS {t["mvs"]:.2f} s, refine {t["refine"]:.2f} s; MVS completeness {r.mvs_completeness:.2f}, '
            f'range {rng[0]:.1f}-{rng[1]:.1f} {self.unit}'
            f'{" from the sparse points" if job.plausible else ""}'
            f'{f", {r.implausible} px outside it made unknown" if r.implausible else ""}{flags})'
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
