# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Shared test helpers: frames of the shipped bag, keyframe messages, nodes spun in this process."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CameraInfo, Image

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.jobs.synth_bag import TOPICS

SHIPPED_BAG = Path('bags') / 'synth_orbit_s0'

# ------------------------------------------------------------------------------------ data


def shipped_frames(repo: Path, frames: Iterable[int], size: tuple[int, int] | None = None) -> list[dict]:
    """The shipped bag's ``frames`` (indices into its pose stream), resized to ``size`` (w, h) if given.

    Each is a dict: ``stamp``, ``rgb``, ``camera``, ``pose`` (4x4) and, where stored (every 3rd frame),
    ground-truth depth ``gt``.
    """
    frames = list(frames)
    with open_bag(repo / SHIPPED_BAG) as reader:
        stamps = [m.timestamp_ns for m in reader.messages([TOPICS['pose']])]
        index = {stamps[i]: k for k, i in enumerate(frames)}
        out: list[dict] = [{'stamp': stamps[i]} for i in frames]
        for m in reader.messages([TOPICS[k] for k in ('image', 'camera_info', 'pose', 'depth')]):
            if (k := index.get(m.timestamp_ns)) is None:
                continue
            if m.topic == TOPICS['image']:
                out[k]['rgb'] = np.ascontiguousarray(msg_utils.compressed_image_to_numpy(m.msg))
            elif m.topic == TOPICS['camera_info']:
                out[k]['camera'] = msg_utils.camera_info_to_pinhole(m.msg)
            elif m.topic == TOPICS['pose']:
                out[k]['pose'] = msg_utils.pose_stamped_to_matrix(m.msg)
            else:
                out[k]['gt'] = msg_utils.depth_image_to_m(m.msg).copy()
    return out if size is None else [resized(f, size) for f in out]


def resized(f: dict, size: tuple[int, int]) -> dict:
    """Frame ``f`` resized to ``size`` (width, height): rgb by area, intrinsics scaled, ``gt`` nearest."""
    cam = f['camera']
    out = dict(f)
    out['rgb'] = np.ascontiguousarray(cv2.resize(f['rgb'], size, interpolation=cv2.INTER_AREA))
    out['camera'] = cam.scaled(size[0] / cam.width, size[1] / cam.height)
    if 'gt' in f:
        out['gt'] = cv2.resize(f['gt'], size, interpolation=cv2.INTER_NEAREST)
    return out


def keyframe_topics(qos: QoSProfile) -> dict[str, tuple[type, str, QoSProfile]]:
    """Publisher spec (:meth:`InProcess.publishers`) of the keyframe image, camera_info and pose."""
    return {
        'image': (Image, 'keyframes/image', qos),
        'info': (CameraInfo, 'keyframes/camera_info', qos),
        'pose': (PoseStamped, 'keyframes/pose', qos),
    }


def create_publishers(node: Node, spec: dict[str, tuple[type, str, QoSProfile]]) -> dict:
    """``node``'s publishers of ``spec`` (name -> (type, topic, qos)), by name."""
    return {k: node.create_publisher(cls, topic, qos) for k, (cls, topic, qos) in spec.items()}


def image_msg(rgb: np.ndarray, stamp: int) -> Image:
    return msg_utils.numpy_to_image(rgb, 'rgb8', msg_utils.make_header(stamp, 'camera_optical'))


def info_msg(cam: PinholeCamera, stamp: int) -> CameraInfo:
    return msg_utils.pinhole_to_camera_info(cam, msg_utils.make_header(stamp, 'camera_optical'))


def pose_msg(t_wc: np.ndarray, stamp: int, frame_id: str = 'map') -> PoseStamped:
    return msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp, frame_id=frame_id)


def publish_frame(pubs: dict, f: dict, stamp: int | None = None, pose: bool = True) -> None:
    """Publish frame ``f``'s image, camera_info and (if ``pose``) pose, stamped ``stamp`` or its own.

    ``pubs`` are named as in :func:`keyframe_topics`.
    """
    stamp = f['stamp'] if stamp is None else stamp
    pubs['image'].publish(image_msg(f['rgb'], stamp))
    pubs['info'].publish(info_msg(f['camera'], stamp))
    if pose:
        pubs['pose'].publish(pose_msg(f['pose'], stamp))


