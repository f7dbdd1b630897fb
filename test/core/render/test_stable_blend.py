# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``blend='stable'``: view weights continuous in the pose, so a sweep past a change of the nearest
views (and of the best view) renders without jumps, where the paper's best-view selection jumps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ibr_ros.core.evaluation.flicker import excess_flicker
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import matrix_from_rt
from ibr_ros.core.render import NovelViewRenderer, RenderConfig, SourceView, selection_gains
from ibr_ros.core.render.renderer import MIN_GAIN

DEPTH = 10.0  # m: a fronto-parallel textured wall
CAM = PinholeCamera.from_fov(96, 64, 60.0)


def _wall(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth colour texture of the wall at world ``(x, y)`` (m), 0..255 float."""
    return np.stack(
        [
            128 + 60 * np.sin(0.9 * x + 0.3) * np.cos(0.7 * y),
            128 + 60 * np.sin(0.5 * x - 1.1 * y),
            128 + 50 * np.cos(1.3 * x),
        ],
        axis=-1,
    )


def _image(cx: float, cy: float, tint: float) -> np.ndarray:
    """What a camera at ``(cx, cy, 0)`` looking along world +z (identity rotation) sees of the wall,
    its colours offset by ``tint`` (view-dependent colour: what makes switching views visible)."""
    u, v = np.meshgrid(np.arange(CAM.width, dtype=float), np.arange(CAM.height, dtype=float))
    x = cx + (u - CAM.cx) / CAM.fx * DEPTH
    y = cy + (v - CAM.cy) / CAM.fy * DEPTH
    return np.clip(_wall(x, y) + tint, 0, 255).astype(np.uint8)


def _view(cx: float, tint: float) -> SourceView:
    depth = np.full((CAM.height, CAM.width), DEPTH, np.float32)
    return SourceView(_image(cx, 0.0, tint), depth, CAM, matrix_from_rt(np.eye(3), [cx, 0.0, 0.0]))


def _max_step(cfg: RenderConfig) -> float:
    """Largest excess flicker (16 px blocks, 0..255) between consecutive renders of a sweep from
    x = 1.2 to 3.8 m against the exact wall (the 4 nearest of the 6 views change at 1.5, 2.5 and
    3.5 m, and so does the best view)."""
    views = [_view(float(i), 12.0 * i) for i in range(6)]
    r = NovelViewRenderer(views, cfg)
    renders, truths, valids = [], [], []
    for x in np.arange(1.2, 3.8, 0.05):
        out = r.render(matrix_from_rt(np.eye(3), [x, 0.3, 0.0]), CAM)
        assert out.valid.mean() > 0.9
        renders.append(out.rgb)
        valids.append(out.valid)
        truths.append(_image(x, 0.3, 0.0))
    return float(excess_flicker(renders, truths, valids).max())


@pytest.fixture(scope='module')
def steps() -> dict[str, float]:
    base = RenderConfig(n_segments=150, fill_holes_px=0)
    return {b: _max_step(replace(base, blend=b)) for b in ('paper', 'ulr', 'stable')}


def test_stable_sweep_has_no_jump(steps: dict[str, float]) -> None:
    # the texture moves ~0.4 px per step; the tint differs by 12 levels between neighbouring views
    assert steps['paper'] > 2.0  # the best view switches: a jump of a good part of the tint difference
    assert steps['stable'] < 0.5
    assert steps['stable'] < 0.25 * steps['paper']
    assert steps['stable'] < steps['ulr']


def test_selection_gains_fade_a_view_out_before_it_leaves() -> None:
    centres = [np.array([float(i), 0.0, 0.0]) for i in range(6)]
    prev = None
    for x in np.linspace(1.0, 4.0, 301):  # the query moves along the line of views
        d = np.abs(np.arange(6) - x)
        order = np.argsort(d, kind='stable')
        chosen, nxt = order[:4], order[4]
        g = selection_gains([x, 0.0, 0.0], [centres[i] for i in chosen], centres[nxt], 0.3)
        assert g.min() >= MIN_GAIN
        assert g.max() <= 1.0
        gain_of = dict(zip(chosen.tolist(), g.tolist(), strict=True))
        gain_of.setdefault(int(nxt), 0.0)  # a view left out has weight 0
        if (
            prev is not None
        ):  # continuous: every view's gain moves a little per step, also when the set changes
            for i in range(6):
                assert abs(gain_of.get(i, 0.0) - prev.get(i, 0.0)) < 0.1
        prev = gain_of
    assert selection_gains([0.0, 0.0, 0.0], centres[:4], None, 0.3).tolist() == [1.0] * 4


def test_stable_blend_is_a_config_choice() -> None:
    with pytest.raises(ValueError, match='stable_fade'):
        RenderConfig(blend='stable', stable_fade=0.0)
    with pytest.raises(ValueError, match='stable_sigma_deg'):
        RenderConfig(blend='stable', stable_sigma_deg=0.0)
    assert (RenderConfig().blend, RenderConfig().stable_sigma_deg) == ('ulr', 4.0)
