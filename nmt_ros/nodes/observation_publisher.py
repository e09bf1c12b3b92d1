"""observation_publisher: replays a bag's observation topics at their recorded timing.

Publishes ``/mocap/segment_angles`` (120 Hz) and ``/force_plate/wrench`` (1080 Hz) from
``bag`` (the CDR bytes as recorded, header stamps untouched) at ``rate`` x real time, and
``/clock`` with the bag time when ``publish_clock`` is set. Like ``ros2 bag play
--wait-for-subscribers``, it first waits until every replayed topic has
``expected_subscribers`` matched subscriptions (up to ``wait_timeout_s``; then it reports an
ERROR and does not replay: it never publishes into a graph that would drop data silently).

QoS: RELIABLE, KEEP_LAST ``qos_depth`` (deep), VOLATILE, whatever the bag recorded, so a
replay through the graph loses nothing; best-effort subscribers still connect. After the
last message it waits until every reliable subscriber acknowledged everything, then
announces the end of stream on ``/nmt/status`` (the number of messages per topic; the
trackers flush when they have seen that many) and, with ``exit_when_finished``, exits
(exit code 0, or 1 if the subscribers were missing or did not acknowledge).
"""
from __future__ import annotations

from collections.abc import Sequence
import itertools
from pathlib import Path
import threading
import time

from msg_adapters.cdr_header import header_stamp_ns
from msg_adapters.diagnostics import ERROR
from nmt_ros.io.bags import BagError, bag_info, read_raw
from nmt_ros.io.replay import ReadAhead
from nmt_ros.nodes.bag_player import BagPlayer
from nmt_ros.nodes.node_base import NmtNode, data_qos
from nmt_ros.nodes.readiness import missing_subscribers
from nmt_ros.nodes.runtime import run_node
from nmt_ros.topics import OBSERVATIONS

NODE_NAME = 'observation_publisher'
DEFAULT_BAG = Path(__file__).resolve().parents[2] / 'bags' / 'reference_jump'
#: Niceness of the bag-reading thread (its chunks are read well ahead of the schedule, so it
#: can wait for the trackers; the pacing and publishing thread keeps the process's priority).
READER_NICE = 10


def first_stamps(bag: str, topics: list[str]) -> dict[str, int]:
    """Header stamp of each topic's first message (identifies the trial to consumers)."""
    out: dict[str, int] = {}
    for raw in read_raw(bag, topics):
        if raw.topic not in out:
            try:
                out[raw.topic] = header_stamp_ns(raw.data)
            except ValueError:
                out[raw.topic] = 0
        if len(out) == len(topics):
            break
    return {t: s for t, s in out.items() if s}


