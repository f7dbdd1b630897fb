# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The benchmark and tool scripts import only names that exist (they are not run by the suite)."""

from __future__ import annotations

import ast
import importlib
import importlib.util
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = sorted([*(REPO / 'bench').glob('*.py'), *(REPO / 'tools').glob('*.py')])


@pytest.mark.parametrize('script', SCRIPTS, ids=lambda p: f'{p.parent.name}/{p.name}')
def test_script_imports_resolve(script: Path) -> None:
    for node in ast.walk(ast.parse(script.read_text(encoding='utf-8'))):
        if (
            isinstance(node, ast.ImportFrom)
            and node.module
            and node.module.split('.')[0] in ('ibr_ros', 'msg_utils')
        ):
            module = importlib.import_module(node.module)
            for alias in node.names:
                assert hasattr(module, alias.name) or importlib.util.find_spec(
                    f'{node.module}.{alias.name}'
                ), f'{script.name}:{node.lineno}: {node.module} has no {alias.name}'
