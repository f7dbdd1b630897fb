"""Node parameters -> core configurations, shared by the rclpy nodes and ``ibr process`` (no rclpy).

Errors are :class:`~ibr_ros.errors.UserError` naming the parameter and its value, e.g. ``parameter
sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'``; ``ibr process`` prefixes the node name.
"""

from __future__ import annotations

from ibr_ros.core.depth.mvs import MvsOptions
from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.registration.sfm_session import ScaleHint
from ibr_ros.core.render.renderer import RenderConfig
from ibr_ros.errors import UserError
from ibr_ros.models import mono_spec, sky_spec

__all__ = ['RENDER_PARAMETERS', 'SFM_MODES', 'SFM_SCALES', 'refiner_config', 'render_config', 'sfm_settings']

#: ``sfm_mode`` of the depth_refiner: register pose-less keyframes 'auto'(matically), 'always' or not.
SFM_MODES = ('auto', 'always', 'off')
#: ``sfm_scale`` of the depth_refiner: what ``sfm_scale_m`` measures (see :class:`ScaleHint`).
SFM_SCALES = ('none', 'baseline', 'altitude', 'depth')


def sfm_settings(mode: str, scale: str, scale_m: float) -> ScaleHint | None:
    """Check the depth_refiner's ``sfm_mode``, ``sfm_scale`` and ``sfm_scale_m``; the scale hint."""
    if mode not in SFM_MODES:
        raise UserError(f"parameter sfm_mode must be 'auto', 'always' or 'off', got {mode!r}")
    if scale not in SFM_SCALES:
        raise UserError(
            f"parameter sfm_scale must be 'none', 'baseline', 'altitude' or 'depth', got {scale!r}"
        )
    if scale == 'none':
        return None
    if scale_m <= 0:
        raise UserError(f'parameter sfm_scale_m must be > 0 with sfm_scale {scale!r}, got {scale_m}')
    return ScaleHint(scale, scale_m)  # type: ignore[arg-type]


def refiner_config(
    mono: str, mono_model: str, mono_preset: str, sky: str, sky_model: str, sky_preset: str, mvs: MvsOptions
) -> RefinerConfig:
    """The depth_refiner's ``mono*`` and ``sky*`` parameters as a :class:`RefinerConfig` (models resolved
    by :func:`~ibr_ros.models.mono_spec` / :func:`~ibr_ros.models.sky_spec`, not loaded)."""
    if mono not in ('plane', 'onnx'):
        raise UserError(f"parameter mono must be 'plane' or 'onnx', got {mono!r}")
    if sky not in ('fallback', 'onnx', 'none'):
        raise UserError(f"parameter sky must be 'fallback', 'onnx' or 'none', got {sky!r}")
    return RefinerConfig(
        mono=mono,  # type: ignore[arg-type]
        mono_model=mono_spec(mono_model, mono_preset) if mono == 'onnx' else None,
        sky=sky,  # type: ignore[arg-type]
        sky_model=sky_spec(sky_model, sky_preset) if sky == 'onnx' else None,
        mvs=mvs,
    )


#: view_renderer parameters that configure the renderer: name -> (default, description, limits). The
#: defaults are :class:`RenderConfig`'s; 0 switches an addition off. The paper's renderer: blend
#: paper, depth_split 0, coverage_px 0, depth_tolerance 0, resolution_weight_deg 0, depth_lookup_steps 0,
#: min_depth_samples 10.
RENDER_PARAMETERS: dict[str, tuple[object, str, tuple[float, float] | None]] = {
    'renderer': ('ibr', "'ibr' (superpixel warp), 'splat' or 'ulr' (baselines)", None),
    'blend': ('ulr', "'ulr' (ULR weights), 'paper' (smallest angle penalty wins) or 'soft' (Gaussian)", None),
    'n_views': (4, 'source views per query', (1, 4)),
    'n_segments': (1500, 'SLIC superpixels per source view', (16, 100000)),
    'depth_split': (0.02, 'split superpixels at depth steps above this (log depth), 0 = off', (0.0, 10.0)),
    'coverage_px': (1.0, 'per-pixel reprojection check of warped superpixels (px), 0 = off', (0.0, 1e3)),
    'depth_tolerance': (0.5, "views vote on each pixel's depth with this tolerance, 0 = off", (0.0, 1e3)),
    'resolution_weight_deg': (40.0, 'penalty (deg) per unit of the ULR resolution term', (0.0, 1e3)),
    'depth_lookup_steps': (2, 'per-pixel depth corrections of the colour lookup, 0 = off', (0, 10)),
    'depth_lookup_max_px': (1.0, 'largest depth correction of the colour lookup (px)', (0.01, 1e3)),
    'depth_lookup_min_fit_px': (
        0.08,
        'correct only superpixels whose affine warp misses by more (RMS px)',
        (0.0, 1e3),
    ),
    'min_depth_samples': (2, 'known-depth pixels a superpixel needs to be warped (paper: 10)', (1, 100000)),
    'max_axis_angle_deg': (90.0, 'ignore views facing farther away (deg)', (1.0, 180.0)),
    'far_factor': (3.0, 'distance limit = this x median scene depth', (0.01, 1e6)),
    'max_cached_views': (64, 'per-view caches kept (LRU)', (1, 100000)),
}

#: RENDER_PARAMETERS whose RenderConfig field is None (off) at 0.
_OFF_AT_ZERO = ('depth_split', 'coverage_px', 'depth_tolerance')


def render_config(values: dict[str, object]) -> RenderConfig:
    """The view_renderer's :data:`RENDER_PARAMETERS` (missing ones take their defaults) as a
    :class:`RenderConfig`; a bad value is a :class:`UserError` naming the parameter."""
    try:  # each value as the type of its default (str, int or float)
        fields = {name: type(spec[0])(values.get(name, spec[0])) for name, spec in RENDER_PARAMETERS.items()}
    except (TypeError, ValueError) as exc:
        raise UserError(f'bad view_renderer parameter value: {exc}') from exc
    for name in _OFF_AT_ZERO:
        fields[name] = fields[name] or None
    try:
        return RenderConfig(**fields)  # type: ignore[arg-type]
    except ValueError as exc:
        raise UserError(f'bad view_renderer parameter: {exc}') from exc
