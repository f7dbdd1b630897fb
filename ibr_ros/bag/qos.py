# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Offered QoS profiles of recorded topics, stored as rosbag2 stores them (``offered_qos_profiles``).

rosbag2 keeps, per topic, the QoS profiles that the recorded publishers offered, in ``metadata.yaml``
and in each MCAP channel's metadata; ``ros2 bag play`` offers them again, so that a transient-local
subscriber (e.g. a late-joining renderer) matches the player and gets the history. Metadata version 8
(ROS 2 Jazzy) stores a YAML string of a list of profiles with the policies as rmw enum integers;
version 9 a list with the policies as names. Both are read; version 8 is written.

Only what decides matching and replay is kept: reliability, durability, history and depth. Deadline,
lifespan and liveliness are written as rosbag2 records a default Fast DDS publisher (infinite,
automatic).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, get_args

import yaml

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['Durability', 'History', 'OfferedQos', 'Reliability', 'dump_offered_qos', 'parse_offered_qos']

# Names as rmw's ``*_to_str`` gives them (metadata version 9); the position is the rmw enum value (version 8).
Reliability = Literal['system_default', 'reliable', 'best_effort', 'unknown', 'best_available']
Durability = Literal['system_default', 'transient_local', 'volatile', 'unknown', 'best_available']
History = Literal['system_default', 'keep_last', 'keep_all', 'unknown']
_POLICIES: dict[str, tuple[str, ...]] = {
    'history': get_args(History),
    'reliability': get_args(Reliability),
    'durability': get_args(Durability),
}
_LIVELINESS_AUTOMATIC = 1
#: ``RMW_DURATION_INFINITE``, as rosbag2 records a deadline, lifespan or lease that is not set.
_INFINITE = {'sec': 9223372036, 'nsec': 854775807}


@dataclass(frozen=True)
class OfferedQos:
    """One offered QoS profile: ``OfferedQos('reliable', 'transient_local', depth=1000)``.

    Raises:
        ValueError: A policy name that rmw does not know, or a negative depth.

    """

    reliability: Reliability = 'reliable'
    durability: Durability = 'volatile'
    history: History = 'keep_last'
    depth: int = 10

    def __post_init__(self) -> None:
        for policy, names in _POLICIES.items():
            if getattr(self, policy) not in names:
                raise ValueError(f'{policy} {getattr(self, policy)!r} is not one of {", ".join(names)}')
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise ValueError(f'depth {self.depth!r} is not a non-negative integer')

    @classmethod
    def from_profile(cls, profile: Any) -> OfferedQos:
        """The policies of an rclpy ``QoSProfile`` (its enum values are rmw's, as version 8 stores them)."""
        values = {policy: getattr(profile, policy).value for policy in _POLICIES}
        return cls(
            **{policy: _name(policy, value) for policy, value in values.items()},  # type: ignore[arg-type]  # _name gives a literal
            depth=int(profile.depth),
        )

    def __str__(self) -> str:
        history = f'keep_last {self.depth}' if self.history == 'keep_last' else self.history
        return f'{self.reliability} {self.durability} {history}'


def dump_offered_qos(profiles: Sequence[OfferedQos]) -> str:
    """``offered_qos_profiles`` as rosbag2 writes it with metadata version 8 ('' for no profiles)."""
    if not profiles:
        return ''
    items = [
        {
            'history': _POLICIES['history'].index(q.history),
            'depth': q.depth,
            'reliability': _POLICIES['reliability'].index(q.reliability),
            'durability': _POLICIES['durability'].index(q.durability),
            'deadline': dict(_INFINITE),
            'lifespan': dict(_INFINITE),
            'liveliness': _LIVELINESS_AUTOMATIC,
            'liveliness_lease_duration': dict(_INFINITE),
            'avoid_ros_namespace_conventions': False,
        }
        for q in profiles
    ]
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False).strip()


def parse_offered_qos(value: object) -> tuple[OfferedQos, ...]:
    """The profiles in an ``offered_qos_profiles`` value: a YAML string (version <= 8) or a list (9).

    Policies may be rmw enum integers or names (any case); depth is ignored (0) for ``keep_all``.

    Raises:
        ValueError: Not YAML, not a list of mappings, a policy missing or unknown, a bad depth.

    """
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError as exc:
            raise ValueError(f'not YAML: {" ".join(str(exc).split())}') from exc
    if value is None:
        return ()
    if not isinstance(value, list):
        raise ValueError(f'a list of profiles expected, not {type(value).__name__}')
    profiles = []
    for i, item in enumerate(value):
        if not isinstance(item, dict):
            raise ValueError(f'profile {i}: a mapping expected, not {type(item).__name__}')
        try:
            policies = {policy: _name(policy, item[policy]) for policy in _POLICIES}
            depth = item.get('depth', 0) if policies['history'] == 'keep_all' else item['depth']
            profiles.append(OfferedQos(**policies, depth=depth))  # type: ignore[arg-type]  # names from _name
        except KeyError as exc:
            raise ValueError(f'profile {i}: no {exc.args[0]}') from None
        except ValueError as exc:
            raise ValueError(f'profile {i}: {exc}') from None
    return tuple(profiles)


def _name(policy: str, value: object) -> str:
    """The name of a policy value given as rmw enum integer or name."""
    names = _POLICIES[policy]
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(names):
        return names[value]
    if isinstance(value, str) and value.lower() in names:
        return value.lower()
    raise ValueError(f'{policy} {value!r} is not one of {", ".join(names)} (or 0-{len(names) - 1})')