class ObservationPublisherNode(NmtNode):
    """Timed replay of observation topics (see the module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, exit_default=True, gated=False, **kwargs)
        p = self.param
        self.bag = p('bag', '', "bag folder (or .mcap) to replay ('' = the shipped "
                     'bags/reference_jump of the source tree)') or str(DEFAULT_BAG)
        self.rate = p('rate', 1.0, 'replay speed factor (2 = twice real time)', low=0.001,
                      high=1000.0)
        self.topics = p('topics', list(OBSERVATIONS), 'topics to replay')
        self.publish_clock = p('publish_clock', False, 'publish /clock with the bag time')
        self.clock_hz = p('clock_hz', 100.0, '/clock rate (wall clock) [Hz]', low=0.1,
                          high=10000.0)
        self.expected_subscribers = p(
            'expected_subscribers', 1, 'matched subscriptions each replayed topic needs '
            'before the replay starts (0 = start at once)', low=0, high=1000)
        self.start_delay_s = p('start_delay_s', 0.0, 'pause after the subscribers matched [s]',
                               low=0.0, high=3600.0)
        self.ack_timeout_s = p('ack_timeout_s', 10.0, 'wait this long at the end for '
                               'reliable subscribers to acknowledge [s]', low=0.0, high=3600.0)
        self.duration_s = p('duration_s', 0.0, 'replay only the samples stamped within this '
                            'long of the first [s] (0 = the whole bag)', low=0.0, high=1e7)
        self.status.settings = {'bag': self.bag, 'rate': self.rate,
                                'publish_clock': self.publish_clock,
                                'duration_s': self.duration_s}
        try:
            info = bag_info(self.bag)
            wanted = [t for t in info.topics if t.name in set(self.topics)]
            absent = sorted(set(self.topics) - {t.name for t in wanted})
            if absent:
                raise BagError(f'topics not in the bag {self.bag}: {absent}')
        except (BagError, KeyError, OSError) as exc:
            self.fail_to_start(f'cannot replay: {exc}')
            return
        self.first_stamps = first_stamps(self.bag, [t.name for t in wanted])
        self.player = BagPlayer(self, wanted, qos_override=data_qos(self.qos_depth),
                                publish_clock=self.publish_clock)
        self.stats = None
        self._stop = threading.Event()
        self.status.state = 'waiting'
        self._thread = threading.Thread(target=self._replay, name='replay', daemon=True)
        self._thread.start()

    def _replay(self) -> None:
        messages = read_raw(self.bag, self.topics)
        if self.duration_s > 0:
            end_ns = min(self.first_stamps.values()) + round(self.duration_s * 1e9)
            # (read in log-time order: stop reading at the first sample past the end)
            messages = itertools.takewhile(
                lambda m: header_stamp_ns(m.data) <= end_ns, messages)
        # read ahead from now on: the first chunks are decoded while the subscribers come up,
        # not during the trackers' cold start (io.replay.ReadAhead)
        ahead = ReadAhead(messages, reader_nice=READER_NICE)
        try:
            if not self._wait_for_subscribers():
                return
            if self.start_delay_s > 0:
                self._stop.wait(self.start_delay_s)
            self.status.state = 'replaying'
            self.status.mark_active()
            self.publish_status()
            stats = self.player.play(iter(ahead),
                                     rate=self.rate,
                                     clock_hz=self.clock_hz if self.publish_clock else None,
                                     stop=self._stop, ack_timeout_s=0.0)
            self.stats = stats
            for topic, n in stats.per_topic.items():
                self.status.publish(topic, n)
            late = stats.lateness.summary_ms()
            self.status.extra.update({'max_late_ms': stats.max_late_ns / 1e6,
                                      'late_p50_ms': late['p50_ms'],
                                      'late_p99_ms': late['p99_ms'],
                                      'replay_wall_s': stats.wall_s})
            if self._stop.is_set():
                self.status.state = 'stopped'
                return
            # announce first (consumers count messages, so the announcement may overtake
            # data), then make sure every reliable subscriber has everything
            self.status.state = 'finished'
            self.announce_end(dict(stats.per_topic), self.first_stamps, bag=self.bag,
                              rate=self.rate)
            acked = self.player.wait_for_acks(self.ack_timeout_s)
            self.status.extra['all_acknowledged'] = acked
            if not acked:
                self.status.error = ('replay finished but not every reliable subscriber '
                                     f'acknowledged within {self.ack_timeout_s:g} s')
                self.exit_code = 1
            self.publish_status()
        except Exception as exc:  # noqa: BLE001 - reported, the process ends with code 1
            self.status.error = f'replay failed: {exc!r}'
            self.exit_code = 1
            self.publish_status()
        finally:
            ahead.close()
            if self.exit_when_finished:
                self.done = True

    def _wait_for_subscribers(self) -> bool:
        if self.expected_subscribers <= 0:
            return True
        wanted = {name: self.expected_subscribers for name in self.player.publishers}
        deadline = time.monotonic() + self.wait_timeout_s
        while not self._stop.is_set():
            counts = {name: pub.get_subscription_count()
                      for name, pub in self.player.publishers.items()}
            missing = missing_subscribers(wanted, counts)
            if not missing:
                self.status.detail = ''
                return True
            self.status.detail = f'waiting for subscribers: {missing}'
            if time.monotonic() >= deadline:
                self.status.error = (f'no replay: after {self.wait_timeout_s:g} s the topics '
                                     f'still lack subscribers (have/want): {missing}')
                self.status.event(ERROR, self.status.error)
                self.status.state = 'failed'
                self.exit_code = 1
                self.publish_status()
                return False
            time.sleep(0.01)
        return False

    def on_shutdown(self, interrupted: bool) -> None:
        if hasattr(self, '_stop'):
            self._stop.set()
            self._thread.join(timeout=5.0)
        self.publish_status()
        self.wait_for_acks(2.0)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(ObservationPublisherNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
