"""Readiness: a node opens its inputs only once its outputs have their subscribers.

The ``wait_for`` parameter lists ``'/topic=N'`` entries (:func:`parse_wait_for`); the node
base checks them against the matched subscriptions (:func:`missing_subscribers`), so
readiness propagates upstream and nothing is published into the void. ROS-free.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence


def parse_wait_for(entries: Sequence[str]) -> dict[str, int]:
    """``['/a=2', '/b']`` -> ``{'/a': 2, '/b': 1}``; ValueError names a malformed entry."""
    out: dict[str, int] = {}
    for entry in entries:
        entry = entry.strip()
        if not entry:
            continue
        topic, _, count = entry.partition('=')
        topic = topic.strip()
        if not topic.startswith('/'):
            raise ValueError(f'wait_for entry {entry!r}: expected "/topic=N"')
        try:
            n = int(count) if count.strip() else 1
        except ValueError:
            raise ValueError(f'wait_for entry {entry!r}: N must be an integer') from None
        if n < 0:
            raise ValueError(f'wait_for entry {entry!r}: N must be >= 0')
        out[topic] = n
    return out


def missing_subscribers(wanted: Mapping[str, int], counts: Mapping[str, int]) -> dict[str, str]:
    """Topics short of subscribers -> 'have/want' text."""
    return {t: f'{counts.get(t, 0)}/{n}' for t, n in wanted.items() if counts.get(t, 0) < n}
