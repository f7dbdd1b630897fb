# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Novel views: SLIC superpixels, the shape-preserving warp, the raster and blend kernels and the
renderer (the 4 nearest views, a depth test, blending); settings in :class:`RenderConfig`.
"""

from __future__ import annotations

from ibr_ros.core.render.blend import (
    BLEND_MODES,
    bilinear,
    blend_views,
    put_rgb,
)
from ibr_ros.core.render.config import (
    PAPER_FIELDS,
    RenderConfig,
)
from ibr_ros.core.render.holes import fill_small_holes
from ibr_ros.core.render.projection import (
    intrinsics_vector,
    lands_near,
    refine_preimage,
    relative_pose,
    reprojection_params,
)
from ibr_ros.core.render.raster import (
    affine_maps,
    raster_views,
    row_spans,
)
from ibr_ros.core.render.renderer import (
    NovelViewRenderer,
    Rendered,
    SourceView,
    output_camera,
    selection_gains,
)
from ibr_ros.core.render.reply import (
    REFUSALS,
    ReplyPolicy,
    ReplyStatus,
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
    'BLEND_MODES',
    'PAPER_FIELDS',
    'REFUSALS',
    'NovelViewRenderer',
    'RenderConfig',
    'Rendered',
    'ReplyPolicy',
    'ReplyStatus',
    'SourceView',
    'SuperpixelStats',
    'WarpModel',
    'WarpResult',
    'affine_maps',
    'barycentric',
    'bilinear',
    'blend_views',
    'circumscribed_triangles',
    'fill_small_holes',
    'intrinsics_vector',
    'lands_near',
    'output_camera',
    'prepare_warp',
    'put_rgb',
    'raster_views',
    'refine_preimage',
    'relative_pose',
    'reprojection_params',
    'row_spans',
    'selection_gains',
    'shape_coefficients',
    'shape_energy',
    'slic',
    'solve_warp',
    'split_at_depth_edges',
    'superpixel_stats',
    'warp_superpixels',
]
