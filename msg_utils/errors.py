# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The one exception type of :mod:`msg_utils`, and what converting a message may raise."""

from __future__ import annotations

from ibr_ros.core.geometry.camera import CameraError
from ibr_ros.core.geometry.transforms import GeometryError

__all__ = ['CONVERSION_ERRORS', 'MessageError']


class MessageError(ValueError):
    """A message (or a value meant for one) that cannot be converted.

    The text names the offending field and its value, e.g.
    ``Image.step 100 is smaller than width*3 = 120``.
    """


#: What converting a malformed message raises: :class:`MessageError` and the camera and pose
#: validation errors of :mod:`ibr_ros.core.geometry` (all ValueErrors, ValueError itself included).
#: Catch these to count and drop a bad message.
CONVERSION_ERRORS: tuple[type[Exception], ...] = (MessageError, CameraError, GeometryError, ValueError)
