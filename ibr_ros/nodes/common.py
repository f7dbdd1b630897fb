# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Shared plumbing of the ibr_ros nodes: QoS profiles, parameters with descriptors, bad-input
accounting, ``/diagnostics`` (:func:`start_diagnostics`), matching messages by stamp
(:class:`~ibr_ros.core.flight.stamps.StampAssembler`, re-exported) and the process entry point (init,
spin, clean shutdown)."""

from __future__ import annotations

import faulthandler
import logging
import math
import signal
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy._rclpy_pybind11 import RCLError
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.subscription import Subscription
from rclpy.topic_endpoint_info import TopicEndpointInfo

import msg_utils
from ibr_ros.core.diagnostics import AreaStatus, NodeDiagnostics
from ibr_ros.core.flight.stamps import StampAssembler
from ibr_ros.errors import UserError
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Values,
)

__all__ = [
    'BAD_MESSAGE',
    'EXIT_BAD_CONFIG',
    'POSE_MESSAGES',
    'BadInput',
    'StampAssembler',
    'declare_table',
    'input_qos',
    'latched_qos',
    'model_qos',
    'reliable_qos',
    'run_node',
    'sensor_qos',
    'size_mismatch',
    'spin_forever',
    'start_diagnostics',
    'subscribe_field',
]

#: ``pose_type`` -> the message type of ``camera/pose`` and its conversion to a 4x4 ``T_wc``.
POSE_MESSAGES = {
    'pose': (PoseStamped, msg_utils.pose_stamped_to_matrix),
    'odometry': (Odometry, msg_utils.odometry_to_matrix),
}

#: What converting a malformed message raises: :data:`msg_utils.CONVERSION_ERRORS` (the nodes' name).
BAD_MESSAGE = msg_utils.CONVERSION_ERRORS

#: Exit status of a node whose parameters are rejected at start-up.
EXIT_BAD_CONFIG = 2

LOG = logging.getLogger(__name__)


def sensor_qos() -> QoSProfile:
    """Raw camera streams (REP-2003 sensor data): best effort, keep last 5."""
    return qos_profile_sensor_data


def model_qos(depth: int = 1000) -> QoSProfile:
    """Keyframes, depth, camera_info: reliable + transient local, deep enough for the whole model,
    so that a node started late (or restarted) receives everything already published."""
    return QoSProfile(
        history=QoSHistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=QoSReliabilityPolicy.RELIABLE,
        durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
    )


def latched_qos() -> QoSProfile:
    """A status topic: reliable + transient local, the latest message only (a late joiner gets it)."""
    return model_qos(1)


def input_qos(publishers: Sequence[TopicEndpointInfo]) -> tuple[QoSProfile, str]:
    """The QoS to subscribe a stream with, given its ``publishers``, and a note for the log.

    Reliable and keep-all when every publisher offers reliable (a bag replay: nothing is lost, DDS
    flow control holds the publisher back instead); else sensor-data best effort (a camera driver).
    """
    if publishers and all(p.qos_profile.reliability == QoSReliabilityPolicy.RELIABLE for p in publishers):
        qos = QoSProfile(
            history=QoSHistoryPolicy.KEEP_ALL, depth=1, reliability=QoSReliabilityPolicy.RELIABLE
        )
        return qos, 'reliable keep-all: its publishers offer reliable'
    return sensor_qos(), 'best effort: a publisher offers best effort; lost messages are counted'


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Queries and replies: reliable, volatile."""
    return QoSProfile(depth=depth, reliability=QoSReliabilityPolicy.RELIABLE)


def declare_table(node: Node, table: ParamTable[Any]) -> Values:
    """Declare every parameter of ``table`` with its descriptor (range, choices, read-only unless
    dynamic); the values given (params file, ``-p``), checked by the table (UserError naming one)."""
    values = {p.name: _declare_param(node, p) for p in table.params}
    return table.values(values)


