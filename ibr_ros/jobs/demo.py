# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr demo``: the main job on the default synthetic bag, through the real node graph over DDS.

Starts bag_player, frame_subsampler, depth_refiner and view_renderer as separate processes (as
``ibr graph`` does) in a DDS domain of their own (localhost only; :func:`ibr_ros.graph.claim_domain`),
replays the bag, waits until the frame_subsampler's ``keyframes/status`` says it has seen every
frame of the bag and the camera stream ended, and every keyframe it counted has its refined depth
(nothing is decided on a timer), then sends
novel-view queries along a path between the keyframes (each waited for until its
``novel_view/status`` and, when answered, its view arrived) and writes into ``out``:
``novel_views/query_NN.png`` (ground truth | rendered), ``depth/keyframe_NN.png`` (image | refined
depth | ground-truth depth), ``logs/<node>.log``, ``summary.json`` and ``summary.md`` (timings,
depth error and rephotography error against the exact re-rendered ground truth).
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import msg_utils
from ibr_ros.core.evaluation.rephoto import score
from ibr_ros.core.geometry.path import interpolate_path
from ibr_ros.errors import UserError
from ibr_ros.graph import Graph, NodeSpec
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.eval_depth import colour_depth
from ibr_ros.jobs.synth_bag import TOPICS, GroundTruthRenderer

__all__ = ['run_demo']

LOG = logging.getLogger(__name__)


def _png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, cv2.imencode('.png', cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes())


