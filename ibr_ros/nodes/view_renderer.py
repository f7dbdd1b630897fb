# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``view_renderer``: answers novel-view queries from the keyframe model.

Subscribes (reliable, transient local, so a renderer started late or restarted receives the whole
model already published): ``keyframes/image`` (``sensor_msgs/Image``), ``keyframes/camera_info``,
``keyframes/pose`` (``geometry_msgs/PoseStamped``) and ``keyframes/depth`` (``32FC1`` metres or
``16UC1`` mm), matched by stamp. A keyframe joins the model once all four arrived; a newer depth for
it (a refiner's ``refine_again``) replaces the old one; copies of what the model holds (refiners
mirror the model) are ignored, and a depth with no known value is rejected (counted, WARN), never
swapped in for a good one. Superpixels and warp data of a new view are
computed when it arrives (:meth:`~ibr_ros.core.render.renderer.NovelViewRenderer.prepare`), not on a query.

Queries: ``novel_view/query`` (``geometry_msgs/PoseStamped``, reliable): camera-to-world pose of
the desired optical frame in the model's frame (``map``; an empty frame_id is taken as it).
Replies (reliable): ``novel_view/image`` (``rgb8``, black where nothing was rendered), the same as
JPEG on ``novel_view/image/compressed`` (``jpeg_quality``, 0 = off) and ``novel_view/camera_info``,
all with the query's header stamp so that clients can match them.
Output intrinsics: ``width`` x ``height`` with ``hfov_deg``; each 0 takes the latest keyframe's
(all three 0: the keyframe camera itself, distortion dropped). They may be changed at run time
(``ros2 param set``, ``ibr query --width/--height/--hfov``).