def _declare_param(node: Node, p: Param) -> object:
    desc = ParameterDescriptor(name=p.name, description=p.description, read_only=not p.dynamic)
    if p.choices:
        desc.additional_constraints = 'one of: ' + ', '.join(p.choices)
    if p.range is not None and p.kind == 'int':
        desc.integer_range = [IntegerRange(from_value=int(p.range[0]), to_value=int(p.range[1]), step=0)]
    elif p.range is not None and p.kind == 'double':
        desc.floating_point_range = [
            FloatingPointRange(from_value=float(p.range[0]), to_value=float(p.range[1]), step=0.0)
        ]
    if p.kind == 'list' and not p.default:  # rclpy would type [] as a byte array: a string array
        value = node.declare_parameter(p.name, Parameter.Type.STRING_ARRAY, desc).value
        return [] if value is None else value
    return node.declare_parameter(p.name, p.default, desc).value


class BadInput:
    """Counts rejected messages by reason and logs each reason at most every ``throttle_s`` seconds."""

    def __init__(self, node: Node, throttle_s: float = 5.0) -> None:
        self.node = node
        self.counts: Counter[str] = Counter()
        self.throttle_s = throttle_s
        self._last_log: dict[str, float] = {}

    def __call__(self, reason: str, detail: str) -> None:
        """Record one rejected message: ``reason`` is a short key, ``detail`` names field and value."""
        self.counts[reason] += 1
        now = time.monotonic()
        if now - self._last_log.get(reason, -math.inf) >= self.throttle_s:  # throttled per reason
            self._last_log[reason] = now
            self.node.get_logger().warning(
                f'rejected input ({reason}, {self.counts[reason]} so far): {detail}'
            )

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def subscribe_field(
    node: Node,
    msg_type: type,
    topic: str,
    qos: QoSProfile,
    field: str,
    convert: Callable[[Any], Any],
    put: Callable[[int, str, Any], None],
    bad: BadInput,
    diag: NodeDiagnostics | None = None,
) -> Subscription:
    """Subscribe ``topic``; each message goes through ``convert`` and on to ``put(stamp_ns, field, value)``.

    A message that ``convert`` rejects (:data:`BAD_MESSAGE`) is counted and logged by ``bad`` under
    the reason ``field`` and dropped; so are messages DDS reports lost (reason ``lost``, best-effort
    inputs) and publishers whose QoS cannot match (reason ``incompatible_qos``). Every message
    arriving counts as input ``field`` of ``diag``.
    """

    def callback(msg: Any) -> None:
        if diag is not None:
            diag.received(field)
        try:
            value = convert(msg)
        except BAD_MESSAGE as exc:
            bad(field, str(exc))
            return
        put(msg_utils.stamp_to_ns(msg.header.stamp), field, value)

    def lost(status: Any) -> None:
        for _ in range(int(status.total_count_change)):
            bad('lost', f'{topic}: {status.total_count} messages lost by DDS so far (best effort, too slow)')

    events = SubscriptionEventCallbacks(
        message_lost=lost,
        incompatible_qos=lambda s: bad(
            'incompatible_qos', f'{topic}: a publisher offers an incompatible QoS'
        ),
    )
    return node.create_subscription(msg_type, topic, callback, qos, event_callbacks=events)


