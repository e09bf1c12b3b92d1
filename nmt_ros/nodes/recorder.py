"""recorder: every topic of the graph into a rosbag2-layout MCAP bag (like ``ros2 bag record -a``).

Topics are discovered with ``get_topic_names_and_types`` and re-scanned every
``scan_period_s``, so topics that appear later are recorded from their first publisher on.
Each is subscribed *raw* (the CDR bytes as sent, no deserialisation) with a QoS adapted to its
publishers as rosbag2 does: RELIABLE only if every publisher offers it (else BEST_EFFORT),
TRANSIENT_LOCAL only if every publisher offers it, KEEP_LAST ``qos_depth``; the publishers'
offered profiles are stored with the topic. Hidden topics (a name part starting with ``_``)
are skipped unless ``include_hidden``; ``topics`` restricts and ``exclude`` removes names.

Receive path (lossless at 1080 Hz and faster on 2 shared cores): the subscriptions are
*polled* (``nmt_ros.nodes.polled_subscriptions``): every ``take_period_s`` one timer callback
takes every waiting message of every topic and only queues them, sorted by receive time, for
the writer thread (``nmt_ros.io.background_writer``: bounded queue of ``max_queue_mb``, MCAP
records, zstd chunk compression, splitting, file writes). A per-message subscription callback
under rclpy's executors cost 330-900 us of CPU per message here, more than a core for the
graph's ~8,600 messages/s at 1x: the recorder fell behind, the unread backlog in Fast DDS made
every message dearer still, and KEEP_LAST dropped the oldest (10 % of a 10 s force-plate
stream). Taking in batches keeps the middleware's backlog to one period.

Message times: log time = receive time (``received_timestamp`` of the middleware, or the ROS
clock at the take under ``use_sim_time``, i.e. ``/clock``), publish time = the publisher's
source timestamp. Splitting like rosbag2: a new file ``<name>_<i>.mcap`` once the current one
reaches ``max_bag_size`` bytes or spans ``max_bag_duration`` seconds (0 = never), all listed
in one ``metadata.yaml``. Complete chunks are flushed every ``flush_period_s``; on
SIGINT/SIGTERM the recorder keeps taking messages until none arrived for ``drain_idle_s``,
then writes what is queued, the summary and ``metadata.yaml``. A recording killed outright
loses at most the last ``flush_period_s`` and is repaired by ``nmt bag reindex``.
"""
from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
import time
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from nmt_ros.io.background_writer import BackgroundBagWriter
from nmt_ros.io.bags import BagError, BagWriter
from nmt_ros.io.msgdefs import get_message_class
from nmt_ros.io.qos import OfferedQos
from nmt_ros.nodes.node_base import NmtNode
from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions
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
    """Raw, QoS-adapting, polled recorder of all topics (see the module docstring)."""

    #: the middleware's threads keep the default policy here: they stamp each message's
    #: receive time, the recording's log time and the clock the graph's latencies are read
    #: on; under SCHED_BATCH a stamp could wait for a scheduler tick
    BATCH_THREAD_PREFIXES: tuple[str, ...] = ()

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
        self.take_period_s = p('take_period_s', 0.01, 'take the waiting messages of every '
                               'topic this often [s] (the middleware holds them meanwhile)',
                               low=0.0005, high=1.0)
        self.compression = p('compression', 'zstd', 'MCAP chunk compression: zstd, lz4, none')
        self.flush_period_s = p('flush_period_s', 1.0, 'close and flush a chunk this often '
                                '(what a crash may lose) [s]', low=0.01, high=3600.0)
        self.max_bag_size = p('max_bag_size', 0, 'start a new file once the current one '
                              'reaches this size [bytes] (0 = no limit)', low=0,
                              high=1 << 50)
        self.max_bag_duration = p('max_bag_duration', 0.0, 'start a new file once the current '
                                  'one spans this long [s] (0 = no limit)', low=0.0,
                                  high=1e9)
        self.max_queue_mb = p('max_queue_mb', 256, "writer queue bound [MiB]; when full the "
                              "take waits and messages stay in the middleware's history",
                              low=1, high=1 << 20)
        self.drain_idle_s = p('drain_idle_s', 0.3, 'on shutdown, stop once no message came '
                              'for this long [s]', low=0.0, high=60.0)
        self.drain_max_s = p('drain_max_s', 10.0, 'longest shutdown drain [s]', low=0.0,
                             high=3600.0)
        if not self.output:
            self.output = datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S')
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        self.status.settings = {'output': self.output, 'compression': self.compression}
        self.last_message = time.monotonic()
        self.largest_take = 0
        self.heard: set[str] = set()         # topics whose first message arrived
        self.writer: BackgroundBagWriter | None = None
        self.inputs: PolledSubscriptions | None = None
        try:
            bag = BagWriter(self.output, compression=self.compression,
                            flush_period_s=self.flush_period_s,
                            max_bag_size=self.max_bag_size,
                            max_bag_duration_s=self.max_bag_duration)
        except (FileExistsError, OSError, ValueError) as exc:
            self.fail_to_start(f'cannot record: {exc}')
            return
        self.writer = BackgroundBagWriter(bag, max_queue_bytes=self.max_queue_mb << 20,
                                          flush_period_s=self.flush_period_s)
        self.inputs = PolledSubscriptions(self)
        self.status.state = 'recording'
        self.get_logger().info(f'recording to {self.output}')
        self.scan()
        self.create_timer(self.scan_period_s, self.scan)
        self.create_timer(self.take_period_s, self.take)

    def wanted(self, topic: str) -> bool:
        if self.only and topic not in self.only:
            return False
        return topic not in self.exclude and (self.include_hidden or not is_hidden(topic))

    def scan(self) -> None:
        """Subscribe to topics that appeared since the last scan."""
        if self.writer is None or self.inputs is None:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self.inputs or not self.wanted(topic):
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
            self.inputs.add(topic, cls, adapted_qos(offered, self.qos_depth), raw=True)
            self.status.extra['topics'] = len(self.inputs)
            self.get_logger().info(f'recording {topic} [{msgtype}]')

    def take(self) -> int:
        """Take every waiting message and queue it for the writer; returns how many."""
        if self.writer is None or self.inputs is None:
            return 0
        taken = self.inputs.take_all()
        if not taken:
            return 0
        batch = []
        for topic, messages in taken.items():
            self.status.receive(topic, len(messages))
            if topic not in self.heard:          # once per topic: the data began to flow
                self.heard.add(topic)
                self.get_logger().info(f'first message on {topic}')
            batch.extend((topic, data, info['received_timestamp'], info['source_timestamp'])
                         for data, info in messages)
        if self.sim_time:
            now = self.get_clock().now().nanoseconds
            batch = [(topic, data, now, sent) for topic, data, _, sent in batch]
        batch.sort(key=_log_time)
        try:
            self.writer.put(batch)
        except BagError as exc:
            self.fail_to_start(f'recording failed: {exc}')
            return 0
        self.largest_take = max(self.largest_take, len(batch))
        self.last_message = time.monotonic()
        self.status.mark_active()
        return len(batch)

    def status_values(self) -> None:
        if self.writer is not None:
            stats = self.writer.stats
            self.status.extra.update({
                'largest_take': self.largest_take,
                'queue_max_mb': round(stats.max_bytes / (1 << 20), 3),
                'queue_blocked_s': round(stats.blocked_s, 3)})

    def on_shutdown(self, interrupted: bool) -> None:
        """Take what is still arriving, then write what is queued and finalise the bag."""
        if self.writer is None or self.inputs is None:
            return
        start = time.monotonic()
        self.last_message = max(self.last_message, start - self.drain_idle_s / 2)
        while time.monotonic() - start < self.drain_max_s:
            if not self.take():
                if time.monotonic() - self.last_message > self.drain_idle_s:
                    break
                time.sleep(self.take_period_s)
        try:
            info = self.writer.close()
            self.status.state = 'closed'
            self.status.detail = f'{info.message_count} messages in {self.output}'
            self.get_logger().info(self.status.detail)
        except BagError as exc:
            self.status.error = f'could not finalise {self.output}: {exc}'
            self.get_logger().error(self.status.error)
            self.exit_code = 1
        finally:
            self.writer = None
            self.inputs.destroy()
            self.inputs = None


def _log_time(message: tuple[str, bytes, int, int]) -> int:
    return message[2]


def main(args: Sequence[str] | None = None) -> int:
    return run_node(RecorderNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
