# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe images, depth and confidence kept on disk during ``ibr process``, so that its memory does
not grow with the flight.

:meth:`SpillStore.put` writes an array to a ``.npy`` file and returns it memory-mapped
(copy-on-write: it behaves as the array did, and nothing is written back). A mapped page is
resident only once read through that mapping; :func:`loaded` reads a fresh in-memory copy by file
instead (the mapping stays untouched), :func:`remapped` a fresh mapping (the old one, and the pages
read through it, go once it is dropped). The store's folder is removed by :meth:`SpillStore.close`
(also on errors and interrupts, used as a context manager).
"""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path
from types import TracebackType

import numpy as np

__all__ = ['SpillStore', 'loaded', 'remapped']


class SpillStore:
    """Arrays in ``.npy`` files of a new folder ``folder`` (removed on :meth:`close`)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True)
        self._n = itertools.count()
        self.nbytes = 0  # written so far

    def put(self, array: np.ndarray, name: str = 'a') -> np.ndarray:
        """``array`` written to disk, returned memory-mapped (same dtype, shape and values)."""
        path = self.folder / f'{next(self._n):06d}_{name}.npy'
        a = np.ascontiguousarray(array)
        np.save(path, a, allow_pickle=False)
        self.nbytes += a.nbytes
        return np.load(path, mmap_mode='c')

    def close(self) -> None:
        """Remove the folder and its files (the mapped arrays must not be read afterwards)."""
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> SpillStore:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def loaded(a: np.ndarray) -> np.ndarray:
    """An in-memory copy of a spilled array read from its file (not through its mapping); any
    other array as it is."""
    if isinstance(a, np.memmap) and a.filename is not None:
        return np.load(a.filename)
    return a


def remapped(a: np.ndarray) -> np.ndarray:
    """A fresh mapping of a spilled array (none of its pages resident); any other array as it is."""
    if isinstance(a, np.memmap) and a.filename is not None:
        return np.load(a.filename, mmap_mode='c')
    return a
