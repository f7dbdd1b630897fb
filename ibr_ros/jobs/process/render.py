# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Novel views along the keyframe path, rendered from the refined keyframes (the view_renderer)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.path import interpolate_path, path_stamps
from ibr_ros.core.render import NovelViewRenderer, ReplyStatus, SourceView, output_camera
from ibr_ros.jobs.process.frames import Keyframe
from ibr_ros.jobs.process.options import Progress
from ibr_ros.jobs.process.params import ProcessConfigs
from ibr_ros.jobs.process.spill import remapped


@dataclass
class NovelView:
    """One query along the path: ``stamp`` (ns), pose, its status (the view_renderer's
    ``novel_view/status``) and the published view (None when refused; ``reason`` says why)."""

    stamp: int
    t_wc: np.ndarray
    camera: PinholeCamera | None = None
    rgb: np.ndarray | None = None
    valid: np.ndarray | None = None
    reason: str | None = None
    render_s: float = 0.0
    status: ReplyStatus | None = None


def render_all(
    keyframes: list[Keyframe], cfg: ProcessConfigs, n_views: int, progress: Progress | None
) -> tuple[list[NovelView], dict[str, object]]:
    """The view_renderer's model of the refined keyframes and its replies to the path queries."""
    model = [k for k in keyframes if k.depth is not None]
    unusable: dict[str, str] = {}
    info: dict[str, object] = {'model_views': len(model), 'unusable_views': unusable}
    if not model:
        return [], info
    model_frame = model[0].pose_frame
    renderer = NovelViewRenderer([], cfg.viewing.render)
    t0 = time.perf_counter()
    for n_done, k in enumerate(model, 1):
        if k.pose_frame != model_frame:
            unusable[str(k.stamp)] = f'frame {k.pose_frame!r}, the model is in {model_frame!r}'
            if progress is not None:
                progress('model', n_done, len(model))
            continue
        i = renderer.add_view(
            SourceView(
                k.rgb,
                k.depth,
                k.camera,
                k.t_wc,
                name=str(k.stamp),
                stamp=k.stamp * 1e-9,
                confidence=k.confidence,
            )
        )
        renderer.prepare([i])
        # Spilled arrays: fresh mappings for the keyframe and the renderer's view (same values), so
        # that the pages the preparation read are not kept resident for every keyframe.
        k.rgb = remapped(k.rgb)
        k.depth, k.confidence = (None if a is None else remapped(a) for a in (k.depth, k.confidence))
        renderer.views[i] = replace(renderer.views[i], rgb=k.rgb, depth=k.depth, confidence=k.confidence)
        if (why := renderer.skip_reason(i)) is not None:
            unusable[str(k.stamp)] = why
        if progress is not None:
            progress('model', n_done, len(model))
    info['prepare_s'] = time.perf_counter() - t0
    camera = output_camera(cfg.viewing.width, cfg.viewing.height, cfg.viewing.hfov_deg, model[-1].camera)
    poses = interpolate_path([k.t_wc for k in model], n_views)
    stamps = path_stamps([k.stamp for k in model], n_views)
    views = [NovelView(s, t) for s, t in zip(stamps, poses, strict=True)]
    policy = cfg.viewing.reply
    for j, v in enumerate(views):
        t1 = time.perf_counter()
        out = renderer.render(v.t_wc, camera)
        v.render_s = time.perf_counter() - t1
        if out.reason is not None:
            v.status = policy.refuse('unrenderable', out.reason)
        else:
            used = [renderer.views[i].name for i in out.used_views]
            v.status = policy.judge(float(out.valid.mean()), used, 1e3 * v.render_s)
        if v.status.published:
            v.camera, v.rgb, v.valid = camera, out.rgb, out.valid
        if v.status.result != 'answered':
            v.reason = f'{v.status.reason}: {v.status.message}'
        if progress is not None:
            progress('views', j + 1, len(views))
    info['model_frame'] = model_frame
    info['camera'] = {'width': camera.width, 'height': camera.height, 'hfov_deg': camera.hfov_deg}
    return views, info