Every query gets exactly one ``novel_view/status`` (``diagnostic_msgs/DiagnosticArray``, reliable,
the query's stamp, published after the image if there is one) holding one ``DiagnosticStatus``
(:class:`~ibr_ros.core.render.reply.ReplyStatus`): level OK ``answered``, WARN ``incomplete`` or
ERROR ``refused`` (no image), the reason, the rendered fraction ``valid_fraction``, the views used
and the render time, so that a client never waits for an image that will not come and never takes
a torn view for a good one. A query is answered only when at least ``min_valid_fraction`` of the
pixels were rendered (the default is measured: ``bench/README.md``, section Valid fraction); a
view below it is not published (refused, reason ``incomplete``) unless ``publish_incomplete`` is
set, then it is published and its status says ``incomplete``.

Queries are answered newest first: before rendering, the node takes every query already waiting in
its subscription; each is checked (no model, another frame, invalid or unrenderable pose: counted
by reason) and only the newest renderable one is rendered, the others counted as ``superseded`` and
logged, so an overloaded renderer answers the latest pose instead of falling ever further behind.
Refused queries (no model yet, invalid pose, another frame, farther than the renderer's distance
limit, facing away from every view, superseded, too incomplete, a renderer error) get their status
only: each is counted per reason and logged (throttled per reason).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.core.depth.refine import known_depth
from ibr_ros.core.diagnostics import Queue
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render import NovelViewRenderer, ReplyStatus, SourceView, output_camera
from ibr_ros.jobs.warmup import warm_up_renderer
from ibr_ros.node_config.view_renderer import INTRINSICS, VIEW_RENDERER
from ibr_ros.nodes.common import (
    BAD_MESSAGE,
    BadInput,
    StampAssembler,
    declare_table,
    model_qos,
    reliable_qos,
    run_node,
    start_diagnostics,
    subscribe_field,
)


class ViewRenderer(Node):
    """Novel-view rendering node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('view_renderer')
        cfg = VIEW_RENDERER.build(declare_table(self, VIEW_RENDERER))
        self.width, self.height, self.hfov = cfg.width, cfg.height, cfg.hfov_deg
        self.policy = cfg.reply
        self.frame_id = cfg.frame_id
        self.max_keyframes = cfg.max_keyframes
        self.config = cfg.render
        self.renderer = NovelViewRenderer([], self.config)
        self.bad = BadInput(self)
        self.unanswered = BadInput(self)
        self.frames = StampAssembler(  # keyframes not in the model yet; model + pending <= max_keyframes
            ('image', 'camera_info', 'pose', 'depth'),
            self.max_keyframes,
            lambda detail: self.bad('incomplete', detail),
            what='keyframe',
            max_bytes=cfg.max_pending_bytes,
        )
        self.indices: dict[int, int] = {}  # stamp -> view index in the renderer
        self.confidence: dict[int, np.ndarray] = {}  # stamp -> depth confidence (keyframes/depth/confidence)
        self.model_frame = ''
        self.latest_camera: PinholeCamera | None = None
        self.answered = 0
        self.incomplete = 0  # published below min_valid_fraction (publish_incomplete)
        self.latencies: list[float] = []
        self.diag = start_diagnostics(self, VIEW_RENDERER.diagnostics, self._diagnostics)
        qos = model_qos()
        for msg_type, field, convert in (
            (Image, 'image', lambda m: np.array(msg_utils.image_to_rgb(m))),
            (CameraInfo, 'camera_info', msg_utils.camera_info_to_pinhole),
            (
                PoseStamped,
                'pose',
                lambda m: (msg_utils.pose_stamped_to_matrix(m), m.header.frame_id or 'map'),
            ),
            (Image, 'depth', lambda m: np.array(msg_utils.depth_image_to_m(m))),
        ):
            subscribe_field(
                self, msg_type, f'keyframes/{field}', qos, field, convert, self._put, self.bad, self.diag
            )
        subscribe_field(
            self, Image, 'keyframes/depth/confidence', qos, 'confidence',
            lambda m: np.array(msg_utils.image_to_confidence(m)), self._on_confidence, self.bad, self.diag,
        )  # fmt: skip
        self._query_sub = self.create_subscription(
            PoseStamped, 'novel_view/query', self._on_query_msg, reliable_qos(100)
        )
        self.pub_image = self.create_publisher(Image, 'novel_view/image', reliable_qos())
        self.pub_info = self.create_publisher(CameraInfo, 'novel_view/camera_info', reliable_qos())
        self.jpeg_quality = cfg.jpeg_quality
        self.pub_jpeg = (
            self.create_publisher(CompressedImage, 'novel_view/image/compressed', reliable_qos())
            if self.jpeg_quality
            else None
        )
        # As deep as the query queue: one callback may refuse every query waiting (superseded) at once.
        self.pub_status = self.create_publisher(DiagnosticArray, 'novel_view/status', reliable_qos(100))
        self.add_on_set_parameters_callback(self._on_params)
        if cfg.warmup:
            self._warmup()

    def _on_params(self, params: list[Parameter]) -> SetParametersResult:
        """Adopt new output intrinsics; rclpy has already checked them against their declared ranges."""
        new = {prm.name: prm.value for prm in params if prm.name in INTRINSICS}
        self.width = int(new.get('width', self.width))
        self.height = int(new.get('height', self.height))
        self.hfov = float(new.get('hfov_deg', self.hfov))
        return SetParametersResult(successful=True)

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        views = self.renderer.views
        arrays = [a for v in views for a in (v.rgb, v.depth, v.confidence) if a is not None]
        return {
            'rejected': self.bad.counts
            + Counter({f'query.{r}': n for r, n in self.unanswered.counts.items()}),
            'queues': {
                'pending_keyframes': Queue(len(self.frames), self.max_keyframes),
                'pending_bytes': Queue(self.frames.pending_bytes, self.frames.max_bytes or 0),
            },
            'model': {
                'keyframes': len(self.indices),
                'max_keyframes': self.max_keyframes,
                'usable': sum(self.renderer.skip_reason(i) is None for i in range(len(views))),
                'bytes': sum(a.nbytes for a in arrays),
            },
        }

    def _warmup(self) -> None:
        seconds = warm_up_renderer(self.config)
        self.get_logger().info(f'warm-up render in {seconds:.2f} s')

    # -- model ----------------------------------------------------------------------------------
    def _put(self, stamp: int, field: str, value: Any) -> None:
        if field == 'depth' and not known_depth(value):
            self.bad('depth_unknown', f'keyframe {stamp} ns: a depth with no known value, rejected')
            return
        if stamp in self.indices:  # image, camera_info and pose are fixed once a keyframe is in the model
            if field == 'depth':
                v = self.renderer.views[self.indices[stamp]]
                if v.depth is not None and np.array_equal(v.depth, value, equal_nan=True):
                    return  # a mirror's copy of the depth the model has
                self._update(
                    stamp, {'image': v.rgb, 'camera_info': v.camera, 'pose': (v.t_wc, ''), 'depth': value}
                )
            return
        free = self.max_keyframes - len(self.indices)
        if free <= 0:
            self.bad(
                'model_full', f'model full ({self.max_keyframes} keyframes): keyframe {stamp} ns dropped'
            )
            return
        self.frames.max_pending = free
        if (record := self.frames.put(stamp, field, value)) is not None:
            self._update(stamp, record)

    def _on_confidence(self, stamp: int, field: str, value: np.ndarray) -> None:
        """A depth confidence: kept for its keyframe (optional: without one the depth counts as sure)."""
        if stamp in self.indices:
            v = self.renderer.views[self.indices[stamp]]
            if v.confidence is not None and np.array_equal(v.confidence, value):
                return  # a mirror's copy
            if v.depth is not None and value.shape != v.depth.shape:
                self.bad(
                    'size',
                    f'keyframe {stamp} ns: confidence {value.shape[::-1]}, depth {v.depth.shape[::-1]}',
                )
                return
            self.confidence[stamp] = value  # superpixels and warp model stay; only the blend weights change
            self.renderer.set_confidence(self.indices[stamp], value)
            return
        self.confidence[stamp] = value
        while len(self.confidence) > 2 * self.max_keyframes:  # of keyframes that never came
            dropped = min(s for s in self.confidence if s not in self.indices)
            del self.confidence[dropped]
            self.bad('confidence', f'confidence of keyframe {dropped} ns dropped: its keyframe did not come')

    def _update(self, stamp: int, kf: dict[str, Any]) -> None:
        """Add complete keyframe ``kf`` to the model or replace its depth (a bad one waits for another)."""
        rgb, cam, (pose, frame), depth = kf['image'], kf['camera_info'], kf['pose'], kf['depth']
        replaced = stamp in self.indices
        problem = None
        if rgb.shape[:2] != (cam.height, cam.width) or depth.shape != (cam.height, cam.width):
            problem = (
                'size',
                f'keyframe {stamp} ns: image {rgb.shape[1]}x{rgb.shape[0]}, depth '
                f'{depth.shape[1]}x{depth.shape[0]}, camera_info {cam.width}x{cam.height}',
            )
        elif not replaced and self.model_frame and frame != self.model_frame:
            problem = ('frame', f'keyframe {stamp} ns is in {frame!r}, the model in {self.model_frame!r}')
        if problem is not None:
            self.bad(*problem)
            if not replaced:  # keep image, camera_info and pose waiting for another depth
                for field in ('image', 'camera_info', 'pose'):
                    self.frames.put(stamp, field, kf[field])
            return
        if not replaced:
            self.model_frame = frame
        t0 = time.perf_counter()
        conf = self.confidence.get(stamp)
        if conf is not None and conf.shape != depth.shape:
            self.bad('size', f'keyframe {stamp} ns: confidence {conf.shape[::-1]}, depth {depth.shape[::-1]}')
            del self.confidence[stamp]  # dropped (counted): the depth counts as sure
            conf = None
        view = SourceView(rgb, depth, cam, pose, name=str(stamp), stamp=stamp * 1e-9, confidence=conf)
        if replaced:
            index = self.indices[stamp]
            self.renderer.replace_view(index, view)
        else:
            index = self.indices[stamp] = self.renderer.add_view(view)
            self.latest_camera = cam
        self.renderer.prepare([index])
        usable = self.renderer.skip_reason(index)
        self.get_logger().info(
            f'{"updated" if replaced else "added"} keyframe {stamp} ns '
            f'({len(self.renderer.views)} in the model{"; unusable: " + usable if usable else ""}; '
            f'prepared in {time.perf_counter() - t0:.2f} s)'
        )

    # -- queries --------------------------------------------------------------------------------
    def _on_query_msg(self, msg: PoseStamped) -> None:
        """Answer the newest renderable query of those waiting (see module docstring)."""
        self.diag.received('query')
        newest = self._check(msg)
        while True:  # the queries that arrived meanwhile, oldest first
            with self._query_sub.handle:
                taken = self._query_sub.handle.take_message(PoseStamped, False)
            if taken is None:
                break
            self.diag.received('query')
            if (query := self._check(taken[0])) is None:
                continue
            if newest is not None:
                self._refuse(
                    newest[0],
                    'superseded',
                    f'superseded by query {query[0]} ns before it was rendered (queries arrive faster '
                    'than they render)',
                )
            newest = query
        if newest is not None:
            self._answer(*newest)

    def _check(self, msg: PoseStamped) -> tuple[int, np.ndarray, float] | None:
        """``(stamp, T_wc, arrival)`` of a query that can be rendered; else None (refused)."""
        t0 = time.perf_counter()
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        if self.latest_camera is None:
            self._refuse(stamp, 'no_model', 'no keyframe with depth received yet')
            return None
        frame = msg.header.frame_id or self.model_frame
        if frame != self.model_frame:
            self._refuse(stamp, 'frame', f'the query is in {frame!r}, the model in {self.model_frame!r}')
            return None
        try:
            t_wc = msg_utils.pose_stamped_to_matrix(msg)
        except BAD_MESSAGE as exc:
            self._refuse(stamp, 'invalid_query', str(exc))
            return None
        if (reason := self.renderer.refusal(t_wc)) is not None:
            self._refuse(stamp, 'unrenderable', reason)
            return None
        return stamp, t_wc, t0

    def _refuse(self, stamp: int, reason: str, detail: str) -> None:
        """Count and log refused query ``stamp`` and publish its status (ERROR, no image follows)."""
        self.unanswered(reason, f'query {stamp} ns: {detail}')
        self._publish_status(stamp, self.policy.refuse(reason, detail))

    def _publish_status(self, stamp: int, status: ReplyStatus) -> None:
        header = msg_utils.make_header(stamp, self.frame_id)
        name = self.get_fully_qualified_name()
        self.pub_status.publish(msg_utils.reply_to_diagnostics(status, header, name=name))
        self.diag.published('status')

    def _answer(self, stamp: int, t_wc: np.ndarray, t0: float) -> None:
        """Render query ``stamp`` that arrived at ``t0`` (perf_counter); publish the view if the policy
        lets it through, and its status."""
        if self.latest_camera is None:  # _check answers no query before the first keyframe
            return
        t1 = time.perf_counter()
        try:
            camera = output_camera(self.width, self.height, self.hfov, self.latest_camera)
            out = self.renderer.render(t_wc, camera)
        except BAD_MESSAGE as exc:
            self._refuse(stamp, 'invalid_query', str(exc))
            return
        except Exception as exc:  # a renderer bug must not take the model down with it
            self._refuse(stamp, 'render_error', repr(exc))
            return
        if out.reason is not None:
            self._refuse(stamp, 'unrenderable', out.reason)
            return
        views = [self.renderer.views[i].name for i in out.used_views]
        status = self.policy.judge(float(out.valid.mean()), views, 1e3 * (time.perf_counter() - t1))
        if not status.published:
            self.unanswered('incomplete', f'query {stamp} ns: {status.message}')
            self._publish_status(stamp, status)
            return
        header = msg_utils.make_header(stamp, self.frame_id)
        self.pub_image.publish(msg_utils.numpy_to_image(out.rgb, 'rgb8', header))
        if self.pub_jpeg is not None and self.pub_jpeg.get_subscription_count() > 0:  # encoded on demand
            jpeg = msg_utils.numpy_to_compressed_image(out.rgb, quality=self.jpeg_quality, header=header)
            self.pub_jpeg.publish(jpeg)
        self.pub_info.publish(msg_utils.pinhole_to_camera_info(camera, header))
        self.diag.published('image')
        self.diag.measured(time.perf_counter() - t0)
        self._publish_status(stamp, status)
        dt = time.perf_counter() - t0
        if status.result == 'answered':
            self.answered += 1
            self.latencies.append(dt)
            self.get_logger().info(
                f'query {stamp} ns answered in {1e3 * dt:.0f} ms ({status.message} from views {views})'
            )
        else:
            self.incomplete += 1
            self.get_logger().warning(
                f'query {stamp} ns: {status.message} ({self.incomplete} so far), in {1e3 * dt:.0f} ms '
                f'from views {views}'
            )


def main(args: list[str] | None = None) -> int:
    return run_node(ViewRenderer, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
