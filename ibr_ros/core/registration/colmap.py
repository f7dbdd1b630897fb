# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``pycolmap``, imported without its signal handlers.

pycolmap's import installs glog's failure signal handler for SIGTERM (and others), so a process
that imported it dies on SIGTERM with a stack dump instead of shutting down. :func:`pycolmap`
imports it once and puts back the SIGINT and SIGTERM handlers that were there before (from the main
thread, where Python allows it; the nodes and ``ibr`` import it at start-up).
"""

from __future__ import annotations

import signal
import threading
from types import ModuleType

__all__ = ['pycolmap']

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def pycolmap() -> ModuleType:
    """The ``pycolmap`` module, its import leaving the SIGINT and SIGTERM handlers as they were."""
    main = threading.current_thread() is threading.main_thread()
    saved = {s: signal.getsignal(s) for s in _SIGNALS} if main else {}
    import pycolmap as module

    for sig, handler in saved.items():
        if handler is not None:
            signal.signal(sig, handler)
    return module
