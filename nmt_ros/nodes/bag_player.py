"""Publish recorded messages over ROS 2 at their recorded timing (the rclpy side of replay).

:class:`BagPlayer` owns one publisher per topic on a node it is given (it never inits rclpy
or spins), publishes CDR bytes as they are stored (or message objects) and optionally
``/clock``. Timing comes from the pure :class:`nmt_ros.io.replay.ReplayScheduler`.

QoS follows ``ros2 bag play``: a topic is published with its recorded offered QoS when all
recorded offers agree, else with our default :data:`nmt_ros.io.qos.OBSERVATION_QOS`
(RELIABLE, KEEP_LAST 1000, VOLATILE: lossless replay, and best-effort subscribers such as
``nmt echo`` still connect). ``/clock`` uses the clock QoS of rclcpp/rclpy (KEEP_LAST 1,
BEST_EFFORT).
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
import os
import time
from typing import Any

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosgraph_msgs.msg import Clock

from msg_adapters.clock import to_clock
from nmt_ros.io.bags import TopicInfo
from nmt_ros.io.msgdefs import get_message_class
from nmt_ros.io.qos import INFINITE_DURATION, OBSERVATION_QOS, OfferedQos
from nmt_ros.io.replay import CLOCK, Lateness, ReplayScheduler
from nmt_ros.topics import CLOCK as CLOCK_TOPIC

CLOCK_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)


def _duration(value: tuple[int, int]) -> Duration:
    if tuple(value) == INFINITE_DURATION:
        return Duration()  # "default": infinite for deadline/lifespan/lease
    return Duration(seconds=int(value[0]), nanoseconds=int(value[1]))


def qos_profile(offered: OfferedQos) -> QoSProfile:
    """An :class:`OfferedQos` record -> rclpy ``QoSProfile``."""
    def policy(enum: Any, name: str) -> Any:
        key = name.upper()
        if key not in enum.__members__ or key == 'UNKNOWN':
            return enum.SYSTEM_DEFAULT
        return enum[key]

    history = policy(HistoryPolicy, offered.history)
    depth = int(offered.depth) if offered.depth > 0 else OBSERVATION_QOS.depth
    return QoSProfile(
        history=history, depth=depth,
        reliability=policy(ReliabilityPolicy, offered.reliability),
        durability=policy(DurabilityPolicy, offered.durability),
        deadline=_duration(offered.deadline), lifespan=_duration(offered.lifespan),
        liveliness=policy(LivelinessPolicy, offered.liveliness),
        liveliness_lease_duration=_duration(offered.liveliness_lease_duration),
        avoid_ros_namespace_conventions=offered.avoid_ros_namespace_conventions)


def playback_qos(recorded: Sequence[OfferedQos]) -> QoSProfile:
    """The recorded offer if all recorded offers agree, else the default (rosbag2's rule)."""
    if recorded and all(q == recorded[0] for q in recorded):
        return qos_profile(recorded[0])
    return qos_profile(OBSERVATION_QOS)


@dataclass
class PlaybackStats:
    """What :meth:`BagPlayer.play` did."""

    messages: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    clock_messages: int = 0
    max_late_ns: int = 0
    lateness: Lateness = field(default_factory=Lateness)   # of the messages (not /clock)
    wall_s: float = 0.0
    all_acked: bool = True


class BagPlayer:
    """Publishers for a set of recorded topics, plus timed playback.

    ``topics``: :class:`~nmt_ros.io.bags.TopicInfo` records (name, type, offered QoS), e.g.
    ``bag_info(path).topics``. ``qos_override`` replaces the recorded QoS for every topic.
    """

    def __init__(self, node: Node, topics: Iterable[TopicInfo], *,
                 qos_override: QoSProfile | None = None, publish_clock: bool = False,
                 clock_topic: str = CLOCK_TOPIC) -> None:
        self.node = node
        self.publishers = {}
        for topic in topics:
            qos = qos_override or playback_qos(topic.offered_qos)
            self.publishers[topic.name] = node.create_publisher(
                get_message_class(topic.type), topic.name, qos)
        self.clock_publisher = (node.create_publisher(Clock, clock_topic, CLOCK_QOS)
                                if publish_clock else None)

    def missing_subscribers(self, min_count: int = 1) -> dict[str, int]:
        """Topics with fewer than ``min_count`` matched subscriptions -> their count."""
        counts = {name: pub.get_subscription_count() for name, pub in self.publishers.items()}
        return {name: c for name, c in counts.items() if c < min_count}

    def wait_for_subscribers(self, min_count: int = 1, timeout_s: float = 10.0,
                             poll_s: float = 0.01) -> None:
        """Block until every topic has ``min_count`` matched subscriptions.

        Raises ``TimeoutError`` naming the topics still short after ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            missing = self.missing_subscribers(min_count)
            if not missing:
                return
            if time.monotonic() >= deadline:
                listing = ', '.join(f'{name} ({count})' for name, count in missing.items())
                raise TimeoutError(
                    f'waited {timeout_s:g} s for {min_count} subscriber(s) per topic; still '
                    f'short: {listing}')
            time.sleep(poll_s)

    def publish(self, topic: str, data: Any) -> None:
        """Publish CDR bytes or a message object on a player topic."""
        self.publishers[topic].publish(data)

    def publish_clock(self, bag_time_ns: int) -> None:
        """Publish ``/clock`` (no-op without ``publish_clock=True``)."""
        if self.clock_publisher is not None:
            self.clock_publisher.publish(to_clock(int(bag_time_ns)))

    def play(self, messages: Iterable[Any], *, rate: float = 1.0,
             clock_hz: float | None = None, stop: Any = None,
             scheduler: ReplayScheduler | None = None,
             ack_timeout_s: float = 5.0) -> PlaybackStats:
        """Publish ``messages`` (items with ``topic``, ``log_time_ns`` and ``data``: CDR bytes
        or a message) at their recorded timing; blocks until done or ``stop`` is set.

        Items on topics without a publisher are skipped. With ``clock_hz`` (and
        ``publish_clock=True``) ``/clock`` ticks at that wall rate, carrying the bag time.
        At the end waits up to ``ack_timeout_s`` for reliable subscribers to acknowledge.
        """
        sched = scheduler or ReplayScheduler(rate, clock_hz=clock_hz)
        stats = PlaybackStats(per_topic={name: 0 for name in self.publishers})
        wanted = (m for m in messages if m.topic in self.publishers)
        start = time.monotonic()
        for event in sched.run(wanted, stop=stop):
            stats.max_late_ns = max(stats.max_late_ns, event.late_ns)
            if event.kind == CLOCK:
                self.publish_clock(event.bag_time_ns)
                stats.clock_messages += self.clock_publisher is not None
                continue
            item = event.item
            self.publishers[item.topic].publish(item.data)
            stats.lateness.add(event.late_ns)
            stats.messages += 1
            stats.per_topic[item.topic] += 1
        stats.all_acked = self.wait_for_acks(ack_timeout_s)
        stats.wall_s = time.monotonic() - start
        return stats

    def wait_for_acks(self, timeout_s: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (True if so)."""
        ok = True
        for pub in self.publishers.values():
            ok &= pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9)))
        return bool(ok)

    def destroy(self) -> None:
        """Destroy the publishers (the node stays)."""
        for pub in self.publishers.values():
            self.node.destroy_publisher(pub)
        if self.clock_publisher is not None:
            self.node.destroy_publisher(self.clock_publisher)
        self.publishers = {}
        self.clock_publisher = None


def default_node_name(prefix: str = 'nmt_bag_player') -> str:
    """A node name unique per process (several players may run at once)."""
    return f'{prefix}_{os.getpid()}'