# ---------------------------------------------------------------------------------- nodes


def spin_until(node: Node, cond: Callable[[], object], timeout: float) -> bool:
    """Spin ``node`` in this thread until ``cond()`` holds or ``timeout`` seconds passed; ``cond()``."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    return bool(cond())


def assert_refuses_to_start(
    main: Callable[[list[str]], int],
    name: str,
    params: list[str],
    error: str,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """Node ``name``'s ``main`` with ``-p params`` exits EXIT_BAD_CONFIG, one line naming ``error``."""
    from ibr_ros.nodes.common import EXIT_BAD_CONFIG

    argv = [name, '--ros-args']
    for prm in params:
        argv += ['-p', prm]
    assert main(argv) == EXIT_BAD_CONFIG
    err = capfd.readouterr().err
    assert f'[{name}]: cannot start: {error}' in err
    assert 'Traceback' not in err


class InProcess:
    """The node under test and a feeder node, spun by one executor in a background thread.

    The node's subscription callbacks are wrapped to count handled messages, so that :meth:`send`
    can wait until the node is done with one message before it publishes the next.
    """

    def __init__(self, node: Node, feeder: str = 'feeder') -> None:
        self.node = node
        self.feeder = rclpy.create_node(feeder)
        self.cond = threading.Condition()
        self.handled = 0
        self.error: BaseException | None = None
        for sub in node.subscriptions:
            sub.callback = self._counted(sub.callback)
        create = node.create_subscription

        def create_counted(msg_type, topic, callback, *args, **kwargs):  # subscriptions made later
            return create(msg_type, topic, self._counted(callback), *args, **kwargs)

        node.create_subscription = create_counted
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.executor.add_node(self.feeder)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _counted(self, callback: Callable) -> Callable:
        def handled(msg: object) -> None:
            try:
                callback(msg)
            finally:
                with self.cond:
                    self.handled += 1
                    self.cond.notify_all()

        return handled

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass
        except BaseException as exc:  # a callback raised: the node is dead
            self.error = exc
        with self.cond:
            self.cond.notify_all()

    @property
    def alive(self) -> bool:
        return self.error is None and self.thread.is_alive()

    def wait(self, cond: Callable[[], object], timeout: float) -> bool:
        """Wait until ``cond()`` (re-checked on every notification, at least every 20 ms) or the node dies."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while not cond():
                left = deadline - time.monotonic()
                if left <= 0 or self.error is not None:
                    return bool(cond())
                self.cond.wait(min(left, 0.02))
        return True

    def collect(self, cls: type, topic: str, qos: QoSProfile) -> list:
        """Messages arriving at the feeder on ``topic``."""
        box: list = []

        def got(msg: object) -> None:
            with self.cond:
                box.append(msg)
                self.cond.notify_all()

        self.feeder.create_subscription(cls, topic, got, qos)
        return box

    def publishers(self, spec: dict[str, tuple[type, str, QoSProfile]]) -> dict:
        """Feeder publishers, once each is matched with the node's subscription."""
        pubs = create_publishers(self.feeder, spec)
        assert self.wait(lambda: all(p.get_subscription_count() > 0 for p in pubs.values()), 30)
        return pubs

    def send(self, pub, msg: object) -> None:
        """Publish ``msg`` and wait until the node's callback for it returned."""
        with self.cond:
            target = self.handled + 1
        pub.publish(msg)
        assert self.wait(lambda: self.handled >= target, 30), (
            f'{pub.topic_name}: not handled ({self.error!r})'
        )

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=5)
        self.node.destroy_node()
        self.feeder.destroy_node()


@contextmanager
def in_process(
    factory: Callable[[], Node], params_file: Path | None = None, feeder: str = 'feeder', **params: object
) -> Iterator[InProcess]:
    """rclpy with ``params_file`` and ``params``, the node made by ``factory`` and its harness."""
    args = ['--ros-args']
    if params_file is not None:
        args += ['--params-file', str(params_file)]
    for key, value in params.items():
        args += ['-p', f'{key}:={str(value).lower() if isinstance(value, bool) else value}']
    rclpy.init(args=args)
    h = None
    try:
        h = InProcess(factory(), feeder)
        yield h
    finally:
        if h is not None:
            h.close()
        rclpy.try_shutdown()
        if h is not None:
            h.thread.join(timeout=10)
