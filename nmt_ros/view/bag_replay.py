"""A bag replayed into the live view (``nmt view --bag``), without a ROS graph.

Every topic of the bag is advertised first, then the messages are sent in log-time order at
their recorded timing scaled by ``rate`` (``rate <= 0``: as fast as possible), each with its
recorded log time, so Foxglove's plots and the scene keep the recording's clock. The
schedule is drift-free (each message is due at start + (log time - first) / rate); the
server's clock is broadcast every ``TIME_PERIOD_S`` of wall time.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
import os
import threading
import time

from nmt_ros.io.bags import bag_info, read_raw
from nmt_ros.view.server import ViewServer

TIME_PERIOD_S = 0.05


@dataclass
class ReplayStats:
    """What a replay sent."""

    messages: int = 0
    wall_s: float = 0.0
    per_topic: dict[str, int] = field(default_factory=dict)
    interrupted: bool = False


def bag_topics(bag: str | os.PathLike) -> list[tuple[str, str]]:
    """(topic, type) of every topic of a bag."""
    return [(t.name, t.type) for t in bag_info(bag).topics]


def replay_bag(server: ViewServer, bag: str | os.PathLike, *, rate: float = 1.0,
               start_s: float = 0.0, duration_s: float | None = None,
               stop: threading.Event | None = None,
               on_message: Callable[[str], None] | None = None) -> ReplayStats:
    """Send the bag's messages (from ``start_s`` after its first message, for ``duration_s``)
    through ``server``; returns counts. ``stop`` ends the replay early."""
    info = bag_info(bag)
    server.advertise_all((t.name, t.type) for t in info.topics)
    begin = info.start_ns + int(round(start_s * 1e9))
    end = None if duration_s is None else begin + int(round(duration_s * 1e9))
    stats = ReplayStats()
    wall0 = time.monotonic()
    last_time = 0.0
    first_log = None
    for raw in read_raw(bag):
        if raw.log_time_ns < begin:
            continue
        if end is not None and raw.log_time_ns > end:
            break
        if stop is not None and stop.is_set():
            stats.interrupted = True
            break
        if first_log is None:
            first_log = raw.log_time_ns
        if rate > 0:
            due = wall0 + (raw.log_time_ns - first_log) / 1e9 / rate
            wait = due - time.monotonic()
            if wait > 0:
                if stop is not None:
                    if stop.wait(wait):
                        stats.interrupted = True
                        break
                else:
                    time.sleep(wait)
        server.publish(raw.topic, raw.data, raw.log_time_ns)
        stats.messages += 1
        stats.per_topic[raw.topic] = stats.per_topic.get(raw.topic, 0) + 1
        now = time.monotonic()
        if now - last_time >= TIME_PERIOD_S:
            server.broadcast_time(raw.log_time_ns)
            last_time = now
        if on_message is not None:
            on_message(raw.topic)
    stats.wall_s = time.monotonic() - wall0
    return stats
