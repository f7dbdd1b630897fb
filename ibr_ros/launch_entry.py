"""Run one executable of ``entry_points.CONSOLE_SCRIPTS`` by name (used by the lib/ibr_ros launchers)."""

from __future__ import annotations

import importlib
import sys

from ibr_ros.entry_points import CONSOLE_SCRIPTS


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] not in CONSOLE_SCRIPTS:
        names = ', '.join(sorted(CONSOLE_SCRIPTS))
        print(
            f'usage: python -m ibr_ros.launch_entry NAME [ARGS...]; NAME is one of: {names}', file=sys.stderr
        )
        return 2
    module, _, func = CONSOLE_SCRIPTS[args[0]].partition(':')
    sys.argv = [args[0], *args[1:]]
    result = getattr(importlib.import_module(module), func)()
    return int(result or 0)


if __name__ == '__main__':
    sys.exit(main())
