# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Parameter tables: one per node, the single source of its ROS parameters (no rclpy).

A :class:`ParamTable` lists a node's parameters (:class:`Param`: name, type from the default, range
or choices, description, read-only or dynamic) and the function that builds the node's core
configuration from their values. The rclpy node declares its parameters by looping over the table
(:func:`ibr_ros.nodes.common.declare_table`), ``ibr process`` builds the same configurations from
``config/*.yaml`` with :meth:`ParamTable.config`, and the shipped params files and the README's node
reference are generated from the tables (:meth:`ParamTable.params_file`, :meth:`ParamTable.reference`;
``python -m ibr_ros.node_config`` checks them, ``--write`` rewrites them).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from ibr_ros.core.diagnostics import LATENCY_SAMPLES, RATE_WINDOW_S
from ibr_ros.errors import UserError

__all__ = [
    'DIAGNOSTICS_PERIOD',
    'DIAGNOSTICS_TOPIC',
    'Diagnostics',
    'Param',
    'ParamTable',
    'Topic',
    'Value',
    'Values',
]

#: A parameter value: the ROS parameter types the nodes use.
Value = bool | int | float | str | list[float] | list[str]
C = TypeVar('C')

_KINDS: dict[type, str] = {bool: 'bool', int: 'int', float: 'double', str: 'string', list: 'list'}


class Values(dict[str, Value]):
    """A node's checked parameter values, with typed reads for the table's ``build`` function.

    A read of the wrong type is a programming error (the table checked every value): TypeError.
    """

    def number(self, name: str) -> float:
        """A double (or integer) parameter as a float."""
        v = self[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise TypeError(f'parameter {name} is not a number: {v!r}')
        return float(v)

    def integer(self, name: str) -> int:
        """An integer parameter."""
        v = self[name]
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f'parameter {name} is not an integer: {v!r}')
        return v

    def text(self, name: str) -> str:
        """A string parameter."""
        v = self[name]
        if not isinstance(v, str):
            raise TypeError(f'parameter {name} is not a string: {v!r}')
        return v

    def flag(self, name: str) -> bool:
        """A bool parameter."""
        v = self[name]
        if not isinstance(v, bool):
            raise TypeError(f'parameter {name} is not a bool: {v!r}')
        return v

    def numbers(self, name: str) -> list[float]:
        """A double-array parameter."""
        v = self[name]
        if not isinstance(v, list):
            raise TypeError(f'parameter {name} is not a list: {v!r}')
        return [float(x) for x in v]

    def texts(self, name: str) -> list[str]:
        """A string-array parameter."""
        v = self[name]
        if not isinstance(v, list):
            raise TypeError(f'parameter {name} is not a list: {v!r}')
        return [str(x) for x in v]


@dataclass(frozen=True)
class Param:
    """One ROS parameter: its type is its default's (a ``list`` default is a double or string array).

    ``range`` ``(lo, hi)`` bounds a number (inclusive; rclpy checks it too), ``choices`` a string;
    ``dynamic`` parameters may be set at run time, the others are read-only. ``comment`` adds lines
    to the params file only (examples, how it interacts with other parameters).
    """

    name: str
    default: Value
    description: str
    range: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    dynamic: bool = False
    comment: str = ''

    def __post_init__(self) -> None:
        if isinstance(self.default, bool) and self.range is not None:
            raise ValueError(f'parameter {self.name}: a bool has no range')
        if self.choices and not isinstance(self.default, str):
            raise ValueError(f'parameter {self.name}: choices need a string default')
        if self.choices and self.default not in self.choices:
            raise ValueError(f'parameter {self.name}: default {self.default!r} is not one of its choices')

    @property
    def kind(self) -> str:
        """'bool', 'int', 'double', 'string' or 'list'."""
        return _KINDS[type(self.default)]

    def check(self, value: object, where: str = '') -> Value:
        """``value`` as this parameter's type (an integer is accepted for a double), checked against
        the range or choices; a :class:`UserError` naming ``where`` + the parameter and the value."""
        name = f'{where}{self.name}'
        kinds = {'bool': 'true or false', 'double': 'a number', 'int': 'an integer', 'list': 'a list'}
        bad = UserError(
            f'parameter {name} must be {kinds.get(self.kind, "a string")} (default {self.default!r}), '
            f'got {value!r}'
        )
        out: Value
        if self.kind == 'bool':
            if not isinstance(value, bool):
                raise bad
            out = value
        elif self.kind in ('int', 'double'):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad
            if self.kind == 'int' and not isinstance(value, int):
                raise bad
            out = float(value) if self.kind == 'double' else int(value)
            if self.range is not None and not self.range[0] <= out <= self.range[1]:
                lo, hi = (_num(v) for v in self.range)
                raise UserError(f'parameter {name} must be {lo}..{hi}, got {value!r}')
            if self.kind == 'double' and math.isnan(out):
                raise UserError(f'parameter {name} must be a number, got nan')
        elif self.kind == 'list':
            if not isinstance(value, (list, tuple)):
                raise bad
            out = list(value)
        else:
            if not isinstance(value, str):
                raise bad
            if self.choices and value not in self.choices:
                raise UserError(f'parameter {name} must be {_alternatives(self.choices)}, got {value!r}')
            out = value
        return out

    def constraints(self) -> str:
        """The range or choices as a human-readable text ('' when free)."""
        if self.range is not None:
            return f'{_num(self.range[0])} .. {_num(self.range[1])}'
        if self.choices:
            return ', '.join(self.choices)
        return ''


@dataclass(frozen=True)
class Topic:
    """A topic of a node, for its reference: relative name, message type, QoS and meaning."""

    name: str
    type: str
    description: str
    qos: str = ''


@dataclass(frozen=True)
class Diagnostics:
    """What a node reports on ``/diagnostics`` (:class:`~ibr_ros.core.diagnostics.NodeDiagnostics`):
    its input and output streams (``<stream>.count``, ``<stream>.rate_hz``; a name in ``<>`` stands
    for several, e.g. ``<topic>``), what its ``latency`` measures, its rejection ``reasons``, its
    ``queues`` and its ``model`` keys, each with its meaning."""

    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    latency: str
    reasons: tuple[tuple[str, str], ...]
    queues: tuple[tuple[str, str], ...] = ()
    model: tuple[tuple[str, str], ...] = ()

    def keys(self) -> dict[str, list[str]]:
        """The documented keys of each area (:data:`~ibr_ros.core.diagnostics.AREAS`)."""
        streams = lambda names: [f'{n}.{k}' for n in names for k in ('count', 'rate_hz')]  # noqa: E731
        latency = ['latency.count', 'latency_ms.median', 'latency_ms.p95', 'latency_ms.max']
        return {
            'inputs': streams(self.inputs),
            'outputs': streams(self.outputs) + latency,
            'rejected': ['total', *(r for r, _ in self.reasons)],
            'queues': [k for q, _ in self.queues for k in (q, f'{q}.bound')],
            'model': [k for k, _ in self.model],
        }

    def reference(self) -> str:
        """The Markdown block of the node reference."""
        code = lambda names: ', '.join(f'`{n}`' for n in names) or 'none'  # noqa: E731
        described = lambda pairs: '; '.join(f'`{k}` {d}' for k, d in pairs) or 'none'  # noqa: E731
        lines = [
            f'**Diagnostics** (`{DIAGNOSTICS_TOPIC.name}`, every `diagnostics_period_s`: one '
            f'DiagnosticStatus per area, named `<node>: <area>`; rates over the last {RATE_WINDOW_S:g} s)',
            '',
            '| area | keys | level |',
            '|---|---|---|',
            f'| inputs | `<stream>.count`, `<stream>.rate_hz` of {code(self.inputs)} | OK |',
            f'| outputs | the same of {code(self.outputs)}; `latency.count`, `latency_ms.median`, '
            f'`latency_ms.p95`, `latency_ms.max` of the last {LATENCY_SAMPLES}: {self.latency} | OK |',
            f'| rejected | `total` and each reason: {described(self.reasons)} | WARN when the total grew '
            'since the last report, ERROR while `incompatible_qos` is counted |',
            f'| queues | `<queue>` (depth) and `<queue>.bound` (0: none) of {described(self.queues)} | WARN '
            'when one is full |',
            f'| model | {described(self.model)} | OK |',
        ]
        return '\n'.join(lines) + '\n'


#: The node's ``/diagnostics`` period, a parameter of every node.
DIAGNOSTICS_PERIOD = Param(
    'diagnostics_period_s', 1.0, 'period of the /diagnostics report (s)', (0.1, 3600.0)
)

#: ``/diagnostics`` (absolute, as diagnostic_updater's), in every node's published topics.
DIAGNOSTICS_TOPIC = Topic(
    '/diagnostics',
    'diagnostic_msgs/DiagnosticArray',
    "this node's rates, latency, rejections, queues and model size (see Diagnostics below)",
    'reliable, depth 10',
)


@dataclass(frozen=True)
class ParamTable(Generic[C]):
    """A node's parameters and the function that builds its core configuration from their values.

    ``build`` gets every parameter (checked, defaults filled in) and returns the configuration; it
    raises :class:`UserError` naming the parameter for combinations the table cannot express.
    """

    node: str
    summary: str
    params: tuple[Param, ...]
    build: Callable[[Values], C]
    subscribes: tuple[Topic, ...] = ()
    publishes: tuple[Topic, ...] = ()
    diagnostics: Diagnostics | None = None

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        if len(set(names)) != len(names):
            raise ValueError(f'{self.node}: parameter names repeat: {names}')

    def __getitem__(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def defaults(self) -> Values:
        """Every parameter's default (lists copied)."""
        out = Values()
        for p in self.params:
            out[p.name] = p.default.copy() if isinstance(p.default, list) else p.default
        return out

    def values(self, given: Mapping[str, object] | None = None, *, where: str = '') -> Values:
        """The defaults updated by ``given``, each checked; an unknown name is a :class:`UserError`."""
        out = self.defaults()
        for name, value in (given or {}).items():
            try:
                param = self[name]
            except KeyError:
                raise UserError(f'{name!r} is not a parameter of {self.node}') from None
            out[name] = param.check(value, where)
        return out

    def config(self, given: Mapping[str, object] | None = None, *, where: str = '') -> C:
        """The core configuration from ``given`` values (missing ones take their defaults)."""
        return self.build(self.values(given, where=where))

    # -- generated documents ----------------------------------------------------------------------
    def params_file(self) -> str:
        """``config/<node>.yaml``: the defaults in ROS 2 params-file format, described in comments."""
        lines = [
            f'# Defaults of the {self.node} node (ROS 2 params-file format).',
            '# Generated from ibr_ros.node_config: edit the table there, then run',
            '# `python -m ibr_ros.node_config --write` (a test checks this file is current).',
            '/**:',
            '  ros__parameters:',
        ]
        for p in self.params:
            lines.append(f'    # {p.description}' + (f' [{p.constraints()}]' if p.constraints() else ''))
            lines += [f'    #   {c}' for c in textwrap.wrap(p.comment, 96)] if p.comment else []
            lines.append(f'    {p.name}: {_yaml(p.default)}')
        return '\n'.join(lines) + '\n'

    def reference(self) -> str:
        """The node's Markdown reference block (as image_pipeline's ``doc/components.rst``)."""
        out = [f'### {self.node}', '', self.summary, '']
        for title, topics in (
            ('Subscribed topics', self.subscribes),
            ('Published topics', self.publishes),
        ):
            if not topics:
                continue
            out += [f'**{title}**', '']
            for t in topics:
                qos = f' ({t.qos})' if t.qos else ''
                out.append(f'- `{t.name}` (`{t.type}`){qos}: {t.description}')
            out.append('')
        out += [
            '**Parameters**',
            '',
            '| name | type | default | range | description |',
            '|---|---|---|---|---|',
        ]
        for p in self.params:
            dyn = ' (dynamic)' if p.dynamic else ''
            desc = p.description.replace('|', '\\|')
            out.append(f'| `{p.name}` | {p.kind}{dyn} | `{_yaml(p.default)}` | {p.constraints()} | {desc} |')
        if self.diagnostics is not None:
            out += ['', self.diagnostics.reference().rstrip('\n')]
        return '\n'.join(out) + '\n'


def _num(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))


def _alternatives(choices: Sequence[str]) -> str:
    quoted = [repr(c) for c in choices]
    return quoted[0] if len(quoted) == 1 else ', '.join(quoted[:-1]) + ' or ' + quoted[-1]


def _yaml(v: object) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, str):
        return (
            "''"
            if v == ''
            else (repr(v) if v in ('off', 'on', 'yes', 'no', 'none', 'true', 'false') or ':' in v else v)
        )
    if isinstance(v, list):
        return '[' + ', '.join(_yaml(x) for x in v) + ']'
    return repr(v)