def run_demo(
    bag: Path, out: Path, *, n_queries: int = 8, rate: float = 1.0, timeout_s: float = 900.0
) -> dict:
    """Run the demo (see module docstring); returns the summary.

    ``rate`` 1 replays in real time: the subsampler's camera subscriptions are best effort (sensor
    data QoS), so replaying faster than it decodes frames would drop frames and make the keyframe
    set depend on the machine's load.
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image

    from ibr_ros.bag import open_bag
    from ibr_ros.core.flight.status import FlightStatus
    from ibr_ros.core.render import ReplyStatus
    from ibr_ros.graph import claim_domain, wait_for_subsampler

    bag, out = Path(bag), Path(out)
    gt = GroundTruthRenderer(bag)  # raises UserError for bags without synth.json
    with open_bag(bag) as reader:
        n_frames = reader.topics[TOPICS['image']].count
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    topics = [TOPICS['image'], TOPICS['camera_info'], TOPICS['pose']]
    specs = [
        NodeSpec(
            'bag_player',
            {
                'bag': str(bag.resolve()),
                'rate': rate,
                'topics': topics,
                **wait_for_subsampler(bag),
            },
        ),
        NodeSpec('frame_subsampler', {'scene_depth_m': 80.0}),
        NodeSpec('depth_refiner', {'max_neighbours': 2}),
        NodeSpec('view_renderer', {}),
    ]
    latched = QoSProfile(
        depth=1000, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
    )
    keyframes: dict[int, list] = {}
    depths: dict[int, tuple] = {}
    replies: dict[int, tuple] = {}
    flight: list[FlightStatus] = []
    domain, lock = claim_domain(1 + os.getpid() % 100)  # held until the graph is stopped
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')})
    rclpy.init()
    graph = Graph(specs, env=env, log_dir=out / 'logs')
    try:
        node = rclpy.create_node('ibr_demo')

        def stamp_of(m: Any) -> int:  # any stamped message
            return msg_utils.stamp_to_ns(m.header.stamp)

        def on_image(m: Image) -> None:
            keyframes.setdefault(stamp_of(m), [None, None])[0] = np.array(msg_utils.image_to_rgb(m))

        def on_pose(m: PoseStamped) -> None:
            keyframes.setdefault(stamp_of(m), [None, None])[1] = msg_utils.pose_stamped_to_matrix(m)

        def on_depth(m: Image) -> None:
            depths[stamp_of(m)] = (np.array(msg_utils.image_to_numpy(m)), time.monotonic())

        def on_reply(m: Image) -> None:
            replies[stamp_of(m)] = (np.array(msg_utils.image_to_rgb(m)), time.monotonic())

        def on_status(m: DiagnosticStatus) -> None:
            try:
                flight.append(FlightStatus.from_pairs(msg_utils.status_to_pairs(m)))
            except ValueError as exc:
                LOG.warning('keyframes/status: %s', exc)

        infos: dict[int, CameraInfo] = {}
        node.create_subscription(DiagnosticStatus, 'keyframes/status', on_status, latched)
        node.create_subscription(Image, 'keyframes/image', on_image, latched)
        node.create_subscription(PoseStamped, 'keyframes/pose', on_pose, latched)
        node.create_subscription(Image, 'keyframes/depth', on_depth, latched)
        node.create_subscription(
            CameraInfo, 'novel_view/camera_info', lambda m: infos.__setitem__(stamp_of(m), m), 10
        )
        node.create_subscription(Image, 'novel_view/image', on_reply, 10)
        statuses: dict[int, ReplyStatus] = {}

        def on_reply_status(m: DiagnosticArray) -> None:
            try:
                stamp, st = msg_utils.diagnostics_to_reply(m)
            except msg_utils.MessageError as exc:
                LOG.warning('novel_view/status: %s', exc)
                return
            statuses[stamp] = st

        status_sub = node.create_subscription(DiagnosticArray, 'novel_view/status', on_reply_status, 10)
        query_pub = node.create_publisher(PoseStamped, 'novel_view/query', 10)
        graph.start()
        print(
            f'ibr demo: graph started ({", ".join(graph.procs)}) in ROS_DOMAIN_ID {domain}; replaying {bag}',
            flush=True,
        )
        deadline = t0 + timeout_s
        last_count = -1
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
            status = graph.poll()
            failed = {n: rc for n, rc in status.items() if rc not in (None, 0)}
            if failed:
                raise UserError(f'node(s) failed: {failed}; see {out / "logs"}')
            count = len(depths)
            if count != last_count:
                last_count = count
                print(f'ibr demo: {len(keyframes)} keyframes, {count} refined', flush=True)
            latest = flight[-1] if flight else None
            seen_all = latest is not None and latest.camera == 'ended' and latest.frames >= n_frames
            if latest is not None and seen_all and latest.keyframes == len(keyframes) <= count:
                break
        else:
            raise UserError(f'timed out after {timeout_s:.0f} s with {len(depths)}/{len(keyframes)} depths')
        replay_s = time.monotonic() - t0

        stamps = sorted(s for s, (img, pose) in keyframes.items() if img is not None and pose is not None)
        path = interpolate_path([keyframes[s][1] for s in stamps], n_queries)
        results: list[dict[str, object]] = []

        def waiting(stamp: int) -> bool:  # for the query's status, then for the view it announces
            if stamp not in statuses:
                return True
            return statuses[stamp].published and (stamp not in replies or stamp not in infos)

        while time.monotonic() < deadline and (
            query_pub.get_subscription_count() == 0 or status_sub.get_publisher_count() == 0
        ):
            rclpy.spin_once(node, timeout_sec=0.05)
        for k, t_wc in enumerate(path):
            stamp = 1_000_000_000 + k
            sent = time.monotonic()
            query_pub.publish(msg_utils.matrix_to_pose_stamped(t_wc, stamp_ns=stamp, frame_id='map'))
            while waiting(stamp) and time.monotonic() - sent < 30.0:
                rclpy.spin_once(node, timeout_sec=0.02)
            st = statuses.get(stamp)
            if stamp not in replies or st is None or st.result != 'answered':
                results.append({'query': k, 'answered': False, 'reason': st.reason if st else 'no status',
                                'valid_fraction': st.valid_fraction if st else None})  # fmt: skip
                continue
            rgb, received = replies[stamp]
            cam = msg_utils.camera_info_to_pinhole(infos[stamp])
            truth = gt.render(t_wc, cam)
            sc = score(truth.rgb, rgb, valid_mask=rgb.any(axis=2), patch=7, shift=2)
            _png(out / 'novel_views' / f'query_{k:02d}.png', np.hstack([truth.rgb, rgb]))
            results.append({'query': k, 'answered': True, 'latency_ms': 1e3 * (received - sent),
                            'valid_fraction': st.valid_fraction, 'auc': sc.auc, 'tail': sc.tail,
                            'completeness': sc.completeness})  # fmt: skip
    finally:
        graph.stop()
        rclpy.try_shutdown()
        lock.close()

    depth_rows = []
    for i, stamp in enumerate(stamps):
        if stamp not in depths:
            continue
        img, t_wc = keyframes[stamp]
        cam_h, cam_w = img.shape[:2]
        from ibr_ros.core.synth import flight_camera

        cam = flight_camera((cam_w, cam_h), gt.hfov_deg)
        truth = gt.render(t_wc, cam)
        d = depths[stamp][0]
        ok = np.isfinite(truth.depth) & ~truth.sky & np.isfinite(d) & (d > 0)
        rel = np.abs(d[ok] - truth.depth[ok]) / truth.depth[ok]
        depth_rows.append(
            {'keyframe': i, 'median_abs_rel': float(np.median(rel)), 'coverage': float(ok.mean())}
        )
        fin = truth.depth[np.isfinite(truth.depth)]
        lo, hi = float(fin.min()), float(fin.max())
        tiles = [img, colour_depth(d, lo, hi)[..., ::-1], colour_depth(truth.depth, lo, hi)[..., ::-1]]
        _png(out / 'depth' / f'keyframe_{i:02d}.png', np.hstack(tiles))
    answered = [r for r in results if r['answered']]
    summary = {
        'bag': str(bag),
        'keyframes': len(stamps),
        'refined': len(depth_rows),
        'replay_and_refine_s': replay_s,
        'depth_median_abs_rel': float(np.median([r['median_abs_rel'] for r in depth_rows]))
        if depth_rows
        else None,
        'queries': len(results),
        'answered': len(answered),
        'query_latency_ms_median': float(np.median([r['latency_ms'] for r in answered]))
        if answered
        else None,
        'rephoto_auc_mean': float(np.mean([r['auc'] for r in answered])) if answered else None,
        'rephoto_tail_mean': float(np.mean([r['tail'] for r in answered])) if answered else None,
        'per_keyframe_depth': depth_rows,
        'per_query': results,
    }
    write_atomic(out / 'summary.json', json.dumps(summary, indent=2) + '\n')
    fmt = lambda key, spec: format(summary[key], spec) if summary[key] is not None else 'n/a'  # noqa: E731
    md = [
        f'# ibr demo on `{bag}`',
        '',
        f'- keyframes: {summary["keyframes"]}, refined: {summary["refined"]} '
        f'(replay + refinement {replay_s:.1f} s)',
        f'- refined depth vs ground truth: median abs rel {fmt("depth_median_abs_rel", ".3f")}',
        f'- novel views: {summary["answered"]}/{summary["queries"]} answered, median round trip '
        f'{fmt("query_latency_ms_median", ".1f")} ms',
        f'- rephotography vs ground truth (7x7, shift 2): mean AUC {fmt("rephoto_auc_mean", ".2f")}, '
        f'mean worst-1% {fmt("rephoto_tail_mean", ".1f")}',
    ]
    write_atomic(out / 'summary.md', '\n'.join(md) + '\n')
    return summary
