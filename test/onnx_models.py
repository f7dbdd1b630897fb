# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Tiny ONNX stand-ins with the input/output signatures of well-known models (built with onnx.helper)."""

from __future__ import annotations

from pathlib import Path

import onnx
from onnx import TensorProto, helper


def _save(graph: onnx.GraphProto, path: Path) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def channel_model(
    path: Path,
    *,
    channel: int,
    layout: str = 'NCHW',
    size: tuple[int, int] | None = None,
    out_rank: int = 4,
    add: float = 0.0,
) -> Path:
    """Output = input channel ``channel`` (+ ``add``), shaped 1x1xHxW (rank 4) or 1xHxW (rank 3).

    ``size`` ``(width, height)`` fixes the input's spatial dims; None makes them dynamic.
    """
    h, w = (size[1], size[0]) if size else ('H', 'W')
    in_shape = [1, 3, h, w] if layout == 'NCHW' else [1, h, w, 3]
    axis = 1 if layout == 'NCHW' else 3
    nodes = [
        helper.make_node(
            'Constant', [], ['starts'], value=helper.make_tensor('s', TensorProto.INT64, [1], [channel])
        ),
        helper.make_node(
            'Constant', [], ['ends'], value=helper.make_tensor('e', TensorProto.INT64, [1], [channel + 1])
        ),
        helper.make_node(
            'Constant', [], ['axes'], value=helper.make_tensor('a', TensorProto.INT64, [1], [axis])
        ),
        helper.make_node('Slice', ['image', 'starts', 'ends', 'axes'], ['sliced']),
        helper.make_node(
            'Constant', [], ['bias'], value=helper.make_tensor('b', TensorProto.FLOAT, [], [add])
        ),
        helper.make_node('Add', ['sliced', 'bias'], ['shifted']),
    ]
    if layout == 'NHWC':
        nodes.append(helper.make_node('Transpose', ['shifted'], ['chw'], perm=[0, 3, 1, 2]))
        last = 'chw'
    else:
        last = 'shifted'
    if out_rank == 3:
        nodes.append(
            helper.make_node(
                'Constant', [], ['sq'], value=helper.make_tensor('q', TensorProto.INT64, [1], [1])
            )
        )
        nodes.append(helper.make_node('Squeeze', [last, 'sq'], ['depth']))
        out_shape = [1, h, w]
    else:
        nodes.append(helper.make_node('Identity', [last], ['depth']))
        out_shape = [1, 1, h, w]
    graph = helper.make_graph(
        nodes,
        'stand_in',
        [helper.make_tensor_value_info('image', TensorProto.FLOAT, in_shape)],
        [helper.make_tensor_value_info('depth', TensorProto.FLOAT, out_shape)],
    )
    return _save(graph, path)


def sky_logits_model(path: Path, *, size: tuple[int, int]) -> Path:
    """2-class logits 1x2xHxW: class 0 ('sky') = blue - red, class 1 = red - blue (NCHW input)."""
    w, h = size
    nodes = [
        helper.make_node('Split', ['image'], ['r', 'g', 'b'], axis=1),
        helper.make_node('Sub', ['b', 'r'], ['sky']),
        helper.make_node('Sub', ['r', 'b'], ['other']),
        helper.make_node('Concat', ['sky', 'other'], ['logits'], axis=1),
    ]
    graph = helper.make_graph(
        nodes,
        'sky_stand_in',
        [helper.make_tensor_value_info('image', TensorProto.FLOAT, [1, 3, h, w])],
        [helper.make_tensor_value_info('logits', TensorProto.FLOAT, [1, 2, h, w])],
    )
    return _save(graph, path)
