# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""depth_confidence: MVS pixels >= 0.5 by score and agreement, filled ones < 0.5 by support and
agreement with the monocular depth, sky and unknown at their constants."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth.confidence import ConfidenceConfig, depth_confidence


def _maps():
    depth = np.full((4, 5), 10.0, np.float32)
    mvs = np.zeros_like(depth)
    mvs[0] = 10.0  # row 0: MVS
    mono = np.full_like(depth, 10.0)
    mono[2] = 20.0  # row 2: monocular depth disagrees by a factor 2
    support = np.zeros_like(depth)
    support[1:3] = 9.0  # rows 1-2: strong MST support; row 3: none
    depth[3, 4] = np.inf  # sky
    depth[3, 3] = 0.0  # unknown
    return depth, mvs, mono, support


def test_the_three_kinds_of_pixel_in_order_of_trust():
    depth, mvs, mono, support = _maps()
    zncc = np.full_like(depth, 0.9)
    zncc[0, 1] = 0.5  # at the acceptance threshold
    count = np.full(depth.shape, 2, np.uint8)
    count[0, 2] = 1  # one agreeing view of the two wanted
    c = depth_confidence(depth, mvs, mono, support, zncc=zncc, n_consistent=count)
    assert c.dtype == np.float32
    assert c[0, 0] == pytest.approx(0.5 + 0.5 * 0.8)
    assert c[0, 1] == pytest.approx(0.5)
    assert c[0, 2] == pytest.approx(0.5 + 0.5 * 0.8 * 0.5)
    s = 9.0 / 10.0
    assert c[1, 0] == pytest.approx(0.1 + 0.4 * s)  # supported and agreeing
    assert c[2, 0] == pytest.approx(0.1 + 0.4 * s * np.exp(-np.log(2) / 0.25))  # contradicted
    assert c[3, 0] == pytest.approx(0.1)  # monocular depth alone
    assert c[1, 0] > c[2, 0] > c[3, 0]
    assert c[3, 4] == pytest.approx(0.5)  # sky
    assert c[3, 3] == 0.0
    assert (c[1:3] < 0.5).all()
    assert (c[3, :3] < 0.5).all()
    full = depth_confidence(depth, mvs, mono, support)  # no MVS evidence given: full terms
    assert full[0, 0] == pytest.approx(1.0)


def test_bad_input_names_the_argument():
    depth, mvs, mono, support = _maps()
    with pytest.raises(ValueError, match=r'support has shape \(2, 2\), the depth is \(4, 5\)'):
        depth_confidence(depth, mvs, mono, np.zeros((2, 2)))
    with pytest.raises(ValueError, match='depth must be HxW'):
        depth_confidence(depth[0], mvs, mono, support)
    with pytest.raises(ValueError, match='min_zncc'):
        ConfidenceConfig(min_zncc=1.0)
    with pytest.raises(ValueError, match='mono_only'):
        ConfidenceConfig(mono_only=2.0)


def test_mvs_pixels_at_a_depth_step_are_not_confident():
    """Window matching smears the nearer surface over the farther one: MVS pixels within
    ``edge_radius_px`` of a step of more than ``edge_step`` drop below 0.5, the others keep >= 0.5."""
    depth = np.full((9, 12), 40.0, np.float32)
    depth[:, 6:] = 20.0  # a roof edge
    mvs = depth.copy()
    c = depth_confidence(depth, mvs, depth, np.zeros_like(depth))
    assert (c[:, 4:8] < 0.5).all()  # within 2 px of the step
    assert (c[:, :3] == 1.0).all()
    assert (c[:, 9:] == 1.0).all()
    off = depth_confidence(depth, mvs, depth, np.zeros_like(depth), config=ConfidenceConfig(edge_radius_px=0))
    assert (off == 1.0).all()
