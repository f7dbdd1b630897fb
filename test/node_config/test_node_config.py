# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Node parameter tables: the single source of the nodes' parameters, ``ibr process``'s configurations,
``config/*.yaml`` and the README's node reference."""

from __future__ import annotations

import pytest
import yaml

from ibr_ros.core.render import RenderConfig
from ibr_ros.errors import UserError
from ibr_ros.node_config import TABLES, VIEW_RENDERER, Param, render_config
from ibr_ros.node_config.__main__ import expected


def test_shipped_params_files_and_readme_reference_are_generated_from_the_tables(repo) -> None:
    files = expected(repo)
    assert repo / 'README.md' in files, 'README.md lacks the generated node list markers'
    for path, text in files.items():
        assert path.read_text(encoding='utf-8') == text, f'{path}: run python -m ibr_ros.node_config --write'
    assert sorted(p.stem for p in (repo / 'config').glob('*.yaml')) == sorted(TABLES)


@pytest.mark.parametrize('node', sorted(TABLES))
def test_defaults_build_a_config_and_the_params_file_holds_them(node, repo) -> None:
    table = TABLES[node]
    shipped = yaml.safe_load((repo / 'config' / f'{node}.yaml').read_text())['/**']['ros__parameters']
    assert shipped == table.defaults()
    assert table.config(shipped) == table.config({})


def test_render_parameter_defaults_are_the_core_defaults_and_the_params_file(repo) -> None:
    assert render_config({}) == RenderConfig()
    shipped = yaml.safe_load((repo / 'config' / 'view_renderer.yaml').read_text())['/**']['ros__parameters']
    assert render_config(shipped) == RenderConfig()
    assert VIEW_RENDERER.config(shipped).render == RenderConfig()


def test_zero_switches_the_additions_off_giving_the_papers_renderer() -> None:
    off = {'blend': 'paper', 'depth_split': 0.0, 'coverage_px': 0.0, 'depth_tolerance': 0.0}
    paper = render_config(
        {
            **off, 'resolution_weight_deg': 0.0, 'depth_lookup_steps': 0, 'min_depth_samples': 10,
            'confidence_weight_deg': 0.0, 'fill_holes_px': 0,
        }
    )  # fmt: skip
    assert paper == RenderConfig.paper()
    assert render_config({'depth_split': 0.05, 'n_views': 2}).depth_split == 0.05


@pytest.mark.parametrize(
    ('values', 'match'),
    [
        ({'blend': 'max'}, "blend must be 'paper', 'soft', 'ulr' or 'stable', got 'max'"),
        ({'n_views': 5}, 'n_views must be 1..4, got 5'),
        ({'coverage_px': -1.0}, r'coverage_px must be 0..1000, got -1.0'),
        ({'depth_tolerance': 'wide'}, "depth_tolerance must be a number .*, got 'wide'"),
        ({'depth_lookup_max_px': 0.0}, r'depth_lookup_max_px must be 0.01..1000, got 0.0'),
        ({'n_segments': 1.5}, r'n_segments must be an integer .*, got 1.5'),
        ({'no_such': 1}, "'no_such' is not a parameter of view_renderer"),
    ],
)
def test_bad_render_parameters_are_user_errors_naming_them(values, match) -> None:
    with pytest.raises(UserError, match=match):
        VIEW_RENDERER.config(values)


def test_a_param_checks_its_type_range_and_choices() -> None:
    assert Param('x', 1.0, 'x').check(2) == 2.0  # an integer is accepted for a double
    with pytest.raises(UserError, match=r'parameter n\.x must be true or false'):
        Param('x', True, 'x').check(1, 'n.')
    with pytest.raises(ValueError, match='not one of its choices'):
        Param('m', 'c', 'm', choices=('a', 'b'))
    with pytest.raises(ValueError, match='a bool has no range'):
        Param('b', False, 'b', range=(0, 1))


@pytest.mark.parametrize('node', sorted(TABLES))
def test_every_parameter_is_described_and_numbers_have_a_range(node) -> None:
    for p in TABLES[node].params:
        assert p.description, p.name
        if p.kind in ('int', 'double'):
            assert p.range is not None, f'{node}.{p.name} has no range'
            assert p.range[0] <= p.default <= p.range[1], p.name


@pytest.mark.parametrize('node', sorted(TABLES))
def test_every_node_documents_its_diagnostics_and_their_period(node) -> None:
    from ibr_ros.core.diagnostics import AREAS
    from ibr_ros.node_config.table import DIAGNOSTICS_PERIOD, DIAGNOSTICS_TOPIC

    table = TABLES[node]
    assert table['diagnostics_period_s'] == DIAGNOSTICS_PERIOD
    assert DIAGNOSTICS_TOPIC in table.publishes
    assert table.diagnostics is not None
    keys = table.diagnostics.keys()
    assert list(keys) == list(AREAS)
    assert 'total' in keys['rejected']
    assert {'latency.count', 'latency_ms.median', 'latency_ms.p95', 'latency_ms.max'} <= set(keys['outputs'])
    assert table.diagnostics.reference() in table.reference()
