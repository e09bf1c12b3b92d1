"""recorder: every topic of the graph into a rosbag2-layout MCAP bag (like ``ros2 bag record -a``).

Topics are discovered with ``get_topic_names_and_types`` and re-scanned every
``scan_period_s``, so topics that appear later are recorded from their first publisher on.
Each is subscribed *raw* (the CDR bytes as sent, no deserialisation) with a QoS adapted to its
publishers as rosbag2 does: RELIABLE only if every publisher offers it (else BEST_EFFORT),
TRANSIENT_LOCAL only if every publisher offers it, KEEP_LAST ``qos_depth``; the publishers'
offered profiles are stored with the topic. Hidden topics (a name part starting with ``_``)
are skipped unless ``include_hidden``; ``topics`` restricts and ``exclude`` removes names.

Message times: log time = receive time (``received_timestamp`` of the middleware, or the ROS
clock under ``use_sim_time``, i.e. ``/clock``), publish time = the publisher's source
timestamp. The bag (``nmt_ros.io.bags.BagWriter``) flushes complete chunks every
``flush_period_s``; on SIGINT/SIGTERM the recorder keeps taking messages until none arrived
for ``drain_idle_s``, then writes the summary and ``metadata.yaml``. A recording killed
outright loses at most the last chunk and is repaired by ``nmt bag reindex``.
"""
from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
import time
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from nmt_ros.io.bags import BagWriter
from nmt_ros.io.msgdefs import get_message_class
from nmt_ros.io.qos import OfferedQos
from nmt_ros.nodes.node_base import NmtNode
from nmt_ros.nodes.runtime import run_node

NODE_NAME = 'recorder'


def adapted_qos(offered: Sequence[Any], depth: int) -> QoSProfile:
    """rosbag2's rule: request what *every* publisher offers (reliability, durability)."""
    reliable = bool(offered) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    transient = bool(offered) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if transient
                                  else DurabilityPolicy.VOLATILE))


def is_hidden(topic: str) -> bool:
    return any(part.startswith('_') for part in topic.split('/') if part)


class RecorderNode(NmtNode):
    """Raw, QoS-adapting recorder of all topics (see the module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.param
        self.output = p('output', '', "bag folder to create ('' = "
                        "rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory)")
        self.only = set(p('topics', [''], "record only these topics ('' = all)"))
        self.exclude = set(p('exclude', [''], 'topics never recorded'))
        self.include_hidden = p('include_hidden', False, 'also record hidden topics')
        self.scan_period_s = p('scan_period_s', 0.1, 'topic discovery period [s]', low=0.005,
                               high=60.0)
        self.compression = p('compression', 'zstd', 'MCAP chunk compression: zstd, lz4, none')
        self.flush_period_s = p('flush_period_s', 1.0, 'close and flush a chunk this often '
                                '(what a crash may lose) [s]', low=0.01, high=3600.0)
        self.drain_idle_s = p('drain_idle_s', 0.3, 'on shutdown, stop once no message came '
                              'for this long [s]', low=0.0, high=60.0)
        self.drain_max_s = p('drain_max_s', 10.0, 'longest shutdown drain [s]', low=0.0,
                             high=3600.0)
        if not self.output:
            self.output = datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S')
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        self.status.settings = {'output': self.output, 'compression': self.compression}
        self.subscriptions_by_topic: dict[str, Any] = {}
        self.last_message = time.monotonic()
        self.writer: BagWriter | None = None
        try:
            self.writer = BagWriter(self.output, compression=self.compression,
                                    flush_period_s=self.flush_period_s)
        except (FileExistsError, OSError, ValueError) as exc:
            self.fail_to_start(f'cannot record: {exc}')
            return
        self.status.state = 'recording'
        self.get_logger().info(f'recording to {self.output}')
        self.scan()
        self.create_timer(self.scan_period_s, self.scan)

    def wanted(self, topic: str) -> bool:
        if self.only and topic not in self.only:
            return False
        return topic not in self.exclude and (self.include_hidden or not is_hidden(topic))

    def scan(self) -> None:
        """Subscribe to topics that appeared since the last scan."""
        if self.writer is None:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subscriptions_by_topic or not self.wanted(topic):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue  # only subscribers so far: nothing to record yet
            msgtype = types[0]
            if len(types) > 1:
                self.status.event(1, f'{topic} has several types {types}; recording {msgtype}')
            try:
                cls = get_message_class(msgtype)
                offered = [i.qos_profile for i in infos]
                self.writer.add_topic(topic, msgtype, [OfferedQos.from_profile(q)
                                                       for q in offered])
            except (ValueError, KeyError) as exc:
                self.exclude.add(topic)
                self.status.event(1, f'cannot record {topic} ({msgtype}): {exc}')
                continue
            self.subscriptions_by_topic[topic] = self.create_subscription(
                cls, topic, self._callback(topic), adapted_qos(offered, self.qos_depth),
                raw=True)
            self.status.extra['topics'] = len(self.subscriptions_by_topic)
            self.get_logger().info(f'recording {topic} [{msgtype}]')

    def _callback(self, topic: str) -> Any:
        def on_message(data: bytes, info: dict) -> None:
            if self.writer is None:
                return
            log_ns = (self.get_clock().now().nanoseconds if self.sim_time
                      else int(info['received_timestamp']))
            self.writer.write(topic, data, log_ns, int(info['source_timestamp']))
            self.status.receive(topic)
            self.last_message = time.monotonic()
            self.status.mark_active()
        return on_message

    def on_shutdown(self, interrupted: bool) -> None:
        """Take what is still queued, then finalise the bag."""
        if self.writer is None:
            return
        executor = self.executor
        start = time.monotonic()
        self.last_message = max(self.last_message, start - self.drain_idle_s / 2)
        while executor is not None and time.monotonic() - start < self.drain_max_s:
            executor.spin_once(timeout_sec=0.02)
            if time.monotonic() - self.last_message > self.drain_idle_s:
                break
        info = self.writer.close()
        self.writer = None
        self.status.state = 'closed'
        self.status.detail = f'{info.message_count} messages in {self.output}'
        self.get_logger().info(self.status.detail)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(RecorderNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
