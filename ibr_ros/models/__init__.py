# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Models shipped with ibr_ros (see ``README.md`` beside this file) and a registry of downloadable ones.

:func:`mono_spec` and :func:`sky_spec` turn a model given by name or path plus an I/O preset name
(the ``mono_model``/``mono_preset`` and ``sky_model``/``sky_preset`` parameters of the
``depth_refiner`` node) into the specs of :mod:`ibr_ros.core.depth.mono` and :mod:`ibr_ros.core.depth.sky`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from ibr_ros.errors import UserError

if TYPE_CHECKING:
    from ibr_ros.core.depth.mono import MonoModelSpec
    from ibr_ros.core.depth.sky import SkySpec

__all__ = ['SHIPPED_MODELS', 'SHIPPED_MONO_MODEL', 'mono_spec', 'sky_spec']

#: The project's monocular depth + sky model: presets ``PRESETS['ibr_mono']`` (output 0, inverse
#: depth) and ``SKY_PRESETS['ibr_mono']`` (output 1, sky logit).
SHIPPED_MONO_MODEL = Path(__file__).with_name('ibr_mono.onnx')

#: Shipped models by name: (file, its mono preset, its sky preset or None).
SHIPPED_MODELS: dict[str, tuple[Path, str, str | None]] = {
    'ibr_mono': (SHIPPED_MONO_MODEL, 'ibr_mono', 'ibr_mono')
}


def _resolve(model: str, param: str, sky: bool) -> tuple[Path, str | None]:
    """The file of ``model`` (shipped name, registry name or path) and its default preset (or None)."""
    from ibr_ros.models.registry import MODELS, default_cache_dir

    name = str(model).strip()
    if name in SHIPPED_MODELS:
        path, mono_preset, sky_preset = SHIPPED_MODELS[name]
        return path, sky_preset if sky else mono_preset
    if name in MODELS:
        entry = MODELS[name]
        if sky:
            raise UserError(f'parameter {param} {name!r}: the downloadable model {name} has no sky output')
        path = default_cache_dir() / entry.filename
        if not path.is_file():
            raise UserError(
                f'parameter {param} {name!r}: not downloaded yet (expected {path}); '
                f'run `ibr models fetch {name}`'
            )
        return path, entry.preset
    path = Path(name).expanduser()
    if not name or (path.suffix != '.onnx' and len(path.parts) == 1):
        known = ', '.join(sorted({*SHIPPED_MODELS, *([] if sky else MODELS)}))
        raise UserError(
            f'parameter {param} {name!r}: neither a known model ({known}) nor a path to an .onnx file'
        )
    if not path.is_file():
        raise UserError(f'parameter {param} {name!r}: no such file ({path.resolve()})')
    return path, None


def _preset(
    preset: str, default: str | None, presets: dict, model: str, param: str, preset_param: str
) -> str:
    name = str(preset).strip() or default
    if name is None:
        raise UserError(
            f'parameter {preset_param} must name the I/O convention of {param} {model!r}: '
            f'one of {", ".join(sorted(presets))}'
        )
    if name not in presets:
        raise UserError(
            f'parameter {preset_param} {name!r}: unknown preset; one of {", ".join(sorted(presets))}'
        )
    return name


def mono_spec(
    model: str, preset: str = '', *, param: str = 'mono_model', preset_param: str = 'mono_preset'
) -> MonoModelSpec:
    """The :class:`~ibr_ros.core.depth.mono.MonoModelSpec` of a monocular depth model.

    ``model``: a shipped model name (``'ibr_mono'``), a model of ``ibr models list`` already fetched
    into the cache, or a path to an ``.onnx`` file. ``preset``: a name of
    :data:`~ibr_ros.core.depth.mono.PRESETS` ('' = the named model's own; required for a path). Raises
    UserError naming ``param`` / ``preset_param`` and the value.
    """
    from ibr_ros.core.depth.mono import PRESETS

    path, default = _resolve(model, param, sky=False)
    return replace(PRESETS[_preset(preset, default, PRESETS, model, param, preset_param)], path=path)


def sky_spec(
    model: str, preset: str = '', *, param: str = 'sky_model', preset_param: str = 'sky_preset'
) -> SkySpec:
    """The :class:`~ibr_ros.core.depth.sky.SkySpec` of a sky segmentation model (see :func:`mono_spec`).

    ``preset``: a name of :data:`~ibr_ros.core.depth.sky.SKY_PRESETS` ('' = the named model's own).
    """
    from ibr_ros.core.depth.sky import SKY_PRESETS

    path, default = _resolve(model, param, sky=True)
    return replace(SKY_PRESETS[_preset(preset, default, SKY_PRESETS, model, param, preset_param)], path=path)
