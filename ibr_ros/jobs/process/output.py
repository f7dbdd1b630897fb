# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The output bag (the graph's topics, types and QoS) and ``summary.md``/``summary.json`` helpers."""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

import msg_utils
from ibr_ros.bag import BagWriter, OfferedQos
from ibr_ros.core.viz import VizModel
from ibr_ros.jobs.process.frames import Keyframe
from ibr_ros.jobs.process.options import Progress
from ibr_ros.jobs.process.params import ProcessConfigs
from ibr_ros.jobs.process.render import NovelView
from ibr_ros.jobs.process.spill import loaded
from msg_utils.flavor import Flavor

#: Output topics (fully qualified: what the graph's relative names resolve to in the root namespace).
#: QoS the graph's publishers offer (ibr_ros.nodes.common.model_qos / reliable_qos), recorded per topic
#: so that bag_player and ros2 bag play offer it again (a late-joining renderer gets the whole model).
MODEL_QOS = OfferedQos('reliable', 'transient_local', depth=1000)
REPLY_QOS = OfferedQos('reliable', 'volatile', depth=10)
#: The scene_viz's whole-model topics (the latest only) and /tf (tf2's depth).
LATCHED_QOS = OfferedQos('reliable', 'transient_local', depth=1)
TF_QOS = OfferedQos('reliable', 'volatile', depth=100)
#: The input's GPS fixes, as a sensor driver offers them (rclpy's ``qos_profile_sensor_data``).
SENSOR_QOS = OfferedQos('best_effort', 'volatile', depth=5)

OUT_TOPICS = {
    'image': ('/keyframes/image', 'sensor_msgs/msg/Image'),
    'camera_info': ('/keyframes/camera_info', 'sensor_msgs/msg/CameraInfo'),
    'pose': ('/keyframes/pose', 'geometry_msgs/msg/PoseStamped'),
    'depth': ('/keyframes/depth', 'sensor_msgs/msg/Image'),
    'depth_info': ('/keyframes/depth/camera_info', 'sensor_msgs/msg/CameraInfo'),
    'confidence': ('/keyframes/depth/confidence', 'sensor_msgs/msg/Image'),
    'query': ('/novel_view/query', 'geometry_msgs/msg/PoseStamped'),
    'view': ('/novel_view/image', 'sensor_msgs/msg/Image'),
    'view_info': ('/novel_view/camera_info', 'sensor_msgs/msg/CameraInfo'),
    'view_status': ('/novel_view/status', 'diagnostic_msgs/msg/DiagnosticArray'),
    'view_jpeg': ('/novel_view/image/compressed', 'sensor_msgs/msg/CompressedImage'),
    # The scene_viz's topics: the model for RViz and Foxglove.
    'tf': ('/tf', 'tf2_msgs/msg/TFMessage'),
    'tf_static': ('/tf_static', 'tf2_msgs/msg/TFMessage'),
    'poses': ('/keyframes/poses', 'geometry_msgs/msg/PoseArray'),
    'frustums': ('/keyframes/frustums', 'visualization_msgs/msg/MarkerArray'),
    'points': ('/keyframes/points', 'sensor_msgs/msg/PointCloud2'),
    # The input's NavSatFix topic (whatever its name), passed through for the layout's map panel;
    # only in a bag whose input had one.
    'navsat': ('/gps/fix', 'sensor_msgs/msg/NavSatFix'),
}
#: Topics recorded with :data:`LATCHED_QOS` / :data:`TF_QOS`; other ``/keyframes/`` topics with
#: :data:`MODEL_QOS`, ``/gps/fix`` with :data:`SENSOR_QOS`, the rest with :data:`REPLY_QOS`.
_LATCHED = ('/tf_static', '/keyframes/poses', '/keyframes/frustums')


def _offered(topic: str) -> OfferedQos:
    if topic == OUT_TOPICS['navsat'][0]:
        return SENSOR_QOS
    if topic in _LATCHED:
        return LATCHED_QOS
    if topic == '/tf':
        return TF_QOS
    return MODEL_QOS if topic.startswith('/keyframes/') else REPLY_QOS


