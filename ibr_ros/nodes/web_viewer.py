# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``web_viewer``: fly through the model from a web browser.

Topics, parameters and behaviour: ``doc/nodes.md`` (generated from
:data:`ibr_ros.node_config.WEB_VIEWER`); the flying, the map and the newest-only gates:
:mod:`ibr_ros.core.navigation`; the HTTP/WebSocket server and the page: :mod:`ibr_ros.web`. This
node does the ROS side: it hands keyframe poses and the replies to its own queries to the server
(which runs its asyncio loop in a thread beside the executor), encodes those views as JPEG and
publishes the queries the server makes. SIGINT/SIGTERM stop the executor, then the server.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import Image

import msg_utils
from ibr_ros.core.diagnostics import Queue
from ibr_ros.core.navigation import Query
from ibr_ros.io.atomic import write_atomic
from ibr_ros.node_config.web_viewer import WEB_VIEWER
from ibr_ros.nodes.common import (
    BAD_MESSAGE,
    BadInput,
    declare_table,
    model_qos,
    reliable_qos,
    run_node,
    start_diagnostics,
)
from ibr_ros.web import ViewerServer


class WebViewer(Node):
    """Web viewer node (see module docstring)."""

    def __init__(self) -> None:
        super().__init__('web_viewer')
        self.cfg = WEB_VIEWER.build(declare_table(self, WEB_VIEWER))
        self.bad = BadInput(self)
        self._lock = threading.Lock()
        self._ours: set[int] = set()  # stamps of this viewer's queries whose replies are awaited
        self.model_frame = ''  # the keyframe poses' frame (queries go in it unless query_frame is set)
        self.server = ViewerServer(self.cfg, self._publish, self._forget, self.bad, self.get_logger())
        self.create_subscription(PoseStamped, 'keyframes/pose', self._on_pose, model_qos())
        self.create_subscription(Image, 'novel_view/image', self._on_image, reliable_qos())
        self.create_subscription(DiagnosticArray, 'novel_view/status', self._on_status, reliable_qos(100))
        self.pub = self.create_publisher(PoseStamped, 'novel_view/query', reliable_qos())
        self.diag = start_diagnostics(self, WEB_VIEWER.diagnostics, self._diagnostics)
        url = self.server.start()
        if self.cfg.url_file:
            write_atomic(Path(self.cfg.url_file), url + '\n')
        self.get_logger().info(f'serving the viewer on {url}')

    def _diagnostics(self) -> dict[str, Any]:
        """What ``/diagnostics`` reports besides the events (:func:`start_diagnostics`)."""
        with self._lock:
            in_flight = len(self._ours)
        pages = len(self.server.clients)
        return {
            'rejected': self.bad.counts,
            'queues': {'in_flight': Queue(in_flight, pages)},
            'model': {'keyframes': len(self.server.map.poses), 'pages': pages, 'lost': self.server.lost},
        }

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()

    # -- the server's thread -------------------------------------------------------------------
    def _publish(self, q: Query) -> None:
        with self._lock:
            self._ours.add(q.stamp)
        frame = self.cfg.query_frame or self.model_frame
        self.pub.publish(msg_utils.matrix_to_pose_stamped(q.t_wc, stamp_ns=q.stamp, frame_id=frame))
        self.diag.published('query')
        self.diag.started(q.stamp)

    def _forget(self, stamp: int) -> None:
        with self._lock:
            self._ours.discard(stamp)
        self.diag.discard(stamp)  # no view came (refused, superseded, given up); else already stopped

    def _mine(self, stamp: int) -> bool:
        with self._lock:
            return stamp in self._ours

    # -- the executor's thread -----------------------------------------------------------------
    def _on_pose(self, msg: PoseStamped) -> None:
        self.diag.received('pose')
        try:
            t_wc = msg_utils.pose_stamped_to_matrix(msg)
        except BAD_MESSAGE as exc:
            self.bad('pose', f'keyframes/pose: {exc}')
            return
        frame = msg.header.frame_id or 'map'
        if self.model_frame and frame != self.model_frame:
            self.bad('frame', f'keyframes/pose in {frame!r}, the first ones in {self.model_frame!r}: dropped')
            return
        self.model_frame = frame
        self.server.frame_id = self.cfg.query_frame or frame  # what a saved view's pose says
        self.server.post(self.server.on_keyframe, msg_utils.stamp_to_ns(msg.header.stamp), t_wc)

    def _on_image(self, msg: Image) -> None:
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        if not self._mine(stamp):
            return  # another client's view
        self.diag.received('image')
        self.diag.finished(stamp)
        try:
            rgb = np.array(msg_utils.image_to_rgb(msg))
        except BAD_MESSAGE as exc:
            self.bad('image', f'novel_view/image {stamp} ns: {exc}')
            return
        params = [cv2.IMWRITE_JPEG_QUALITY, self.cfg.jpeg_quality]
        ok, jpeg = cv2.imencode('.jpg', np.ascontiguousarray(rgb[..., ::-1]), params)
        if not ok:
            self.bad('jpeg', f'novel_view/image {stamp} ns: JPEG encoding failed')
            return
        self.server.post(self.server.on_image, stamp, jpeg.tobytes(), rgb)
        self.diag.published('view')

    def _on_status(self, msg: DiagnosticArray) -> None:
        self.diag.received('status')
        try:
            stamp, status = msg_utils.diagnostics_to_reply(msg)
        except msg_utils.MessageError as exc:
            self.bad('status', f'novel_view/status: {exc}')
            return
        if self._mine(stamp):
            self.server.post(self.server.on_status, stamp, status)


def main(args: list[str] | None = None) -> int:
    return run_node(WebViewer, args if args is not None else sys.argv)


if __name__ == '__main__':
    sys.exit(main())
