"""The one exception type of :mod:`msg_utils`."""

from __future__ import annotations

__all__ = ['MessageError']


class MessageError(ValueError):
    """A message (or a value meant for one) that cannot be converted.

    The text names the offending field and its value, e.g.
    ``Image.step 100 is smaller than width*3 = 120``.
    """
