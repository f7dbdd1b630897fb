# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The node parameters ``ibr process`` reads (``config/<node>.yaml`` + a ROS 2 params file) and the core
configurations mapped from them."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.depth.schedule import ScheduleConfig
from ibr_ros.core.registration.trigger import SfmConfig
from ibr_ros.errors import UserError
from ibr_ros.jobs.process.options import ProcessOptions
from ibr_ros.node_config import table_of
from ibr_ros.node_config.depth_refiner import DEPTH_REFINER
from ibr_ros.node_config.frame_subsampler import FRAME_SUBSAMPLER, FrameSubsamplerConfig
from ibr_ros.node_config.scene_viz import SCENE_VIZ, SceneVizConfig
from ibr_ros.node_config.view_renderer import VIEW_RENDERER, ViewRendererConfig

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules


#: The nodes whose parameters ``ibr process`` reads.
NODES = ('frame_subsampler', 'depth_refiner', 'view_renderer', 'scene_viz')
#: depth_refiner parameters ``ibr process`` sets itself: one worker, the whole flight known.
REFINER_OFFLINE = {'num_workers': 1, 'worker_index': 0, 'refine_again': False}


def _section_targets(key: str) -> str | None:
    """The node a params-file section applies to (``'*'`` for wildcards), from its key."""
    key = str(key).strip()
    if key in ('/**', '**'):
        return '*'
    name = key.rstrip('/').rsplit('/', 1)[-1]
    return name or None


def _read_params_file(path: Path) -> list[tuple[str, dict[str, object]]]:
    """``[(target, {name: value})]`` of a ROS 2 params file, in file order."""
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    except OSError as exc:
        raise UserError(f'{path}: cannot read params file: {exc.strerror or exc}') from exc
    except yaml.YAMLError as exc:
        raise UserError(f'{path}: not a YAML params file: {exc}') from exc
    if not isinstance(doc, dict):
        raise UserError(f'{path}: a params file maps node names to {{ros__parameters: ...}}')
    out = []
    for key, section in doc.items():
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise UserError(f'{path}: section {key!r} has no ros__parameters mapping')
        if (target := _section_targets(key)) is not None:
            out.append((target, params))
    return out


def load_params(params_file: Path | None = None, config: Path | None = None) -> dict[str, dict[str, object]]:
    """Parameters of :data:`NODES`: ``config/<node>.yaml`` (``config`` folder, default the graph's),
    then the sections of ``params_file`` that apply to each node (wildcards first, in file order).

    Raises:
        UserError: Unreadable file, unknown parameter of a named node, a value of the wrong type.

    """
    from ibr_ros.graph import config_dir

    folder = Path(config) if config is not None else config_dir()
    params: dict[str, dict[str, object]] = {}
    for node in NODES:
        params[node] = {}
        for target, values in _read_params_file(folder / f'{node}.yaml'):
            if target in ('*', node):
                params[node].update(values)
    if params_file is None:
        return params
    sections = _read_params_file(Path(params_file))
    for target, values in sorted(sections, key=lambda s: s[0] != '*'):  # stable: wildcards first
        nodes = NODES if target == '*' else (target,) if target in NODES else ()
        if not nodes:
            LOG.info(
                '%s: section for %s ignored (ibr process runs %s)', params_file, target, ', '.join(NODES)
            )
            continue
        for name, value in values.items():
            known = [n for n in nodes if name in params[n]]
            if not known:
                where = nodes[0] if len(nodes) == 1 else 'any of ' + ', '.join(nodes)
                raise UserError(f'{params_file}: {name!r} is not a parameter of {where}')
            for n in known:
                try:
                    params[n][name] = table_of(n)[name].check(value, f'{n}.')
                except UserError as exc:
                    raise UserError(f'{params_file}: {exc}') from None
    return params


@dataclass(frozen=True)
class ProcessConfigs:
    """The core configurations of one ``ibr process`` run, built with the nodes' parameter tables.

    ``subsampler.target_keyframes``: ``ProcessOptions``' when given (0 = the streaming selector);
    ``viewing``: the view_renderer's, with ``ProcessOptions``' width, height and hfov_deg when given;
    ``flush``: offline the flight has ended, as live once ``keyframes/status`` says so; ``scene``:
    the scene_viz's (the viewer topics of the output bag).
    """

    subsampler: FrameSubsamplerConfig
    schedule: ScheduleConfig
    refiner: RefinerConfig
    sfm: SfmConfig
    viewing: ViewRendererConfig
    flush: bool = True
    scene: SceneVizConfig = field(default_factory=lambda: SCENE_VIZ.config({}))


def process_configs(params: dict[str, dict[str, object]], o: ProcessOptions) -> ProcessConfigs:
    """The core configurations, built from the node parameters by the nodes' own tables."""
    fs, dr, vr, sv = (params[n] for n in NODES)
    if o.target_keyframes is not None and o.target_keyframes < 0:
        raise UserError(
            f'target_keyframes (--target-keyframes) must be >= 0 (0 = off), got {o.target_keyframes}'
        )
    size = {'width': o.width, 'height': o.height, 'hfov_deg': o.hfov_deg}
    subsampler = FRAME_SUBSAMPLER.config(fs, where='frame_subsampler.')
    refining = DEPTH_REFINER.config({**dr, **REFINER_OFFLINE}, where='depth_refiner.')
    viewing = VIEW_RENDERER.config(
        {**vr, **{k: v for k, v in size.items() if v is not None}}, where='view_renderer.'
    )
    if o.target_keyframes is not None:
        subsampler = replace(subsampler, target_keyframes=o.target_keyframes)
    return ProcessConfigs(
        subsampler=subsampler,
        schedule=refining.schedule,
        refiner=refining.refiner,
        sfm=refining.sfm,
        viewing=viewing,
        scene=SCENE_VIZ.config(sv, where='scene_viz.'),
    )
