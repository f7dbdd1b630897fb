# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Run one executable of ``entry_points.CONSOLE_SCRIPTS`` by name: the ``lib/ibr_ros`` launchers run
``python -m ibr_ros.launch_entry NAME ARGS...``, the console scripts call :func:`main` directly (the
name is then the script's own).

SIGINT and SIGTERM end the program with exit status 0 and one line, even while its modules are
still being imported (numba compiles at import): until the program installs its own handlers
(``rclpy.init``), SIGTERM is taken as Ctrl-C.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys

from ibr_ros.entry_points import CONSOLE_SCRIPTS


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def sigterm_as_interrupt() -> None:
    """From now on SIGTERM raises KeyboardInterrupt in the main thread, as Ctrl-C does."""
    signal.signal(signal.SIGTERM, _interrupt)


def interrupted(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a Ctrl-C, also when numba wrapped it (a SystemError with it as context)."""
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def run(name: str, args: list[str]) -> int:
    """Import and run executable ``name`` with ``sys.argv = [name, *args]``; its exit status."""
    sigterm_as_interrupt()
    module, _, func = CONSOLE_SCRIPTS[name].partition(':')
    sys.argv = [name, *args]
    try:
        result = getattr(importlib.import_module(module), func)()
    except (KeyboardInterrupt, SystemError) as exc:
        if not interrupted(exc):
            raise
        print(f'{name}: interrupted, stopped', file=sys.stderr)
        return 0
    return int(result or 0)


def main(argv: list[str] | None = None) -> int:
    own = os.path.basename(sys.argv[0])
    if argv is None and own in CONSOLE_SCRIPTS:  # a console script
        return run(own, sys.argv[1:])
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] not in CONSOLE_SCRIPTS:
        names = ', '.join(sorted(CONSOLE_SCRIPTS))
        print(
            f'usage: python -m ibr_ros.launch_entry NAME [ARGS...]; NAME is one of: {names}', file=sys.stderr
        )
        return 2
    return run(args[0], args[1:])


if __name__ == '__main__':
    sys.exit(main())
