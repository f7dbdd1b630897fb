"""The depth_refiner's parameters -> core configurations (no rclpy).

Errors are :class:`~ibr_ros.errors.UserError` naming the parameter and its value, e.g. ``parameter
sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'``; ``ibr process`` prefixes the node name.
"""

from __future__ import annotations

from ibr_ros.core.depth.mvs import MvsOptions
from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.registration.sfm_session import ScaleHint
from ibr_ros.errors import UserError
from ibr_ros.models import mono_spec, sky_spec

__all__ = ['SFM_MODES', 'SFM_SCALES', 'refiner_config', 'sfm_settings']

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