def write_bag(
    path: Path,
    keyframes: list[Keyframe],
    views: list[NovelView],
    cfg: ProcessConfigs,
    model_frame: str,
    progress: Progress | None = None,
    fixes: Sequence[msg_utils.GeoFix] = (),
) -> dict[str, int]:
    """The output bag (a new ``path``), every message logged at its header stamp, in time order;
    returns the message count per topic.

    Streamed: the messages of one keyframe or view at a time are converted, written and dropped
    (peak memory does not grow with the flight). ``progress('write', done, total)`` per keyframe or view.
    The scene_viz's topics (TF, keyframe poses, frustums, points) are made as the node makes them,
    from a :class:`~ibr_ros.core.viz.VizModel` fed in the same order. ``fixes``: the input's GPS
    fixes as recorded (also without a fix: the status says so), written to ``/gps/fix`` in stamp
    order (recorded order at equal stamps) among the other messages, after them at equal stamps; the
    topic is only declared (and counted) with fixes.
    """
    items = sorted(
        [(k.stamp, 0, i) for i, k in enumerate(keyframes)]
        + [(v.stamp, 1, j) for j, v in enumerate(views)]
        + [(f.stamp_ns, 2, n) for n, f in enumerate(fixes)]
    )
    total = len(keyframes) + len(views)
    counts: Counter = Counter()
    done = 0
    model = VizModel(cfg.scene.viz)
    names = [(name, t) for key, (name, t) in OUT_TOPICS.items() if key != 'navsat' or fixes]
    with BagWriter(path) as writer:
        for name, msgtype in names:
            writer.add_topic(name, msgtype, _offered(name))
        for stamp, group in itertools.groupby(items, key=lambda e: e[0]):
            events: list[tuple[int, str, object]] = []
            before = done
            for _, kind, i in group:
                if kind == 0:
                    k = _in_memory(keyframes[i])  # a spilled keyframe read once for both
                    events += _keyframe_events(k) + _viz_keyframe_events(model, k)
                elif kind == 1:
                    events += _view_events(views[i], cfg, model_frame) + _viz_view_events(
                        model, views[i], cfg
                    )
                else:
                    events.append((10, 'navsat', msg_utils.fix_to_navsatfix(fixes[i], flavor='rosbags')))
                    continue
                done += 1
            events.sort(key=lambda e: e[0])  # stable: messages at one stamp by rank, as before streaming
            for _, key, msg in events:
                writer.write(OUT_TOPICS[key][0], msg, stamp)
                counts[OUT_TOPICS[key][0]] += 1
            if progress is not None and done > before:  # not for a stamp with fixes only
                progress('write', done, total)
    return {name: counts[name] for name, _ in names}


def _in_memory(k: Keyframe) -> Keyframe:
    """``k`` with its image, depth and confidence read from their spill files (:func:`loaded`)."""
    depth = None if k.depth is None else loaded(k.depth)
    confidence = None if k.confidence is None else loaded(k.confidence)
    return replace(k, rgb=loaded(k.rgb), depth=depth, confidence=confidence)


def _keyframe_events(k: Keyframe) -> list[tuple[int, str, object]]:
    """A keyframe's messages (rank at its stamp, topic key, message); its arrays in memory."""
    rb: dict[str, Flavor] = {'flavor': 'rosbags'}
    header = msg_utils.make_header(k.stamp, k.camera_frame, **rb)
    info = msg_utils.pinhole_to_camera_info(k.camera, header, **rb)  # of the image and the depth map
    out: list[tuple[int, str, object]] = [
        (0, 'image', msg_utils.numpy_to_image(k.rgb, 'rgb8', header, **rb)),
        (1, 'camera_info', info),
        (2, 'pose', msg_utils.matrix_to_pose_stamped(k.t_wc, stamp_ns=k.stamp, frame_id=k.pose_frame, **rb)),
    ]
    if k.depth is not None:
        out.append((3, 'depth', msg_utils.depth_m_to_image(k.depth, header, **rb)))
        out.append((4, 'depth_info', info))
        if k.confidence is not None:
            out.append((4, 'confidence', msg_utils.confidence_to_image(k.confidence, header, **rb)))
    return out


