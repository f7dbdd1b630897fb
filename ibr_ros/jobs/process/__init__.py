# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr process``: a whole bag through the node graph's pipeline in one process, into an output bag.

The same core code as the nodes, run synchronously in bag-time order (deterministic):

1. subsample: camera image (``Image`` or ``CompressedImage``), ``CameraInfo`` and pose
   (``PoseStamped`` or ``Odometry``) matched by identical header stamps, then blur
   (:func:`~ibr_ros.core.flight.keyframes.blur_px`) + :class:`~ibr_ros.core.flight.keyframes.KeyframeSelector`
   with the frame_subsampler's parameters, frame by frame as live; or, with its ``target_keyframes``
   > 0 (``ProcessOptions.target_keyframes`` overrides it) on a bag with poses,
   :func:`~ibr_ros.core.flight.keyframes.select_keyframes` over the whole flight: the same blur,
   ``KeyframeConfig`` and ``scene_depth_m``, with ``baseline_ratio`` and ``min_baseline_m`` scaled by
   the common factor that gives about ``target_keyframes`` (the frame_subsampler's
   ``expected_path_m`` is not used: the flight is known). Two passes over the bag: stamps, poses and
   blur of every frame, then the chosen frames' images (no other image decoded); the summary's
   ``keyframe_selection`` gives the method, and for a target the count and the scale;
