# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr query``: ask a running ``view_renderer`` for one novel view and save it.

Publishes one ``geometry_msgs/PoseStamped`` on ``novel_view/query`` (orientation from ENU
yaw/pitch/roll in degrees, :func:`ibr_ros.core.geometry.transforms.rotation_from_ypr`) and waits for
the ``novel_view/status`` whose stamp equals the query's. Answered: waits for the ``novel_view/image``
with that stamp, writes it as PNG (atomically) and prints its size, the valid (rendered) fraction and
the round-trip latency; an incomplete view (the renderer's ``publish_incomplete``) is saved too, with a
warning. Refused: prints the reason and the valid fraction, writes nothing. ``--width/--height/--hfov``
set the renderer's output intrinsics first (they are parameters of the renderer node, shared by all
clients). Exit status 1 when refused or on timeout.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic


def _save_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode('.png', cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    if not ok:
        raise UserError(f'{path}: PNG encoding failed')
    write_atomic(path, buf.tobytes())


def _set_intrinsics(node, args: argparse.Namespace, deadline: float) -> None:
    """Set the renderer's width/height/hfov_deg parameters (only those given)."""
    import rclpy
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    values = {'width': args.width, 'height': args.height, 'hfov_deg': args.hfov}
    params = [
        Parameter(k, value=int(v) if k != 'hfov_deg' else float(v)).to_parameter_msg()
        for k, v in values.items()
        if v is not None
    ]
    if not params:
        return
    client = node.create_client(SetParameters, f'{args.renderer.rstrip("/")}/set_parameters')
    if not client.wait_for_service(timeout_sec=max(0.0, deadline - time.monotonic())):
        raise TimeoutError(f'no parameter service of {args.renderer} (is view_renderer running?)')
    future = client.call_async(SetParameters.Request(parameters=params))
    rclpy.spin_until_future_complete(node, future, timeout_sec=max(0.0, deadline - time.monotonic()))
    if not future.done():
        raise TimeoutError(f'{args.renderer} did not answer the parameter request')
    for r in future.result().results:
        if not r.successful:
            raise UserError(f'{args.renderer} refused the intrinsics: {r.reason}')


def run(args: argparse.Namespace) -> int:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Image

    import msg_utils
    from ibr_ros.core.geometry.transforms import matrix_from_rt, rotation_from_ypr
    from ibr_ros.nodes.common import reliable_qos

    rot = rotation_from_ypr(*(math.radians(a) for a in (args.yaw, args.pitch, args.roll)))
    t_wc = matrix_from_rt(rot, [args.x, args.y, args.z])
    out = Path(args.out)
    rclpy.init(args=['ibr', '--ros-args', '-r', f'__ns:={args.namespace}'] if args.namespace else None)
    try:
        node = rclpy.create_node('ibr_query')
        replies: list[Image] = []
        statuses: list[DiagnosticArray] = []
        node.create_subscription(Image, 'novel_view/image', replies.append, reliable_qos())
        node.create_subscription(DiagnosticArray, 'novel_view/status', statuses.append, reliable_qos())
        pub = node.create_publisher(PoseStamped, 'novel_view/query', reliable_qos())
        deadline = time.monotonic() + args.timeout
        _set_intrinsics(node, args, deadline)
        # Wait until the renderer's query reader and reply writers are all matched (no fixed sleeps).
        while time.monotonic() < deadline and (
            pub.get_subscription_count() == 0
            or node.count_publishers('novel_view/image') == 0
            or node.count_publishers('novel_view/status') == 0
        ):
            rclpy.spin_once(node, timeout_sec=0.05)
        if pub.get_subscription_count() == 0:
            print(f'ibr query: no view_renderer subscribed to novel_view/query within {args.timeout:g} s',
                  file=sys.stderr)  # fmt: skip
            return 1
        stamp = node.get_clock().now().nanoseconds
        t0 = time.perf_counter()
        pub.publish(msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp, frame_id=args.frame))

        def mine(box: list) -> Any:
            return next((m for m in box if msg_utils.stamp_to_ns(m.header.stamp) == stamp), None)

        status = reply = None
        while time.monotonic() < deadline and (status is None or (status[1].published and reply is None)):
            rclpy.spin_once(node, timeout_sec=0.02)
            if status is None and (msg := mine(statuses)) is not None:
                status = msg_utils.diagnostics_to_reply(msg)
            reply = mine(replies)
        latency = time.perf_counter() - t0
        if status is None:
            print(f'ibr query: no reply within {args.timeout:g} s (no novel_view/status for the query)',
                  file=sys.stderr)  # fmt: skip
            return 1
        st = status[1]
        share = f'{st.valid_fraction:.1%} rendered (min_valid_fraction {st.min_valid_fraction:g})'
        if not st.published:
            detail = f'only {share}' if st.reason == 'incomplete' else f'{st.message}; {share}'
            print(f'ibr query: refused ({st.reason}): {detail}', file=sys.stderr)
            return 1
        if reply is None:
            print(f'ibr query: the status says answered, but no image came within {args.timeout:g} s',
                  file=sys.stderr)  # fmt: skip
            return 1
        _save_png(out, msg_utils.image_to_rgb(reply))
        print(f'{out}: {reply.width}x{reply.height}, {share}, round trip {1e3 * latency:.1f} ms')
        if st.result == 'incomplete':
            print(f'ibr query: warning: an incomplete view ({st.message})', file=sys.stderr)
        return 0
    except (TimeoutError, msg_utils.MessageError) as exc:
        print(f'ibr query: {exc}', file=sys.stderr)
        return 1
    finally:
        rclpy.try_shutdown()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('query', help='request one novel view from a running view_renderer and save it')
    for axis in ('x', 'y', 'z'):
        p.add_argument(
            f'--{axis}', type=float, required=True, help=f'camera {axis} in the map frame (m, ENU)'
        )
    p.add_argument('--yaw', type=float, default=0.0, help='heading of the optical axis, CCW from east (deg)')
    p.add_argument('--pitch', type=float, default=0.0, help='optical axis up (+) or down (-) (deg)')
    p.add_argument('--roll', type=float, default=0.0, help='rotation about the optical axis (deg)')
    p.add_argument('--frame', default='map', help='frame of the pose (default: map)')
    p.add_argument('--width', type=int, help="set the renderer's output width (px)")
    p.add_argument('--height', type=int, help="set the renderer's output height (px)")
    p.add_argument('--hfov', type=float, help="set the renderer's horizontal field of view (deg)")
    p.add_argument(
        '--renderer', default='/view_renderer', help='renderer node name (for --width/--height/--hfov)'
    )
    p.add_argument('--namespace', default='', help='ROS namespace of the novel_view topics')
    p.add_argument('--out', required=True, help='PNG file to write')
    p.add_argument('--timeout', type=float, default=10.0, help='seconds to wait for the reply (default 10)')
    p.set_defaults(func=run)