def _view_events(v: NovelView, cfg: ProcessConfigs, model_frame: str) -> list[tuple[int, str, object]]:
    """A novel view's messages (rank at its stamp, topic key, message): query, image, status."""
    rb: dict[str, Flavor] = {'flavor': 'rosbags'}
    out: list[tuple[int, str, object]] = [
        (5, 'query', msg_utils.matrix_to_pose_stamped(v.t_wc, stamp_ns=v.stamp, frame_id=model_frame, **rb))
    ]
    header = msg_utils.make_header(v.stamp, cfg.viewing.frame_id, **rb)
    if v.rgb is not None and v.camera is not None:
        out.append((6, 'view', msg_utils.numpy_to_image(v.rgb, 'rgb8', header, **rb)))
        out.append((7, 'view_info', msg_utils.pinhole_to_camera_info(v.camera, header, **rb)))
    if v.status is not None:
        status = msg_utils.reply_to_diagnostics(v.status, header, name='/view_renderer', **rb)
        out.append((8, 'view_status', status))
    return out


def _viz_keyframe_events(model: VizModel, k: Keyframe) -> list[tuple[int, str, object]]:
    """The scene_viz's messages for a keyframe (after the keyframe's own; its arrays in memory): the
    camera's TF, the keyframes' static TF, poses and frustums (whole, latched) and its points once
    refined."""
    if not np.all(np.isfinite(k.t_wc)):  # not registered by SfM: no pose
        return []
    rb: dict[str, Flavor] = {'flavor': 'rosbags'}
    model.put_pose(k.stamp, k.t_wc, k.pose_frame)
    model.put_camera(k.stamp, k.camera)
    header = msg_utils.make_header(k.stamp, model.world, **rb)
    chain = [(k.stamp, parent, child, t) for parent, child, t in model.camera_transforms(k.t_wc)]
    out: list[tuple[int, str, object]] = [
        (5, 'tf', msg_utils.transforms_to_tf(chain, **rb)),
        (5, 'tf_static', msg_utils.transforms_to_tf(model.static_transforms(), **rb)),
        (5, 'poses', msg_utils.matrices_to_pose_array(model.poses(), header, **rb)),
    ]
    if k.depth is not None:
        model.put_image(k.stamp, k.rgb)
        model.put_depth(k.stamp, k.depth)
        if k.confidence is not None:
            model.put_confidence(k.stamp, k.confidence)
        if (points := model.points(k.stamp)) is not None:
            out.append((5, 'points', msg_utils.points_to_cloud(*points, header, **rb)))
    frustums = msg_utils.frustums_to_marker_array(
        model.frustum_lines(), header, width=model.line_width(), **rb
    )
    out.append((5, 'frustums', frustums))
    return out


def _viz_view_events(model: VizModel, v: NovelView, cfg: ProcessConfigs) -> list[tuple[int, str, object]]:
    """The novel view as JPEG (the view_renderer's) and the scene_viz's novel-view frustum and TF."""
    if v.rgb is None or v.camera is None:
        return []
    rb: dict[str, Flavor] = {'flavor': 'rosbags'}
    out: list[tuple[int, str, object]] = []
    if cfg.viewing.jpeg_quality:
        header = msg_utils.make_header(v.stamp, cfg.viewing.frame_id, **rb)
        jpeg = msg_utils.numpy_to_compressed_image(
            v.rgb, quality=cfg.viewing.jpeg_quality, header=header, flavor='rosbags'
        )
        out.append((6, 'view_jpeg', jpeg))
    model.set_novel_view(v.camera, v.t_wc)
    world = model.world or 'map'
    tf = [(v.stamp, world, cfg.scene.novel_view_frame, v.t_wc)]
    out.append((9, 'tf', msg_utils.transforms_to_tf(tf, **rb)))
    header = msg_utils.make_header(v.stamp, world, **rb)
    frustums = msg_utils.frustums_to_marker_array(
        model.frustum_lines(), header, width=model.line_width(), **rb
    )
    out.append((9, 'frustums', frustums))
    return out