2. MVS + refine: once the whole flight is known, every keyframe (oldest first) is refined once
   with the neighbours and depth range :class:`~ibr_ros.core.depth.schedule.RefineScheduler` gives it
   (the depth_refiner's policy at the end of a flight), by
   :func:`~ibr_ros.core.depth.mvs.compute_depth_maps` and
   :meth:`~ibr_ros.core.depth.refine.DepthRefiner.refine_from_mvs`;
3. render: :class:`~ibr_ros.core.render.renderer.NovelViewRenderer` (the view_renderer's parameters) at
   ``views`` poses along the keyframe path (:func:`ibr_ros.core.geometry.path.interpolate_path`).

SfM mode (the depth_refiner's ``sfm_mode``; ``ProcessOptions.sfm`` forces it): a bag without a pose
topic (``sfm_mode`` ``auto`` or ``always``; ``off`` refuses it), or any bag with ``sfm`` (its poses
are then ignored). Keyframes are chosen without poses as the frame_subsampler does without poses
(its ``pose_source`` ``auto``; ``topic`` refuses, ``none`` always): the sharpest unblurred frame of
every ``poseless_interval_s`` window, or a blurred one kept for overlap
(:class:`~ibr_ros.core.flight.keyframes.IntervalSelector`). With
``sfm_mode`` ``always`` on a bag with poses the keyframes are chosen by pose (as live) and their
poses ignored. Then all keyframes (at least ``sfm_min_keyframes``) are registered together by ONE
:meth:`~ibr_ros.core.registration.sfm_session.SfmSession.update` (images downscaled to ``sfm_max_side``; no
incremental updates offline), with GPS positions from the bag's ``NavSatFix`` topic when there is
one (converted to ENU metres with the first usable fix as origin and interpolated linearly to the
keyframe stamps, at most :data:`GPS_MAX_GAP_S` from a fix, as ``ibr register`` does). Frame of the
result: ENU metres (frame_id ``map``) when the model could be aligned to >= 3 GPS positions, else
the documented ``sfm`` frame (frame_id ``sfm``; unit = the first keyframe baseline, or metres with
``sfm_scale`` + ``sfm_scale_m``; without a scale ``depth_range`` and ``scene_depth_m`` are ignored,
like the node). Unregistered keyframes are dropped (logged, and listed in the summary). The
registered keyframes get SfM's refined shared camera (not the bag's CameraInfo, possibly an initial
guess) and are undistorted with it (:func:`~ibr_ros.core.geometry.undistort.undistort_image`, valid pixels
only, same size): MVS needs undistorted pinholes. From there on as for a posed bag.

Memory does not grow with the flight: keyframe images, depth and confidence wait on disk in
``.<out>.spill-<pid>`` next to the output folder (:mod:`~ibr_ros.jobs.process.spill`, removed when
the run ends, however it ends) and the output bag is written one keyframe or view at a time.

Parameters: ``config/<node>.yaml`` of the three nodes, overridden by a ROS 2 params file
(sections ``/**``, ``<node>`` or ``/<ns>/<node>``), so live and offline runs agree.

Output folder: ``bag/`` (ROS 2 mcap bag, written atomically) with the graph's topics and types:
``/keyframes/image`` (rgb8; undistorted in SfM mode), ``/keyframes/camera_info``,
``/keyframes/pose`` (the bag's poses, or SfM's in frame ``map``/``sfm``), ``/keyframes/depth``
(32FC1 metres or ``sfm`` units, REP-118: NaN unknown, +inf sky), ``/keyframes/depth/camera_info``,
``/keyframes/depth/confidence`` (32FC1 in [0, 1]), ``/novel_view/query`` (PoseStamped), for every query its
``/novel_view/status`` (DiagnosticArray, as the view_renderer's: answered or refused and why, the
valid fraction) and, for answered queries (and incomplete ones with ``publish_incomplete``),
``/novel_view/image`` (rgb8) + ``/novel_view/camera_info``, all with the query's stamp (the midpoint
of its two keyframes' stamps); the scene_viz's ``/tf``, ``/tf_static``, ``/keyframes/poses``,
``/keyframes/frustums``, ``/keyframes/points``; and, when the input has a NavSatFix topic (any name),
every fix read from it as recorded (also those without a fix: their status says so; a message that
does not convert is counted under ``frames.bad.navsat``) on ``/gps/fix``, the viewer layout's map
topic, with a sensor driver's QoS, whether or not SfM used them (``gps`` / ``--no-gps`` only decide
that); log time = header stamp. ``previews/*.png`` (each novel view labelled
with its valid fraction); ``summary.json`` (``novel_views``: every query's status) and
``summary.md`` (counts, timings, seconds per keyframe, the SfM statistics, the novel views' valid
fractions and, for a synthetic bag with ``synth.json``, depth and rephotography errors against the exact
ground truth; in SfM mode only when the bag has poses, after a similarity fit of the SfM camera
centres to them: depths are scaled by its scale, novel view poses moved by it).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np

from ibr_ros.core.render import ReplyStatus
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.jobs.process.evaluate import evaluate_ground_truth
from ibr_ros.jobs.process.frames import Keyframe, subsample
from ibr_ros.jobs.process.options import ProcessOptions, Progress
from ibr_ros.jobs.process.output import OUT_TOPICS, json_default, summary_markdown, write_bag
from ibr_ros.jobs.process.params import NODES, ProcessConfigs, load_params, process_configs
from ibr_ros.jobs.process.refine import refine_all
from ibr_ros.jobs.process.render import NovelView, render_all
from ibr_ros.jobs.process.sfm import GPS_MAX_GAP_S, register_keyframes
from ibr_ros.jobs.process.spill import SpillStore

__all__ = [
    'GPS_MAX_GAP_S',
    'NODES',
    'OUT_TOPICS',
    'Keyframe',
    'NovelView',
    'ProcessOptions',
    'load_params',
    'process_bag',
]


def process_bag(
    bag: Path, out: Path, options: ProcessOptions | None = None, progress: Progress | None = None
) -> dict[str, object]:
    """Process ``bag`` into the folder ``out`` (see the module docstring); returns the summary.

    Raises:
        UserError: Unreadable bag, missing topics, no frames or keyframes, bad parameters, an
            existing ``out/bag`` without ``overwrite``.

    """
    o = options or ProcessOptions()
    bag, out = Path(bag), Path(out)
    if o.views < 0:
        raise UserError(f'--views must be >= 0, got {o.views}')
    if o.max_keyframes is not None and o.max_keyframes < 1:
        raise UserError(f'--max-keyframes must be >= 1, got {o.max_keyframes}')
    _check_out(out, o.overwrite)
    params = load_params(o.params)
    cfg = process_configs(params, o)
    threads = _set_threads(o.threads)
    if out.parent.is_dir():
        _remove_stale_stages(out)
    # Keyframe images, depth and confidence wait on disk next to out (memory does not grow with
    # the flight; spill.py); the folder goes when the run ends, however it ends.
    with SpillStore(out.parent / f'.{out.name}.spill-{os.getpid()}') as store:
        return _process(bag, out, o, params, cfg, threads, store, progress)


def _process(
    bag: Path,
    out: Path,
    o: ProcessOptions,
    params: dict,
    cfg: ProcessConfigs,
    threads: int,
    store: SpillStore,
    progress: Progress | None,
) -> dict[str, object]:
    """:func:`process_bag` once its options are checked, with keyframe arrays spilled to ``store``."""
    t_start = time.perf_counter()
    sub = subsample(bag, cfg, o, progress, spill=lambda a: store.put(a, 'rgb'))
    keyframes = sub.keyframes
    t_sub = time.perf_counter()
    sfm_info, sparse = None, None
    if sub.sfm_why is not None:
        keyframes, cfg, sfm_info, sparse = register_keyframes(sub, cfg, o.threads, progress)
        for k in keyframes:  # undistorted in memory: spilled again
            k.rgb = store.put(k.rgb, 'rgb')
    t_sfm = time.perf_counter()
    refine_info = refine_all(keyframes, cfg, progress, sparse, spill=store.put)
    t_ref = time.perf_counter()
    views, render_info = render_all(keyframes, cfg, o.views, progress)
    t_render = time.perf_counter()
    # Everything goes into a staging folder next to out, renamed to out once complete: an
    # interrupted or failed run leaves the previous result as it was.
    stage = out.parent / f'.{out.name}.partial-{os.getpid()}'
    stage.mkdir(parents=True)
    try:
        model_frame = str(render_info.get('model_frame', keyframes[0].pose_frame))
        topic_counts = write_bag(stage / 'bag', keyframes, views, cfg, model_frame, progress, sub.navsat)
        t_write = time.perf_counter()
        previews = stage / 'previews'
        previews.mkdir()
        gt = evaluate_ground_truth(bag, keyframes, views, previews, progress, sfm=sfm_info is not None)
        t_eval = time.perf_counter()

        refined = [k for k in keyframes if k.depth is not None]
        mvs_s = sum(k.timings_s.get('mvs', 0.0) for k in keyframes)
        refine_s = sum(k.timings_s.get('refine', 0.0) for k in keyframes)
        timings = {
            'subsample': t_sub - t_start,
            'sfm': t_sfm - t_sub,
            'mvs': mvs_s,
            'refine': refine_s,
            'schedule': (t_ref - t_sfm) - mvs_s - refine_s,
            'render': t_render - t_ref,
            'write': t_write - t_render,
            'pipeline': t_write - t_start,
            'evaluate': t_eval - t_write,
            'total': t_eval - t_start,
        }
        n = len(keyframes)
        answered = [v for v in views if v.rgb is not None]
        summary: dict[str, object] = {
            'bag': str(bag),
            'topics': sub.topics,
            'params': params,
            'threads': threads,
            'frames': {
                'images': sub.counts['image'],
                'camera_info': sub.counts['camera_info'],
                'poses': sub.counts['pose'],
                'navsat': sub.counts['navsat'],
                'complete': sub.counts['frames'],
                'decisions': dict(sorted(sub.decisions.items())),
                'bad': dict(sorted(sub.bad.items())),
                'stopped_at_max_keyframes': sub.stopped,
            },
            'keyframe_selection': sub.selection,
            'sfm': sfm_info,
            'keyframes': n,
            'refined': len(refined),
            'refine': refine_info,
            'views_requested': len(views),
            'views_answered': len(answered),
            'unanswered': {str(v.stamp): v.reason for v in views if v.rgb is None},
            'novel_views': [_view_row(v.stamp, v.status) for v in views if v.status is not None],
            'render': render_info,
            'render_ms_median': float(np.median([1e3 * v.render_s for v in views])) if views else None,
            'output': {'bag': str(out / 'bag'), 'topics': topic_counts},
            'timings_s': timings,
            'seconds_per_keyframe': {k: v / n for k, v in timings.items()},
            'per_keyframe': [
                {
                    'stamp': k.stamp,
                    'reason': k.reason,
                    'refined': k.depth is not None,
                    'neighbours': list(k.neighbours),
                    **{f'{s}_s': t for s, t in k.timings_s.items()},
                }
                for k in keyframes
            ],
            'ground_truth': gt,
        }
        write_atomic(stage / 'summary.json', json.dumps(summary, indent=2, default=json_default) + '\n')
        write_atomic(stage / 'summary.md', summary_markdown(summary))
        _commit(stage, out)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return summary


def _view_row(stamp: int, st: ReplyStatus) -> dict[str, object]:
    """A novel view's entry in the summary: its status, as the view_renderer's ``novel_view/status``."""
    return {
        'stamp': stamp,
        'result': st.result,
        'reason': st.reason,
        'valid_fraction': st.valid_fraction,
        'message': st.message,
        'views': list(st.views),
        'render_ms': st.render_ms,
    }


#: What ``ibr process`` writes into its output folder.
OUTPUTS = ('bag', 'previews', 'summary.json', 'summary.md')


def _check_out(out: Path, overwrite: bool) -> None:
    """Refuse an output folder that would lose something: a result without ``overwrite``, other files."""
    if out.exists() and not out.is_dir():
        raise UserError(f'{out} is not a folder')
    if (out / 'bag').exists() and not overwrite:
        raise UserError(f'{out / "bag"} exists already (pass --overwrite to replace it)')
    if out.is_dir() and (other := sorted(p.name for p in out.iterdir() if p.name not in OUTPUTS)):
        raise UserError(
            f'{out} holds other files ({", ".join(other[:5])}): ibr process replaces its output folder '
            'as a whole; choose an empty or new folder'
        )


def _commit(stage: Path, out: Path) -> None:
    """Put the complete ``stage`` in place of ``out`` (two renames; the old result is removed last,
    and put back if the second rename fails)."""
    old = out.parent / f'.{out.name}.old-{os.getpid()}'
    if out.exists():
        out.rename(old)
    try:
        stage.rename(out)
    except OSError:
        if old.exists():
            old.rename(out)
        raise
    shutil.rmtree(old, ignore_errors=True)


def _remove_stale_stages(out: Path) -> None:
    """Staging and old-result folders of earlier runs for ``out`` whose process is gone."""
    for p in out.parent.glob(f'.{out.name}.*-*'):
        kind, _, pid = p.name.rpartition('-')
        if not kind.endswith(('.partial', '.old', '.spill')) or not pid.isdigit():
            continue
        if not Path(f'/proc/{pid}').exists() or int(pid) == os.getpid():
            shutil.rmtree(p, ignore_errors=True)


def _set_threads(threads: int | None) -> int:
    """Use ``threads`` numba and OpenCV threads (None: numba's default, all cores); returns the count."""
    import numba

    if threads is not None:
        most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at run time by numba.config
        if not 1 <= threads <= most:
            raise UserError(f'--threads must be in 1..{most}, got {threads}')
        numba.set_num_threads(threads)
        cv2.setNumThreads(threads)
    return int(numba.get_num_threads())
