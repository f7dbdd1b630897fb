# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Renderer settings: :class:`RenderConfig` and the fields that give the paper's renderer exactly."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

__all__ = ['PAPER_FIELDS', 'RenderConfig']

#: The fields that make :class:`RenderConfig` the renderer exactly as in the paper (see ``as_paper``).
PAPER_FIELDS: dict[str, object] = {
    'blend': 'paper',
    'depth_split': None,
    'coverage_px': None,
    'depth_tolerance': None,
    'resolution_weight_deg': 0.0,
    'depth_lookup_steps': 0,
    'min_depth_samples': 10,
    'confidence_weight_deg': 0.0,
    'fill_holes_px': 0,
}


@dataclass(frozen=True)
class RenderConfig:
    """Renderer settings (angles in degrees, distances in metres, image distances in pixels).

    The defaults are this project's renderer: the paper's pipeline plus five additions
    (``depth_split``, ``coverage_px``, ``depth_tolerance``, ``blend='ulr'`` with the resolution term
    and ``depth_lookup_steps``; see :mod:`ibr_ros.core.render.renderer`).
    :meth:`as_paper` / :meth:`paper` switch them off: the paper exactly.

    Attributes:
        blend: ``'paper'`` (smallest penalty wins), ``'soft'`` (Gaussian falloff of the penalty),
            ``'ulr'`` (weights ``1 - p / p_max`` over the views covering the pixel, as ULR) or
            ``'stable'`` (weights ``g * exp(-p / stable_sigma_deg)``, ``g`` a view's selection gain
            that fades it out before it leaves the nearest ``n_views``: every weight continuous in
            the pose, for navigation without flicker).
        resolution_weight_deg: degrees added to a view's angle penalty per unit of ULR's resolution
            term ``max(0, (|a - C_s| - |a - C_n|) / |a - C_s|)`` (0: the paper's angle only).
        depth_split, depth_split_levels, depth_split_min_px: split superpixels at depth steps larger
            than ``depth_split`` (log depth; None: off) before warping, see
            :func:`~ibr_ros.core.render.superpixels.split_at_depth_edges`.
        coverage_px: a warped superpixel claims a novel pixel only where the source pixel under it,
            reprojected with its own depth, lands within this many px (None: off; unknown depth and
            sky always pass).
        depth_tolerance: the views covering a pixel vote on its depth with this relative tolerance;
            a strict majority excludes the others from the blend (None: off).
        n_views: source views per query, 1..4 (paper: 4).
        n_segments, compactness: SLIC parameters per source view.
        max_samples: reprojection samples per superpixel (Eq. 16; see :mod:`ibr_ros.core.render.warp`).
        shape_weight: weight of the shape term ``E_s`` in Eq. 18 (paper: 1).
        triangle_margin: px between a superpixel's box and its circumscribed triangle.
        near: depth-test plane of the novel camera (m).
        max_axis_angle_deg: views whose optical axis is farther from the novel one are ignored.
        far_factor, max_distance_m: distance limit: ``max_distance_m``, by default ``far_factor``
            times the median scene depth of the views (see
            :meth:`~ibr_ros.core.render.renderer.NovelViewRenderer.distance_limit`).
        max_magnification: linear magnification above which a warped superpixel is dropped.
        soft_sigma_deg: falloff of ``blend='soft'``.
        stable_sigma_deg, stable_fade: ``blend='stable'``: penalty falloff (degrees) and the fraction of
            the left-out view's distance over which a selected view fades out
            (:func:`~ibr_ros.core.render.renderer.selection_gains`).
        ulr_blend_min_weight: ``blend='ulr'`` leaves out views whose weight is below this fraction
            of the best view's (0: all).
        depth_lookup_steps, depth_lookup_max_px, depth_lookup_min_fit_px: per-pixel correction of
            the colour lookup with the source depth: Newton steps (0: off), at most this many px,
            only in superpixels whose affine warp misses its samples by more than this (RMS px;
            0: all).
        max_cached_views: LRU size of the per-view cache.
        min_depth_samples, min_depth_fraction: ``has_depth`` rule of ``superpixel_stats``.
        confidence_weight_deg: angle penalty (degrees) added to a superpixel per unit of missing
            depth confidence (``1 - mean confidence`` of its pixels, when the view has one): low
            confidence loses the blend (0: off, the paper).
        sky_depth_factor: sky pixels (depth ``+inf``) are warped at this times the view's largest
            finite depth (the paper's Eq. 14: 2); 0 warps them as directions (rotation only).
        fill_holes_px: holes of the render up to this many pixels that do not touch its border
            (cracks between warped superpixels) are filled from their surroundings (0: off).
    """

    blend: Literal['paper', 'soft', 'ulr', 'stable'] = 'ulr'
    resolution_weight_deg: float = 40.0
    depth_split: float | None = 0.02
    depth_split_levels: int = 2
    depth_split_min_px: int = 2
    coverage_px: float | None = 1.0
    depth_tolerance: float | None = 0.5
    n_views: int = 4
    n_segments: int = 1500
    compactness: float = 10.0
    max_samples: int = 64
    shape_weight: float = 1.0
    triangle_margin: float = 1.0
    near: float = 0.05
    max_axis_angle_deg: float = 90.0
    far_factor: float = 3.0
    max_distance_m: float | None = None
    max_magnification: float = 8.0
    soft_sigma_deg: float = 2.0
    stable_sigma_deg: float = 4.0
    stable_fade: float = 0.3
    ulr_blend_min_weight: float = 0.3
    depth_lookup_steps: int = 2
    depth_lookup_max_px: float = 1.0
    depth_lookup_min_fit_px: float = 0.08
    max_cached_views: int = 64
    min_depth_samples: int = 2
    min_depth_fraction: float = 0.05
    confidence_weight_deg: float = 10.0
    sky_depth_factor: float = 2.0
    fill_holes_px: int = 256

    def __post_init__(self) -> None:
        if self.blend not in ('paper', 'soft', 'ulr', 'stable'):
            raise ValueError(f"blend must be 'paper', 'soft', 'ulr' or 'stable', got {self.blend!r}")
        if not 1 <= self.n_views <= 4:
            raise ValueError(f'n_views must be 1..4, got {self.n_views}')
        positive: tuple[str, ...] = ('n_segments', 'max_cached_views', 'near', 'far_factor')
        positive += ('soft_sigma_deg', 'stable_sigma_deg')
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if not 0 < self.stable_fade <= 1:
            raise ValueError(f'stable_fade must be in (0, 1], got {self.stable_fade}')
        if not 0 <= self.ulr_blend_min_weight < 1:
            raise ValueError(f'ulr_blend_min_weight must be in [0, 1), got {self.ulr_blend_min_weight}')
        if not 0 < self.max_axis_angle_deg <= 180 or not self.max_magnification >= 1:
            raise ValueError('need 0 < max_axis_angle_deg <= 180 and max_magnification >= 1')
        if (
            self.depth_lookup_steps < 0
            or not self.depth_lookup_max_px > 0
            or not self.depth_lookup_min_fit_px >= 0
        ):
            raise ValueError(
                'need depth_lookup_steps >= 0, depth_lookup_max_px > 0 and depth_lookup_min_fit_px >= 0, got '
                f'{self.depth_lookup_steps}, {self.depth_lookup_max_px}, {self.depth_lookup_min_fit_px}'
            )
        for name in ('depth_tolerance', 'coverage_px', 'depth_split'):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f'{name} must be None (off) or > 0, got {value}')
        if not 0 <= self.depth_split_levels <= 8 or self.depth_split_min_px < 0:
            raise ValueError(
                f'need depth_split_levels 0..8 and depth_split_min_px >= 0, got {self.depth_split_levels}, '
                f'{self.depth_split_min_px}'
            )
        for name in ('resolution_weight_deg', 'confidence_weight_deg', 'sky_depth_factor', 'fill_holes_px'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')

    def as_paper(self) -> RenderConfig:
        """This configuration with the paper's renderer: :data:`PAPER_FIELDS` (best-angle blend,
        SLIC superpixels as they come, angle-only penalty, no per-pixel or cross-view depth tests)."""
        return replace(self, **PAPER_FIELDS)  # type: ignore[arg-type]  # field names with values of their types

    @classmethod
    def paper(cls, **changes: object) -> RenderConfig:
        """The paper's renderer with the other defaults (``changes`` override any field)."""
        return replace(cls().as_paper(), **changes)  # type: ignore[arg-type]  # RenderConfig checks them
