# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Node parameter tables: one per node, shared by the rclpy nodes, ``ibr process``, ``config/*.yaml``
and the README's node reference (no rclpy).

Each node's table lives in the module of its name and is imported on first use (a node loads only
its own: the depth_refiner's pulls in MVS and SfM); :func:`table_of` and :data:`TABLES` give them
by node name. Errors are :class:`~ibr_ros.errors.UserError` naming the parameter and its value,
e.g. ``parameter sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ibr_ros.node_config.table import Param, ParamTable, Topic, Value, Values

if TYPE_CHECKING:
    from ibr_ros.node_config.bag_player import BAG_PLAYER, BagPlayerConfig
    from ibr_ros.node_config.depth_refiner import DEPTH_REFINER, DepthRefinerConfig
    from ibr_ros.node_config.frame_subsampler import FRAME_SUBSAMPLER, FrameSubsamplerConfig
    from ibr_ros.node_config.scene_viz import SCENE_VIZ, SceneVizConfig
    from ibr_ros.node_config.view_renderer import INTRINSICS, VIEW_RENDERER, ViewRendererConfig, render_config
    from ibr_ros.node_config.web_viewer import WEB_VIEWER, WebViewerConfig

    #: Every node's table, by node name, in the order data flows through the graph.
    TABLES: dict[str, ParamTable[Any]]

__all__ = [
    'BAG_PLAYER',
    'DEPTH_REFINER',
    'FRAME_SUBSAMPLER',
    'INTRINSICS',
    'NODES',
    'SCENE_VIZ',
    'TABLES',
    'VIEW_RENDERER',
    'WEB_VIEWER',
    'BagPlayerConfig',
    'DepthRefinerConfig',
    'FrameSubsamplerConfig',
    'Param',
    'ParamTable',
    'SceneVizConfig',
    'Topic',
    'Value',
    'Values',
    'ViewRendererConfig',
    'WebViewerConfig',
    'render_config',
    'table_of',
]

#: The nodes with a parameter table, in the order data flows through the graph.
NODES = ('bag_player', 'frame_subsampler', 'depth_refiner', 'view_renderer', 'scene_viz', 'web_viewer')

#: Where each lazily imported name lives (a module of this package).
_LAZY = {
    'BAG_PLAYER': 'bag_player',
    'BagPlayerConfig': 'bag_player',
    'FRAME_SUBSAMPLER': 'frame_subsampler',
    'FrameSubsamplerConfig': 'frame_subsampler',
    'DEPTH_REFINER': 'depth_refiner',
    'DepthRefinerConfig': 'depth_refiner',
    'VIEW_RENDERER': 'view_renderer',
    'ViewRendererConfig': 'view_renderer',
    'INTRINSICS': 'view_renderer',
    'SCENE_VIZ': 'scene_viz',
    'SceneVizConfig': 'scene_viz',
    'render_config': 'view_renderer',
    'WEB_VIEWER': 'web_viewer',
    'WebViewerConfig': 'web_viewer',
}


def table_of(node: str) -> ParamTable[Any]:
    """The parameter table of ``node`` (one of :data:`NODES`); imports only that node's module."""
    if node not in NODES:
        raise KeyError(f'no parameter table for node {node!r} (nodes: {", ".join(NODES)})')
    table: ParamTable[Any] = getattr(importlib.import_module(f'{__name__}.{node}'), node.upper())
    return table


def __getattr__(name: str) -> Any:
    """PEP 562: the tables (and :data:`TABLES`) are imported when first used."""
    if name == 'TABLES':
        return {node: table_of(node) for node in NODES}
    if name in _LAZY:
        return getattr(importlib.import_module(f'{__name__}.{_LAZY[name]}'), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
