# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""A two-role DDS peer for the smoke test (run as a separate process).

``sub``: waits for one Image on ``smoke/image`` and prints ``RECEIVED <sha256> <h> <w> <encoding>``.
``pub``: waits until the subscriber is matched (no fixed sleeps), then publishes one Image built
from a seeded random array, and waits until the subscriber has left (it exits after receiving).
"""

from __future__ import annotations

import hashlib
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import Image

from msg_utils import image_to_numpy, numpy_to_image

QOS = QoSProfile(
    depth=1, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
)
TIMEOUT_S = 30.0


def make_array(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(120, 160, 3), dtype=np.uint8)


def run_sub(node: rclpy.node.Node) -> int:
    got: list[Image] = []
    node.create_subscription(Image, 'smoke/image', got.append, QOS)
    print('READY', flush=True)
    deadline = time.monotonic() + TIMEOUT_S
    while not got and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    if not got:
        print('TIMEOUT', flush=True)
        return 1
    arr = image_to_numpy(got[0])
    digest = hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()
    print(f'RECEIVED {digest} {arr.shape[0]} {arr.shape[1]} {got[0].encoding}', flush=True)
    return 0


def run_pub(node: rclpy.node.Node, seed: int) -> int:
    pub = node.create_publisher(Image, 'smoke/image', QOS)
    deadline = time.monotonic() + TIMEOUT_S
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    if pub.get_subscription_count() == 0:
        print('NO_SUBSCRIBER', flush=True)
        return 1
    pub.publish(numpy_to_image(make_array(seed), 'rgb8'))
    print('PUBLISHED', flush=True)
    # Keep the writer alive (reliable delivery) until the reader leaves after receiving.
    while pub.get_subscription_count() > 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    return 0


def main() -> int:
    role, seed = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 0
    rclpy.init()
    try:
        node = rclpy.create_node(f'dds_smoke_{role}')
        return run_sub(node) if role == 'sub' else run_pub(node, seed)
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