def selection_line(sel: dict) -> str:
    """How the keyframes were chosen, for ``summary.md``."""
    if sel['method'] == 'interval':
        return f'without poses, the sharpest frame per {sel["interval_s"]:g} s window'
    if sel['method'] == 'streaming':
        return 'KeyframeSelector frame by frame (as the live frame_subsampler; no target_keyframes)'
    scale = (
        f'baseline scale {sel["scale"]:.3g} (baseline_ratio {sel["baseline_ratio"]:.3g}, '
        f'min_baseline_m {sel["min_baseline_m"]:.3g})'
    )
    return (
        f'select_keyframes over the whole flight, target {sel["target"]}: {sel["selected"]} of '
        f'{sel["frames"]} frames, {scale}'
    )


def summary_markdown(s: dict) -> str:
    """``summary.md``: the summary ``s`` (as in ``summary.json``) as Markdown tables."""
    t, pk = s['timings_s'], s['seconds_per_keyframe']

    def f(v: object, fmt: str = '.3f') -> str:
        return 'n/a' if v is None else format(v, fmt)

    tp = s['topics']
    pose = f'{tp["pose"]} ({tp["pose_type"]})' if tp['pose'] else 'no pose topic'
    lines = [
        f'# ibr process on `{s["bag"]}`',
        '',
        *_first_lines(s),
        '',
        '## Details',
        '',
        f'- input: {tp["image"]} ({tp["image_type"]}), {tp["camera_info"]}, {pose}'
        + (f', {tp["navsat"]} (NavSatFix)' if tp.get('navsat') else ''),
        f'- frames: {s["frames"]["complete"]} complete of {s["frames"]["images"]} images; '
        f'decisions {s["frames"]["decisions"]}; bad or incomplete {s["frames"]["bad"]}',
        f'- keyframe selection: {selection_line(s["keyframe_selection"])}',
        f'- output bag: `{s["output"]["bag"]}` ({sum(s["output"]["topics"].values())} messages)',
    ]
    if (sfm := s.get('sfm')) is not None:
        gps = sfm['gps']
        lines.append(
            f'- SfM mode ({sfm["why"]}; keyframes {sfm["keyframe_selection"]}): {sfm["registered"]}/'
            f'{sfm["keyframes"]} keyframes registered, frame `{sfm["frame_id"]}` (unit {sfm["unit"]}), '
            f'reprojection error {f(sfm["mean_reprojection_error_px"], ".2f")} px, '
            + (
                'no GPS'
                if gps is None
                else f'GPS for {gps["keyframes_with_gps"]} keyframes, alignment RMS '
                f'{f(gps["alignment_rms_m"], ".2f")} m'
            )
            + f'; {sfm["seconds"]:.1f} s'
        )
    lines += [
        '',
        '| stage | seconds | seconds per keyframe |',
        '| --- | --- | --- |',
    ]
    for stage in (
        'subsample',
        *(('sfm',) if s.get('sfm') is not None else ()),
        'schedule',
        'mvs',
        'refine',
        'render',
        'write',
        'pipeline',
        'evaluate',
        'total',
    ):
        lines.append(f'| {stage} | {t[stage]:.2f} | {f(pk[stage])} |')
    if (gt := s.get('ground_truth')) is not None:
        lines += [
            '',
            f'- refined depth vs ground truth: median abs rel {f(gt["depth_median_abs_rel"], ".4f")} '
            f'(median over keyframes), coverage {f(gt["depth_coverage_mean"], ".2f")}'
            + (
                f" (SfM poses fitted to the bag's: scale {gt['sfm_alignment']['scale']:.4g}, centre RMS "
                f'{gt["sfm_alignment"]["centre_rms_m"]:.3f} m, rotation RMS '
                f'{gt["sfm_alignment"]["rotation_rms_deg"]:.2f} deg)'
                if gt.get('sfm_alignment')
                else ''
            ),
            f'- novel views vs ground truth (7x7, shift 2): mean AUC {f(gt["rephoto_auc_mean"], ".2f")}, '
            f'mean worst-1% {f(gt["rephoto_tail_mean"], ".2f")}, completeness '
            f'{f(gt["rephoto_completeness_mean"], ".2f")}',
        ]
    return '\n'.join(lines) + '\n'


