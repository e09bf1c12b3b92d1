"""Offered-QoS records as rosbag2 stores them (metadata v9), without importing rclpy.

rosbag2 keeps, per topic, the list of QoS profiles the recorded publishers offered: in
``metadata.yaml`` as a YAML list (v9) and in each MCAP channel's ``offered_qos_profiles``
metadata as the same list dumped to a YAML *string*. Policies are lower-case enum names
(``keep_last``, ``reliable``, ...), durations are ``{sec, nsec}``; rosbag2 writes an infinite
duration as ``{sec: 9223372036, nsec: 854775807}``. Older metadata (v4..v8) used integer
enums inside a string; :func:`parse_qos_list` reads both.

Conversion to and from rclpy ``QoSProfile`` objects is duck-typed here (attribute names and
enum ``.name``); the rclpy-side constructor lives in ``nmt_ros.nodes.bag_player``.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import yaml

INFINITE_DURATION = (9223372036, 854775807)

# rmw enum values, for metadata versions that stored integers (v4..v8)
_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 3: 'manual_by_topic', 4: 'unknown',
               5: 'best_available'}


@dataclass(frozen=True)
class OfferedQos:
    """One offered QoS profile (the fields rosbag2 serialises, in its order)."""

    history: str = 'keep_last'
    depth: int = 1000
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline: tuple[int, int] = (0, 0)
    lifespan: tuple[int, int] = (0, 0)
    liveliness: str = 'system_default'
    liveliness_lease_duration: tuple[int, int] = (0, 0)
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> dict[str, Any]:
        """The v9 mapping (enum names, ``{sec, nsec}`` durations)."""
        def dur(value: tuple[int, int]) -> dict[str, int]:
            return {'sec': int(value[0]), 'nsec': int(value[1])}

        return {
            'history': self.history,
            'depth': int(self.depth),
            'reliability': self.reliability,
            'durability': self.durability,
            'deadline': dur(self.deadline),
            'lifespan': dur(self.lifespan),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': dur(self.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }

    @classmethod
    def from_dict(cls, item: Mapping[str, Any]) -> OfferedQos:
        """Parse one v4..v9 mapping; integer enums (v8 and older) are mapped to names."""
        def enum(key: str, table: dict[int, str], default: str) -> str:
            value = item.get(key, default)
            if isinstance(value, int) and not isinstance(value, bool):
                return table.get(value, 'unknown')
            return str(value).lower()

        def dur(key: str) -> tuple[int, int]:
            value = item.get(key) or {}
            return int(value.get('sec', 0)), int(value.get('nsec', 0))

        return cls(
            history=enum('history', _HISTORY, 'keep_last'),
            depth=int(item.get('depth', 0)),
            reliability=enum('reliability', _RELIABILITY, 'reliable'),
            durability=enum('durability', _DURABILITY, 'volatile'),
            deadline=dur('deadline'),
            lifespan=dur('lifespan'),
            liveliness=enum('liveliness', _LIVELINESS, 'system_default'),
            liveliness_lease_duration=dur('liveliness_lease_duration'),
            avoid_ros_namespace_conventions=bool(
                item.get('avoid_ros_namespace_conventions', False)),
        )

    @classmethod
    def from_profile(cls, profile: Any) -> OfferedQos:
        """From an rclpy ``QoSProfile`` (e.g. ``get_publishers_info_by_topic()[i].qos_profile``).

        Duck-typed: enums are read by ``.name`` and durations by ``.nanoseconds``.
        """
        def dur(value: Any) -> tuple[int, int]:
            ns = int(getattr(value, 'nanoseconds', 0))
            if ns >= INFINITE_DURATION[0] * 1_000_000_000 + INFINITE_DURATION[1]:
                return INFINITE_DURATION
            return divmod(ns, 1_000_000_000)

        return cls(
            history=profile.history.name.lower(),
            depth=int(profile.depth),
            reliability=profile.reliability.name.lower(),
            durability=profile.durability.name.lower(),
            deadline=dur(profile.deadline),
            lifespan=dur(profile.lifespan),
            liveliness=profile.liveliness.name.lower(),
            liveliness_lease_duration=dur(profile.liveliness_lease_duration),
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )


# Our default for observation topics: lossless replay (reliable) with a deep queue (about one
# second of the 1080 Hz force stream), volatile so late joiners do not get stale samples.
OBSERVATION_QOS = OfferedQos()


def as_qos_list(qos: Any) -> tuple[OfferedQos, ...]:
    """Normalise ``None``, one profile or a sequence of profiles (OfferedQos, v9 dicts or
    rclpy ``QoSProfile``) to a tuple of :class:`OfferedQos`."""
    if qos is None:
        return ()
    if isinstance(qos, OfferedQos | Mapping) or hasattr(qos, 'reliability'):
        qos = [qos]
    out = []
    for item in qos:
        if isinstance(item, OfferedQos):
            out.append(item)
        elif isinstance(item, Mapping):
            out.append(OfferedQos.from_dict(item))
        else:
            out.append(OfferedQos.from_profile(item))
    return tuple(out)


def qos_list_to_yaml(qos: Iterable[OfferedQos]) -> str:
    """The YAML *string* stored in MCAP channel metadata ``offered_qos_profiles`` (v9)."""
    items = [q.to_dict() for q in qos]
    if not items:
        return '[]'
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False).rstrip('\n')


def parse_qos_list(value: Any) -> tuple[OfferedQos, ...]:
    """Parse ``offered_qos_profiles`` from metadata (v9 list, or v4..v8 YAML string)."""
    if value is None or value == '':
        return ()
    if isinstance(value, str):
        value = yaml.safe_load(value)
        if not value:
            return ()
    if isinstance(value, Mapping):
        value = [value]
    return tuple(OfferedQos.from_dict(item) for item in value)