def start_diagnostics(
    node: Node,
    spec: Diagnostics | None,
    state: Callable[[], dict[str, Any]],
    outputs: Sequence[str] = (),
) -> NodeDiagnostics:
    """The node's :class:`NodeDiagnostics` (streams of ``spec``, placeholders like ``<topic>`` left out,
    plus ``outputs``), published on ``/diagnostics`` every ``diagnostics_period_s`` (a parameter of the
    node's table). ``state()`` gives :meth:`NodeDiagnostics.report`'s ``rejected``, ``queues`` and
    ``model`` at each report. Statuses are named ``<node>: <area>`` (the fully qualified name without
    its leading slash), hardware_id the host name; the array is stamped with the node clock's now.
    """
    if spec is None:
        raise ValueError(f'{node.get_name()}: its parameter table documents no diagnostics')
    concrete = lambda names: [n for n in names if not n.startswith('<')]  # noqa: E731
    diag = NodeDiagnostics(concrete(spec.inputs), [*concrete(spec.outputs), *outputs])
    period = float(node.get_parameter(DIAGNOSTICS_PERIOD.name).value)
    pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC.name, reliable_qos(10))
    name = node.get_fully_qualified_name().lstrip('/')
    host = socket.gethostname()

    def publish() -> None:
        areas: list[AreaStatus] = diag.report(**state())
        header = msg_utils.make_header(node.get_clock().now().nanoseconds, '')
        pub.publish(msg_utils.areas_to_diagnostics(areas, header, node=name, hardware_id=host))

    node.create_timer(period, publish)
    return diag


def spin_forever(node: Node) -> int:
    """The default ``spin`` of :func:`run_node`: until Ctrl-C or shutdown; exit code 0."""
    rclpy.spin(node)
    return 0


def _quiet_half_built(unraisable: Any) -> None:
    """``sys.unraisablehook`` that drops the AttributeError rclpy's ``__del__`` methods raise for an
    object whose ``__init__`` a shutdown interrupted (Executor, RcutilsLogger); reports the rest."""
    obj = getattr(unraisable, 'object', None)
    owner = getattr(obj, '__qualname__', '')
    if isinstance(unraisable.exc_value, AttributeError) and owner.endswith('__del__') and not rclpy.ok():
        return
    sys.__unraisablehook__(unraisable)


def run_node(
    factory: Callable[[], Node],
    args: Sequence[str] | None = None,
    spin: Callable[[Any], int] = spin_forever,
) -> int:
    """Initialise rclpy, run ``spin(node)`` on the node made by ``factory``, clean up; its exit code.

    Ctrl-C or an external shutdown give 0. SIGUSR1 prints every thread's Python stack to stderr
    (``kill -USR1 PID``: where a busy or stuck node is). Malformed ``--ros-args`` (rcl logs the details), or a
    ``factory`` that rejects its parameters (UserError, ValueError, rclpy ParameterException), give
    :data:`EXIT_BAD_CONFIG` with the reason as one error line, no traceback.
    """
    module = sys.modules.get(getattr(factory, '__module__', ''))
    name = Path(getattr(module, '__file__', None) or 'node').stem  # the node's module, also as __main__
    if threading.current_thread() is threading.main_thread():
        # rclpy's handlers (installed by init) shut the context down and then call these: ignore, so
        # that no KeyboardInterrupt tears through a half-built node; spin then ends by itself.
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: None)
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    sys.unraisablehook = _quiet_half_built
    try:
        rclpy.init(args=list(args) if args is not None else None)
        rclpy.get_global_executor()  # now, before a signal can shut the context down under it
    except RCLError as exc:
        print(f'{name}: {exc}', file=sys.stderr)
        return EXIT_BAD_CONFIG
    node = None
    code = 0
    try:
        try:
            node = factory()
        except (UserError, ValueError, ParameterException) as exc:
            rclpy.logging.get_logger(name).error(f'cannot start: {exc}')
            return EXIT_BAD_CONFIG
        code = spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:  # the context was shut down (a signal) while the node or its executor was built
        if rclpy.ok():
            raise
    finally:
        stopped = not rclpy.ok()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        if stopped:
            print(f'{name}: shut down by a signal or shutdown request, stopped', file=sys.stderr)
    return code


def size_mismatch(width: int, height: int, image_shape: tuple[int, ...], stamp: int) -> str | None:
    """Why a CameraInfo of ``width`` x ``height`` does not fit an image of ``image_shape``, or None."""
    if (height, width) == tuple(image_shape[:2]):
        return None
    return f'CameraInfo {width}x{height} does not match image {image_shape[1]}x{image_shape[0]} at {stamp} ns'