def refine_warnings(refine: dict) -> list[str]:
    """Per-keyframe warnings of :func:`~ibr_ros.jobs.process.refine.refine_all`'s result: every keyframe
    not refined, and the scheduler's warnings but those about a keyframe already listed."""
    not_refined = refine.get('not_refined', {})
    out = [f'keyframe {st} ns not refined: {why}' for st, why in not_refined.items()]
    return out + [w for w in refine.get('warnings', []) if not any(f'{st} ns' in w for st in not_refined)]


def _first_lines(s: dict) -> list[str]:
    """What a user must know first: registered, GPS alignment, refined, answered, and the warnings."""
    n, fr = s['keyframes'], s['frames']
    sfm = s.get('sfm')
    lines = [f'- **keyframes**: {n} of {fr["complete"]} frames (decisions {fr["decisions"]})']
    if sfm is not None:
        lines.append(
            f'- **registered**: {sfm["registered"]}/{sfm["keyframes"]} keyframes (SfM, {sfm["why"]}; '
            f'frame `{sfm["frame_id"]}`)'
        )
        gps = sfm['gps']
        if gps is None:
            lines.append('- **GPS alignment**: none (no NavSatFix topic or --no-gps): frame `sfm`, no metres')
        elif gps['alignment_rms_m'] is None:
            lines.append(
                f'- **GPS alignment**: failed ({gps["keyframes_with_gps"]} keyframes with GPS): frame `sfm`'
            )
        else:
            lines.append(
                f'- **GPS alignment**: {gps["alignment_inliers"]}/{gps["keyframes_with_gps"]} keyframes '
                f'inliers, RMS {gps["alignment_rms_m"]:.2f} m, max {gps["alignment_max_m"]:.2f} m'
            )
    else:
        lines.append(f"- **poses**: the bag's ({s['topics']['pose']}) for all {n} keyframes")
    lines += [
        f'- **refined**: {s["refined"]}/{n} keyframes',
        f'- **answered**: {s["views_answered"]}/{s["views_requested"]} novel views{_fractions(s)}',
    ]
    warnings = []
    if sfm is not None:
        warnings += [f'keyframe {st} ns: {why}' for st, why in sfm['dropped'].items()]
    warnings += refine_warnings(s.get('refine') or {})
    unusable = (s.get('render') or {}).get('unusable_views', {})
    warnings += [f'keyframe {st} ns not rendered from: {why}' for st, why in unusable.items()]
    for v in s.get('novel_views', []):
        if v['result'] != 'answered':
            what = 'published incomplete' if v['result'] == 'incomplete' else 'not answered'
            warnings.append(f'novel view {v["stamp"]} ns {what}: {v["reason"]}: {v["message"]}')
    if warnings:
        lines += [f'- **warnings** ({len(warnings)}):', *(f'  - {w}' for w in warnings)]
    else:
        lines.append('- **warnings**: none')
    return lines


def _fractions(s: dict) -> str:
    """`` (valid fraction min .. max, median m)`` of the rendered novel views; '' when none was."""
    rendered = [
        v for v in s.get('novel_views', []) if v['result'] != 'refused' or v['reason'] == 'incomplete'
    ]
    fr = [v['valid_fraction'] for v in rendered]
    if not fr:
        return ''
    return f' (valid fraction {min(fr):.2f} .. {max(fr):.2f}, median {float(np.median(fr)):.2f})'


def json_default(value: object) -> object:
    """``json.dumps`` ``default`` of the summary: numpy scalars as Python numbers, NaN and inf as null."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    raise TypeError(f'not JSON serialisable: {type(value).__name__}')
