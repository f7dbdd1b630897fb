# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Exceptions shared by the command line tools and the nodes."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input (path, file contents, option), reported as one line."""


class BagError(UserError):
    """A bag that cannot be read or written: missing, empty, corrupt, truncated, unsupported."""

    def __init__(self, path: object, problem: str) -> None:
        super().__init__(f'{path}: {problem}')
        self.path = path
        self.problem = problem
