# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The renderer's view order (nearest first) is sorted lazily but equals a full stable sort."""

from __future__ import annotations

import numpy as np

from ibr_ros.core.render.renderer import NearestFirst


def test_every_read_equals_the_full_stable_sort():
    rng = np.random.default_rng(0)
    for _ in range(200):
        n = int(rng.integers(1, 120))
        dist = rng.integers(0, 15, n).astype(float)  # many ties
        idx = np.sort(rng.choice(1000, n, replace=False))
        ref = [int(i) for i in idx[np.argsort(dist, kind='stable')]]
        first = int(rng.integers(1, 40))
        assert list(NearestFirst(idx, dist, first)) == ref
        assert NearestFirst(idx, dist, first)[:4] == ref[:4]
        k = int(rng.integers(0, n))
        assert NearestFirst(idx, dist, first)[k] == ref[k]
        assert NearestFirst(idx, dist, first)[-1] == ref[-1]
        assert NearestFirst(idx, dist, first)[2:] == ref[2:]
        lazy = NearestFirst(idx, dist, first)
        it = iter(lazy)
        head = [next(it) for _ in range(min(3, n))]
        assert head == ref[: len(head)]
        assert lazy[:] == ref
        assert len(lazy) == n
