"""Node parameter tables: one per node, shared by the rclpy nodes, ``ibr process``, ``config/*.yaml``
and the README's node reference (no rclpy).

Errors are :class:`~ibr_ros.errors.UserError` naming the parameter and its value, e.g. ``parameter
sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'``.
"""

from __future__ import annotations

from typing import Any

from ibr_ros.node_config.bag_player import BAG_PLAYER, BagPlayerConfig
from ibr_ros.node_config.depth_refiner import DEPTH_REFINER, DepthRefinerConfig
from ibr_ros.node_config.frame_subsampler import FRAME_SUBSAMPLER, FrameSubsamplerConfig
from ibr_ros.node_config.table import Param, ParamTable, Topic, Value, Values
from ibr_ros.node_config.view_renderer import INTRINSICS, VIEW_RENDERER, ViewRendererConfig, render_config

__all__ = [
    'BAG_PLAYER',
    'DEPTH_REFINER',
    'FRAME_SUBSAMPLER',
    'INTRINSICS',
    'TABLES',
    'VIEW_RENDERER',
    'BagPlayerConfig',
    'DepthRefinerConfig',
    'FrameSubsamplerConfig',
    'Param',
    'ParamTable',
    'Topic',
    'Value',
    'Values',
    'ViewRendererConfig',
    'render_config',
]

#: Every node's table, by node name, in the order data flows through the graph.
TABLES: dict[str, ParamTable[Any]] = {
    t.node: t for t in (BAG_PLAYER, FRAME_SUBSAMPLER, DEPTH_REFINER, VIEW_RENDERER)
}
