# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark: novel-view query round trip over DDS at 960x540, target p95 <= 100 ms.

The view_renderer runs as its own process (:func:`ibr_ros.graph.node_command`, default parameters:
4 source views, 1500 superpixels each, output camera = the keyframes'). This process publishes 4
keyframes of the synthetic town (``SceneConfig(seed=3)``, orbit at 15 fps, frames 24, 27, 33 and
36 at 960x540 with exact depth; as ``bench_render.py``) on ``keyframes/*``, waits until the renderer
has prepared all of them, sends ``WARMUP`` queries, then ``RUNS`` queries one at a time along a short
path (frame 27 to frame 33, each pose moved by up to 0.5 m): ``geometry_msgs/PoseStamped`` on
``novel_view/query`` -> ``sensor_msgs/Image`` on ``novel_view/image`` with the query's stamp.
Round trip: publish to the reply's arrival in this process's callback (message deserialised).

Baseline, in this process on the same poses (each pose rendered here just before it is queried):
``NovelViewRenderer.render`` with the node's configuration; the ratio p50(round trip) /
p50(render) and the difference show what DDS, the message conversions and the second process cost
(the replies must be pixel-identical to the baseline renders). Also printed: the renderer's own time per
query (its 'answered in' log lines: render + numpy -> Image + publish). Exits 1 when p95 misses
the target (when the 1-minute load average exceeds the CPU count, only warns).
Run: ``.venv/bin/python bench/bench_query.py``.
"""

from __future__ import annotations

import os
import re
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # benchmark the checkout, not an installed copy
# An isolated DDS domain on this machine only, for this process and the renderer it starts.
os.environ.setdefault('ROS_DOMAIN_ID', str(101 + os.getpid() % 100))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

import msg_utils  # noqa: E402
from ibr_ros.core.geometry.transforms import matrix_from_rt  # noqa: E402
from ibr_ros.core.render import NovelViewRenderer, RenderConfig  # noqa: E402
from ibr_ros.graph import Graph, NodeSpec  # noqa: E402
from ibr_ros.nodes.common import model_qos, reliable_qos  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import SOURCES, H, W, orbit_scene  # noqa: E402  (the same scene as bench_render)

PATH = (27, 33)
RUNS = 50
WARMUP = 5
TARGET_P95_MS = 100.0
N_SEGMENTS = 1500


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q))


def query_poses(samples: list, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """``n`` poses from frame PATH[0] to PATH[1]: positions interpolated, rotation of the nearer end."""
    a, b = samples[PATH[0]].t_wc, samples[PATH[1]].t_wc
    out = []
    for s in np.linspace(0.0, 1.0, n):
        t = (a if s < 0.5 else b).copy()
        t[:3, 3] = (1 - s) * a[:3, 3] + s * b[:3, 3]
        out.append(t @ matrix_from_rt(np.eye(3), rng.uniform(-0.5, 0.5, 3)))
    return out


def as_sent(t_wc: np.ndarray) -> np.ndarray:
    """Pose ``t_wc`` as the renderer node receives it (through ``geometry_msgs/PoseStamped``)."""
    return msg_utils.pose_stamped_to_matrix(msg_utils.matrix_to_pose_stamped(t_wc))


def main() -> int:
    camera, samples, frames, views = orbit_scene()
    rng = np.random.default_rng(0)
    warm = query_poses(samples, rng, WARMUP)
    poses = query_poses(samples, rng, RUNS)
    print(
        f'{len(SOURCES)} source views {W}x{H} (synthetic orbit, frames {SOURCES}), {N_SEGMENTS} superpixels'
    )
    print(f'cpus: {os.cpu_count()}, load avg: {os.getloadavg()}')

    # Baseline renderer in this process, views prepared and kernels compiled before any timing. Its
    # poses go through PoseStamped as the node's do (quaternions round off the last bits, which can
    # move a nearest-pixel depth lookup), so that the replies can be compared pixel for pixel.
    views = [replace(v, t_wc=as_sent(v.t_wc)) for v in views]
    renderer = NovelViewRenderer(views, RenderConfig(n_segments=N_SEGMENTS))
    for t_wc in warm:
        renderer.render(t_wc, camera)

    log_dir = Path(tempfile.mkdtemp(prefix='bench_query_'))
    spec = NodeSpec('view_renderer', params={'n_segments': N_SEGMENTS})
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))
    renders, trips, same = [], [], 0
    rclpy.init()
    try:
        with Graph([spec], env=env, log_dir=log_dir) as graph:
            log = log_dir / 'view_renderer.log'
            node = rclpy.create_node('bench_query')
            qos = model_qos()
            pubs = {
                'image': node.create_publisher(Image, 'keyframes/image', qos),
                'info': node.create_publisher(CameraInfo, 'keyframes/camera_info', qos),
                'pose': node.create_publisher(PoseStamped, 'keyframes/pose', qos),
                'depth': node.create_publisher(Image, 'keyframes/depth', qos),
            }
            query = node.create_publisher(PoseStamped, 'novel_view/query', reliable_qos())
            replies: dict[int, tuple[float, Image]] = {}

            def on_reply(m: Image) -> None:
                replies[msg_utils.stamp_to_ns(m.header.stamp)] = (time.perf_counter(), m)

            node.create_subscription(Image, 'novel_view/image', on_reply, reliable_qos())

            def spin_until(cond, timeout: float) -> bool:
                deadline = time.monotonic() + timeout
                while not cond() and time.monotonic() < deadline:
                    if graph.poll()['view_renderer'] is not None:
                        raise RuntimeError(f'view_renderer exited:\n{log.read_text()}')
                    rclpy.spin_once(node, timeout_sec=0.05)
                return cond()

            # Keyframes (latched): the renderer prepares each one when it arrives.
            for i in SOURCES:
                stamp = 1_000_000_000 * (i + 1)
                header = msg_utils.make_header(stamp, 'camera_optical')
                f = frames[i]
                pubs['image'].publish(msg_utils.numpy_to_image(f.rgb, 'rgb8', header))
                pubs['info'].publish(msg_utils.pinhole_to_camera_info(camera, header))
                pubs['pose'].publish(msg_utils.matrix_to_pose_stamped(samples[i].t_wc, stamp_ns=stamp))
                pubs['depth'].publish(msg_utils.numpy_to_image(f.depth.astype(np.float32), '32FC1', header))
            t0 = time.monotonic()
            added = lambda: log.read_text().count('added keyframe') >= len(SOURCES)  # noqa: E731
            if not spin_until(lambda: added() and query.get_subscription_count() > 0, 120):
                raise RuntimeError(f'renderer not ready:\n{log.read_text()}')
            print(f'renderer ready {time.monotonic() - t0:.1f} s after the keyframes were published')

            def ask(t_wc: np.ndarray, stamp: int) -> tuple[float, Image]:
                sent = time.perf_counter()
                query.publish(msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp))
                if not spin_until(lambda: stamp in replies, 10):
                    raise RuntimeError(f'query {stamp} not answered:\n{log.read_text()[-3000:]}')
                arrived, msg = replies[stamp]
                return 1e3 * (arrived - sent), msg

            for k, t_wc in enumerate(warm):
                ask(t_wc, 1 + k)
            for k, t_wc in enumerate(poses):  # paired: the same pose in this process, then over DDS
                t = time.perf_counter()
                out = renderer.render(as_sent(t_wc), camera)
                renders.append(1e3 * (time.perf_counter() - t))
                ms, msg = ask(t_wc, 1000 + k)
                trips.append(ms)
                same += bool(np.array_equal(msg_utils.image_to_numpy(msg), out.rgb))
            node_ms = [
                float(ms)
                for stamp, ms in re.findall(r'query (\d+) ns answered in (\d+) ms', log.read_text())
                if int(stamp) >= 1000
            ]
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    load = os.getloadavg()[0]

    p50, p95 = statistics.median(trips), percentile(trips, 95)
    r50, r95 = statistics.median(renders), percentile(renders, 95)
    print(
        f'round trip over DDS ({RUNS} queries): p50 {p50:.1f} ms, p95 {p95:.1f} ms, max {max(trips):.1f} ms'
    )
    if node_ms:
        own = statistics.median(node_ms)
        print(f"renderer node's own time per query (render + Image + publish): p50 {own:.0f} ms")
    print(f'baseline NovelViewRenderer.render in this process: p50 {r50:.1f} ms, p95 {r95:.1f} ms')
    print(
        f'round trip / render: p50 {p50 / r50:.2f}x (+{p50 - r50:.1f} ms), '
        f'p95 {p95 / r95:.2f}x (+{p95 - r95:.1f} ms)'
    )
    print(f'replies identical to the in-process render: {same}/{RUNS}')
    print(f'load average after the runs: {load:.2f} on {os.cpu_count()} CPUs')
    if p95 <= TARGET_P95_MS:
        print(f'PASS: round trip p95 {p95:.1f} ms <= target {TARGET_P95_MS:.0f} ms')
        return 0
    if load > (os.cpu_count() or 1):
        print(
            f'WARN: machine overloaded (load {load:.2f}): round trip p95 {p95:.1f} ms '
            f'> target {TARGET_P95_MS:.0f} ms; rerun when idle'
        )
        return 0
    print(f'FAIL: round trip p95 {p95:.1f} ms > target {TARGET_P95_MS:.0f} ms')
    return 1


if __name__ == '__main__':
    sys.exit(main())
