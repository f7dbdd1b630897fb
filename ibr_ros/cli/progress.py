# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Progress bars for long jobs (tqdm on stderr; silent when stderr is not a terminal unless forced)."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager

from tqdm import tqdm


@contextmanager
def progress_bar(
    desc: str, *, unit: str = 'item', enabled: bool | None = None
) -> Iterator[Callable[[int, int | None], None]]:
    """Yield a ``progress(done, total)`` callback drawing one tqdm bar on stderr (total None: unknown)."""
    show = sys.stderr.isatty() if enabled is None else enabled
    bar: tqdm | None = None

    def update(done: int, total: int | None) -> None:
        nonlocal bar
        if not show:
            return
        if bar is None:
            bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True)
        bar.update(done - bar.n)

    try:
        yield update
    finally:
        if bar is not None:
            bar.close()


@contextmanager
def staged_progress(
    units: Mapping[str, str], *, enabled: bool | None = None
) -> Iterator[Callable[[str, int, int], None]]:
    """Yield a ``progress(stage, done, total)`` callback: one bar per stage, a new stage closes the
    previous bar (``units``: the unit of each stage's bar, ``item`` for others)."""
    with contextlib.ExitStack() as stack:
        bars: dict[str, Callable[[int, int | None], None]] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in bars:
                stack.close()  # one bar at a time: the previous stage is over
                bars.clear()
                bars[stage] = stack.enter_context(
                    progress_bar(stage, unit=units.get(stage, 'item'), enabled=enabled)
                )
            bars[stage](done, total)

        yield progress
