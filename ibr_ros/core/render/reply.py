# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Whether a novel view answers its query, and the status that says so (``novel_view/status``).

Every query gets exactly one :class:`ReplyStatus`: ``answered`` (at least ``min_valid_fraction`` of
the pixels rendered; the image follows), ``incomplete`` (fewer, published anyway because
``publish_incomplete`` is set; flagged) or ``refused`` (no image, with the reason). The status's level
says at a glance what a client got: ``ok`` a view it can use, ``warn`` a torn one, ``error`` none.
As string key-values for ``diagnostic_msgs/KeyValue`` (:meth:`ReplyStatus.to_pairs`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = ['REFUSALS', 'RESULTS', 'ReplyPolicy', 'ReplyStatus']

#: Reasons a query gets no image: no keyframe with depth yet, a pose in another frame than the model,
#: an invalid pose, nothing renderable there (too far, facing away from every view, nothing
#: visible), a renderer exception, a newer query taken first, too little of the view rendered.
REFUSALS = (
    'no_model',
    'frame',
    'invalid_query',
    'unrenderable',
    'render_error',
    'superseded',
    'incomplete',
)

#: ``result`` -> DiagnosticStatus level name.
RESULTS = {'answered': 'ok', 'incomplete': 'warn', 'refused': 'error'}


@dataclass(frozen=True)
class ReplyStatus:
    """The outcome of one query.

    ``result``: a key of :data:`RESULTS`; ``reason``: '' when answered, ``incomplete`` for an
    incomplete view, else one of :data:`REFUSALS`; ``valid_fraction``: the fraction of the pixels
    rendered (0 when nothing was); ``min_valid_fraction``: the threshold it was judged by;
    ``message``: one line for people; ``views``: names of the source views used (keyframe stamps in
    ns for the node); ``render_ms``: render time (0 when nothing was rendered).
    """

    result: str
    reason: str
    valid_fraction: float
    min_valid_fraction: float
    message: str = ''
    views: tuple[str, ...] = ()
    render_ms: float = 0.0

    def __post_init__(self) -> None:
        for name in ('valid_fraction', 'min_valid_fraction', 'render_ms'):
            object.__setattr__(self, name, float(getattr(self, name)))  # plain floats (numpy's repr differs)
        object.__setattr__(self, 'views', tuple(str(v) for v in self.views))
        if self.result not in RESULTS:
            raise ValueError(f'result must be one of {", ".join(RESULTS)}, got {self.result!r}')
        if (self.reason == '') != (self.result == 'answered') or (
            self.reason and self.reason not in REFUSALS
        ):
            raise ValueError(f'reason {self.reason!r} does not fit result {self.result!r}')
        if self.result == 'incomplete' and self.reason != 'incomplete':
            raise ValueError(f"an incomplete view has reason 'incomplete', got {self.reason!r}")
        for name in ('valid_fraction', 'min_valid_fraction'):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f'{name} must be in [0, 1], got {value!r}')

    @property
    def level(self) -> str:
        """DiagnosticStatus level name: ``ok`` answered, ``warn`` incomplete, ``error`` refused."""
        return RESULTS[self.result]

    @property
    def published(self) -> bool:
        """Whether an image (and camera_info) with the query's stamp is published."""
        return self.result != 'refused'

    def to_pairs(self) -> list[tuple[str, str]]:
        """String key-values; numbers in Python's shortest exact form (they parse back to the same float)."""
        return [
            ('result', self.result),
            ('reason', self.reason),
            ('valid_fraction', repr(self.valid_fraction)),
            ('min_valid_fraction', repr(self.min_valid_fraction)),
            ('published', str(self.published).lower()),
            ('views', ' '.join(self.views)),
            ('render_ms', repr(self.render_ms)),
        ]

    @classmethod
    def from_pairs(cls, pairs: Iterable[tuple[str, str]], message: str = '') -> ReplyStatus:
        """Parse :meth:`to_pairs` (unknown keys ignored); ValueError naming a missing or malformed field."""
        values = dict(pairs)
        try:
            result, reason = values['result'], values['reason']
        except KeyError as exc:
            raise ValueError(f'status field {exc.args[0]} missing') from None
        numbers = {}
        for key in ('valid_fraction', 'min_valid_fraction', 'render_ms'):
            try:
                numbers[key] = float(values.get(key, '0'))
            except ValueError:
                raise ValueError(f'status field {key}: {values[key]!r} is not a number') from None
        return cls(result, reason, message=message, views=tuple(values.get('views', '').split()), **numbers)


@dataclass(frozen=True)
class ReplyPolicy:
    """Judges rendered views: ``min_valid_fraction`` of the pixels must be rendered for an answer;
    with ``publish_incomplete`` a view below it is still published, flagged ``incomplete``."""

    min_valid_fraction: float
    publish_incomplete: bool = False

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise ValueError(f'min_valid_fraction must be in [0, 1], got {self.min_valid_fraction}')

    def judge(self, valid_fraction: float, views: Sequence[str] = (), render_ms: float = 0.0) -> ReplyStatus:
        """The status of a view of which ``valid_fraction`` was rendered (from ``views``)."""
        frac = float(valid_fraction)
        share = f'{frac:.0%} rendered'
        if frac >= self.min_valid_fraction:
            return ReplyStatus('answered', '', frac, self.min_valid_fraction, share, tuple(views), render_ms)
        below = f'{share} (< min_valid_fraction {self.min_valid_fraction:g})'
        if self.publish_incomplete:
            return ReplyStatus(
                'incomplete', 'incomplete', frac, self.min_valid_fraction,
                f'{below}: published flagged incomplete', tuple(views), render_ms,
            )  # fmt: skip
        return ReplyStatus(
            'refused', 'incomplete', frac, self.min_valid_fraction, f'{below}: not published', tuple(views),
            render_ms,
        )  # fmt: skip

    def refuse(self, reason: str, message: str) -> ReplyStatus:
        """The status of a query refused before anything was rendered (``reason``: in :data:`REFUSALS`)."""
        return ReplyStatus('refused', reason, 0.0, self.min_valid_fraction, message)
