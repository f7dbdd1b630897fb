"""Models shipped with ibr_ros (see ``README.md`` beside this file) and a registry of downloadable ones."""

from __future__ import annotations

from pathlib import Path

__all__ = ['SHIPPED_MONO_MODEL']

#: The project's monocular depth + sky model: presets ``PRESETS['ibr_mono']`` (output 0, inverse
#: depth) and ``SKY_PRESETS['ibr_mono']`` (output 1, sky logit).
SHIPPED_MONO_MODEL = Path(__file__).with_name('ibr_mono.onnx')
