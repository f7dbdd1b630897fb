# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Progress bars of long jobs: one bar per stage, each with its count and an ETA."""

from __future__ import annotations

from ibr_ros.cli.process import UNITS
from ibr_ros.cli.progress import staged_progress


def test_one_bar_per_stage_with_count_and_eta(capsys):
    with staged_progress(UNITS, enabled=True) as progress:
        for stage in ('keyframes', 'model', 'views', 'write'):
            for done in range(4):
                progress(stage, done, 3)
    err = capsys.readouterr().err
    for stage, unit in (('keyframes', 'keyframe'), ('model', 'keyframe'), ('write', 'message group')):
        line = next(x for x in err.replace('\r', '\n').splitlines()[::-1] if x.startswith(f'{stage}:'))
        assert '3/3' in line
        assert '<' in line  # elapsed<remaining: the ETA
        assert f'{unit}/s' in line or f's/{unit}' in line


def test_no_output_when_disabled(capsys):
    with staged_progress(UNITS, enabled=False) as progress:
        progress('keyframes', 1, 3)
    assert capsys.readouterr().err == ''
