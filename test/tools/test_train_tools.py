# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pure helpers of tools/train_mono.py (torch itself is an optional training extra, not needed here)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[2] / 'tools'


@pytest.fixture(scope='module')
def train_mono():
    spec = importlib.util.spec_from_file_location('train_mono', TOOLS / 'train_mono.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules['train_mono'] = module
    spec.loader.exec_module(module)
    return module


def test_lr_cycles_restart_at_half_the_peak_and_the_last_one_ends_at_zero(train_mono) -> None:
    f = train_mono.lr_factor
    one = [f(s, 5500) for s in range(5500)]
    assert one == [f(s, 11000, 5500) for s in range(5500)]  # cycle 1 = the single-cycle schedule
    assert max(one) == pytest.approx(1.0, abs=5e-3)  # the cosine has begun by the end of the warm-up
    assert f(5499, 11000, 5500) == pytest.approx(0.0, abs=1e-6)
    assert max(f(s, 11000, 5500) for s in range(5500, 11000)) == pytest.approx(0.5, abs=5e-3)
    # a shorter last cycle still anneals to zero at the last step
    assert f(12999, 13000, 5500) == pytest.approx(0.0, abs=1e-5)
    assert max(f(s, 13000, 5500) for s in range(11000, 13000)) == pytest.approx(0.25, abs=0.01)


def test_real_sample_crops_to_the_training_aspect_and_keeps_unknown_depth(train_mono) -> None:
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (360, 640, 3), dtype=np.uint8)
    depth = np.zeros((360, 640), np.float32)
    depth[100:200, 300:400] = 40.0
    r, d = train_mono.real_sample(rgb, depth, (256, 160), rng)
    assert r.shape == (160, 256, 3)
    assert r.dtype == np.uint8
    assert d.shape == (160, 256)
    assert set(np.unique(d).tolist()) <= {0.0, 40.0}  # nearest: no invented depth values
