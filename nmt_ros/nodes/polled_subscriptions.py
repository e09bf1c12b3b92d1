"""Subscriptions taken in batches on a timer instead of one executor wake-up per message.

rclpy's executors run one callback per message and wake up for each: measured on this 2-core
machine under load (``bench/bench_transport.py``) a raw subscription to a 1080 Hz
WrenchStamped stream costs 330-470 us of CPU per message under the SingleThreadedExecutor and
900-1100 us under the MultiThreadedExecutor. The EventsExecutor (110-210 us) hands a raw
callback the bytes without the message info (receive and send times), which a recorder needs.
Taken in one go every 10 ms, raw messages cost about 130 us each at 1080 Hz and 46 us at
4320 Hz (mostly the middleware's own receive path; more messages per take, less per message).
The reception time of each message is the middleware's (``received_timestamp``), so batching
changes no recorded time.

The subscriptions live on a hidden helper node (``_<node>_reader``, no parameter, logging or
type-description services) that is never added to an executor, so messages never wake one;
the owner calls :meth:`PolledSubscriptions.take_all` from a timer. Messages wait meanwhile in
the middleware's history (KEEP_LAST ``depth``), which must hold one period's worth. Keeping
that backlog short matters: Fast DDS's cost per received message grows with the number of
unread samples in a reader's history (measured: ~40 us with 1,000, ~270 us with 16,000).
"""
from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile


class PolledSubscriptions:
    """Subscriptions of ``owner``'s context whose messages are taken by :meth:`take_all`."""

    def __init__(self, owner: Node) -> None:
        self.node = Node(
            f'_{owner.get_name()}_reader', namespace=owner.get_namespace(),
            context=owner.context, use_global_arguments=False, enable_rosout=False,
            start_parameter_services=False,
            parameter_overrides=[Parameter('start_type_description_service', value=False)])
        self.subscriptions: dict[str, Any] = {}

    def add(self, topic: str, msg_type: type, qos: QoSProfile, *, raw: bool = True) -> None:
        """Subscribe to ``topic`` (``raw``: CDR bytes, no deserialisation)."""
        if topic in self.subscriptions:
            raise ValueError(f'{topic} is already subscribed')
        self.subscriptions[topic] = self.node.create_subscription(
            msg_type, topic, _never_called, qos, raw=raw)

    def __contains__(self, topic: str) -> bool:
        return topic in self.subscriptions

    def __len__(self) -> int:
        return len(self.subscriptions)

    def take(self, topic: str, limit: int = 0) -> Iterator[tuple[Any, dict]]:
        """Every message waiting on ``topic`` (at most ``limit`` if > 0) as
        ``(message or CDR bytes, message info)``; the info dict holds the middleware's
        ``source_timestamp`` and ``received_timestamp`` [ns]."""
        sub = self.subscriptions[topic]
        handle, msg_type, raw = sub.handle, sub.msg_type, sub.raw
        n = 0
        with handle:
            while not limit or n < limit:
                taken = handle.take_message(msg_type, raw)
                if taken is None:
                    return
                n += 1
                yield taken

    def take_all(self, limit: int = 0) -> dict[str, list[tuple[Any, dict]]]:
        """topic -> the messages waiting on it (topics with none are left out)."""
        out = {}
        for topic in self.subscriptions:
            taken = list(self.take(topic, limit))
            if taken:
                out[topic] = taken
        return out

    def destroy(self) -> None:
        """Destroy the subscriptions and the helper node."""
        self.subscriptions = {}
        self.node.destroy_node()


def _never_called(*_args: object) -> None:
    """The callback of a polled subscription (no executor ever runs it)."""
