# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Progress bars for long jobs (tqdm on stderr; silent when stderr is not a terminal unless forced)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
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
