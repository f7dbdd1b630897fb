"""Novel views: SLIC superpixels, the shape-preserving warp, and the renderer (4 nearest views,
depth test, blending).
"""

from __future__ import annotations

from ibr_ros.core.render.renderer import (
    PAPER_FIELDS,
    NovelViewRenderer,
    RenderConfig,
    Rendered,
    SourceView,
)
from ibr_ros.core.render.superpixels import (
    SuperpixelStats,
    slic,
    split_at_depth_edges,
    superpixel_stats,
)
from ibr_ros.core.render.warp import (
    WarpModel,
    WarpResult,
    barycentric,
    circumscribed_triangles,
    prepare_warp,
    shape_coefficients,
    shape_energy,
    solve_warp,
    warp_superpixels,
)

__all__ = [
    'PAPER_FIELDS',
    'NovelViewRenderer',
    'RenderConfig',
    'Rendered',
    'SourceView',
    'SuperpixelStats',
    'WarpModel',
    'WarpResult',
    'barycentric',
    'circumscribed_triangles',
    'prepare_warp',
    'shape_coefficients',
    'shape_energy',
    'slic',
    'solve_warp',
    'split_at_depth_edges',
    'superpixel_stats',
    'warp_superpixels',
]
