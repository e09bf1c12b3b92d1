"""ROS-free helpers of the nodes: input gates, trial time, status book-keeping, end of stream.

Nothing here imports rclpy or message packages, so the rules that decide what a node accepts
and what it reports are tested without a ROS graph (``test/test_node_core.py``):

- :class:`StreamGate` checks one input stream's stamps (duplicate, out of order, before the
  trial start) and spacing. Gaps longer than ``gap_factor`` periods are filled by linear
  interpolation at the nominal period (the zero-lag filters and Stage 2 need uniform
  samples) and reported; a gap longer than ``max_gap_s`` ends the trial instead.
- :class:`TrialClock`: trial time ``t = (stamp - epoch) * 1e-9`` s with the epoch fixed by a
  parameter or by the first accepted observation.
- :class:`NodeStatus`: counters, rejected samples with their reasons, events (gaps, loss of
  control, publisher gone), processing delays, CPU; turned into :class:`Report` records, one
  DiagnosticStatus each (``msg_adapters.diagnostics`` builds the message).
- End of stream: a producer announces ``state = finished`` with the number of messages it
  published per topic (:func:`end_of_stream_values`); a consumer flushes once it has seen
  that many (:class:`EndOfStream`). Topics are independent DDS writers, so the announcement
  may overtake the last data messages: counting, not ordering, decides.
- :func:`parse_wait_for`: ``'TOPIC=N'`` entries of the ``wait_for`` parameter.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
import math
import time

import numpy as np

OK, WARN, ERROR, STALE = 0, 1, 2, 3
NS_PER_S = 1_000_000_000

#: DiagnosticStatus names end with these suffixes (``<node>: <part>``).
STREAM_PART = 'stream'
FINISHED = 'finished'
COUNT_PREFIX = 'count.'
FIRST_PREFIX = 'first_stamp.'


# --------------------------------------------------------------------------- records

@dataclass(frozen=True)
class Report:
    """One status entry: level (0..3), name, message, key/values (ROS-free StatusRecord)."""

    level: int
    name: str
    message: str = ''
    values: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Sample:
    """One accepted (or interpolated) sample of a stream."""

    stamp_ns: int
    values: np.ndarray
    interpolated: bool = False


@dataclass(frozen=True)
class GateResult:
    """What :meth:`StreamGate.offer` decided about one incoming sample."""

    samples: tuple[Sample, ...] = ()    # to feed, in order (interpolated ones first)
    rejected: str | None = None         # reason, when the sample is dropped
    gap: str | None = None              # description of a filled gap
    restart: str | None = None          # reason to end the trial before feeding ``samples``


# --------------------------------------------------------------------------- gates

class StreamGate:
    """Arrival checks of one periodic stream (stamps in int ns).

    ``period_s``: nominal sample period. A sample whose stamp is not after the previous
    accepted one is rejected (duplicate or out of order); stamps before ``not_before_ns``
    are rejected. A spacing above ``gap_factor`` periods is a gap: up to ``max_gap_s`` it is
    filled with samples linearly interpolated at the nominal period; longer gaps ask the
    caller to end the trial (``restart``) and start a new one with this sample.
    """

    def __init__(self, name: str, period_s: float, gap_factor: float = 1.5,
                 max_gap_s: float = 0.5) -> None:
        if not period_s > 0:
            raise ValueError(f'{name}: period must be > 0 s, got {period_s!r}')
        if not gap_factor > 1:
            raise ValueError(f'{name}: gap_factor must be > 1, got {gap_factor!r}')
        self.name = name
        self.period_ns = int(round(period_s * NS_PER_S))
        self.gap_factor = float(gap_factor)
        self.max_gap_ns = int(round(max_gap_s * NS_PER_S))
        self.not_before_ns: int | None = None
        self.last: Sample | None = None

    def reset(self) -> None:
        self.last = None
        self.not_before_ns = None

    def offer(self, stamp_ns: int, values: np.ndarray) -> GateResult:
        """Decide about one sample (already validated for shape and finiteness)."""
        stamp_ns = int(stamp_ns)
        values = np.asarray(values, dtype=float)
        if self.not_before_ns is not None and stamp_ns < self.not_before_ns:
            return GateResult(rejected=(
                f'{self.name}: stamp {fmt_stamp(stamp_ns)} is before the trial start '
                f'{fmt_stamp(self.not_before_ns)}'))
        last = self.last
        if last is None:
            self.last = Sample(stamp_ns, values)
            return GateResult(samples=(self.last,))
        dt = stamp_ns - last.stamp_ns
        if dt == 0:
            return GateResult(rejected=f'{self.name}: duplicate stamp {fmt_stamp(stamp_ns)}')
        if dt < 0:
            return GateResult(rejected=(
                f'{self.name}: out-of-order stamp {fmt_stamp(stamp_ns)}, '
                f'{-dt / 1e6:.3f} ms before the previous sample'))
        if dt > self.max_gap_ns:
            self.last = Sample(stamp_ns, values)
            return GateResult(samples=(self.last,), restart=(
                f'{self.name}: gap of {dt / 1e6:.1f} ms exceeds max_gap_s = '
                f'{self.max_gap_ns / 1e9:g} s; the trial ends and a new one starts'))
        filled: list[Sample] = []
        gap = None
        if dt > self.gap_factor * self.period_ns:
            n_missing = int(round(dt / self.period_ns)) - 1
            for k in range(1, n_missing + 1):
                s = last.stamp_ns + k * self.period_ns
                if s >= stamp_ns - self.period_ns // 2:
                    break
                w = (s - last.stamp_ns) / dt
                filled.append(Sample(s, (1 - w) * last.values + w * values, True))
            gap = (f'{self.name}: gap of {dt / 1e6:.1f} ms after {fmt_stamp(last.stamp_ns)}; '
                   f'filled with {len(filled)} interpolated samples')
        self.last = Sample(stamp_ns, values)
        return GateResult(samples=(*filled, self.last), gap=gap)


class TrialClock:
    """Trial time from header stamps; the epoch is a parameter or the first stamp seen."""

    def __init__(self, epoch_ns: int = 0) -> None:
        self.fixed = int(epoch_ns) if epoch_ns else None
        self.epoch_ns: int | None = self.fixed

    def reset(self) -> None:
        self.epoch_ns = self.fixed

    def start(self, stamp_ns: int) -> int:
        """Fix the epoch at ``stamp_ns`` unless already set; returns the epoch."""
        if self.epoch_ns is None:
            self.epoch_ns = int(stamp_ns)
        return self.epoch_ns

    def t(self, stamp_ns: int) -> float:
        return (int(stamp_ns) - self.epoch_ns) * 1e-9

    def stamps(self, t: np.ndarray) -> np.ndarray:
        """Trial times [s] -> header stamps int64 [ns] (rounded to the nanosecond)."""
        return self.epoch_ns + np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def fmt_stamp(stamp_ns: int) -> str:
    sec, nsec = divmod(int(stamp_ns), NS_PER_S)
    return f'{sec}.{nsec:09d}'


# --------------------------------------------------------------------------- wait spec

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


# --------------------------------------------------------------------------- end of stream

def end_of_stream_values(counts: Mapping[str, int],
                         first_stamps: Mapping[str, int] | None = None,
                         **extra: object) -> dict[str, object]:
    """Key/values announcing that the producer published ``counts[topic]`` messages, the
    first of them stamped ``first_stamps[topic]`` (which identifies the trial)."""
    values: dict[str, object] = {'state': FINISHED}
    values.update({COUNT_PREFIX + topic: int(n) for topic, n in counts.items()})
    values.update({FIRST_PREFIX + topic: int(n) for topic, n in (first_stamps or {}).items()})
    values.update(extra)
    return values


def parse_end_of_stream(values: Mapping[str, str],
                        ) -> dict[str, tuple[int, int | None]] | None:
    """topic -> (count, first stamp or None) from a status record's values (None if not an
    end-of-stream record)."""
    if values.get('state') != FINISHED:
        return None
    out = {}
    for key, value in values.items():
        if not key.startswith(COUNT_PREFIX):
            continue
        topic = key[len(COUNT_PREFIX):]
        try:
            first = values.get(FIRST_PREFIX + topic)
            out[topic] = (int(value), None if first is None else int(first))
        except (TypeError, ValueError):
            continue
    return out


class EndOfStream:
    """Has a consumer seen everything its producers announced (for the current trial)?

    An announcement names, per topic, how many messages were published and the stamp of the
    first one. Only announcements whose first stamp matches the first message the consumer
    received on that topic count, so a stale announcement (an earlier trial, delivered late
    or replayed from a transient-local history) never ends the current trial.
    """

    def __init__(self, topics: Iterable[str]) -> None:
        self.topics = tuple(topics)
        self.announced: dict[str, tuple[int, int | None, float]] = {}

    def reset(self) -> None:
        self.announced = {}

    def announce(self, counts: Mapping[str, tuple[int, int | None]], now: float) -> bool:
        """Record an announcement; True if it concerns one of our topics."""
        mine = {t: v for t, v in counts.items() if t in self.topics}
        for topic, (n, first) in mine.items():
            self.announced[topic] = (n, first, now)
        return bool(mine)

    def _valid(self, first_seen: Mapping[str, int]) -> dict[str, tuple[int, float]]:
        out = {}
        for topic, (n, first, at) in self.announced.items():
            if first is not None and topic in first_seen and first_seen[topic] != first:
                continue  # another trial
            if first is not None and topic not in first_seen:
                continue  # nothing of that trial received yet
            out[topic] = (n, at)
        return out

    def announced_at(self, first_seen: Mapping[str, int]) -> float | None:
        valid = self._valid(first_seen)
        return min((at for _, at in valid.values()), default=None)

    def complete(self, seen: Mapping[str, int], first_seen: Mapping[str, int]) -> bool:
        """Every validly announced topic seen in full (and at least one announced)."""
        valid = self._valid(first_seen)
        return bool(valid) and all(seen.get(t, 0) >= n for t, (n, _) in valid.items())

    def missing(self, seen: Mapping[str, int], first_seen: Mapping[str, int]) -> dict[str, int]:
        return {t: n - seen.get(t, 0) for t, (n, _) in self._valid(first_seen).items()
                if seen.get(t, 0) < n}


class TrialBook:
    """Per-trial book-keeping of a tracker for the end-of-stream protocol.

    Inputs seen (every message received, accepted or not, with the stamp of the first),
    outputs published (count and first stamp, for our own announcement) and the producers'
    announcements. ``verdict`` says when the trial is over: every announced message received,
    or ``timeout_s`` after a valid announcement with messages still missing.
    """

    def __init__(self, inputs: Iterable[str]) -> None:
        self.end = EndOfStream(inputs)
        self.trial = 0
        self.active = False
        self.seen: dict[str, int] = {}
        self.first_seen: dict[str, int] = {}
        self.published: dict[str, int] = {}
        self.first_published: dict[str, int] = {}

    def saw(self, topic: str, stamp_ns: int) -> None:
        self.seen[topic] = self.seen.get(topic, 0) + 1
        self.first_seen.setdefault(topic, int(stamp_ns))

    def start(self) -> int:
        self.trial += 1
        self.active = True
        self.published = {}
        self.first_published = {}
        return self.trial

    def output(self, topic: str, first_stamp_ns: int, n: int) -> None:
        self.published[topic] = self.published.get(topic, 0) + int(n)
        self.first_published.setdefault(topic, int(first_stamp_ns))

    def announcement(self, values: Mapping[str, str], now: float) -> bool:
        counts = parse_end_of_stream(values)
        return bool(counts) and self.end.announce(counts, now)

    def verdict(self, now: float, timeout_s: float) -> str | None:
        """None (go on), or why the trial ends now."""
        if not self.active:
            return None
        if self.end.complete(self.seen, self.first_seen):
            return 'end of stream announced and every message received'
        at = self.end.announced_at(self.first_seen)
        if at is not None and now - at > timeout_s:
            missing = self.end.missing(self.seen, self.first_seen)
            return (f'end of stream announced but messages still missing after '
                    f'{timeout_s:g} s: {missing}')
        return None

    def finish(self) -> tuple[dict[str, int], dict[str, int]]:
        """End the trial: (published counts, first stamps) for the announcement."""
        out = (dict(self.published), dict(self.first_published))
        self.active = False
        self.seen = {}
        self.first_seen = {}
        self.end.reset()
        return out


# --------------------------------------------------------------------------- status book

def percentiles_ms(values_s: Iterable[float]) -> dict[str, float]:
    """p50/p99/max of durations [s] in ms (NaN when empty)."""
    arr = np.asarray(list(values_s), dtype=float)
    if arr.size == 0:
        return {'p50_ms': math.nan, 'p99_ms': math.nan, 'max_ms': math.nan}
    return {'p50_ms': float(np.percentile(arr, 50) * 1e3),
            'p99_ms': float(np.percentile(arr, 99) * 1e3), 'max_ms': float(arr.max() * 1e3)}


class NodeStatus:
    """What a node reports on ``/nmt/status`` (counters, reasons, events, timing)."""

    def __init__(self, node: str, *, keep_reasons: int = 8, keep_delays: int = 4096,
                 process_time: object = time.process_time,
                 monotonic: object = time.monotonic) -> None:
        self.node = node
        self.state = 'starting'
        self.detail = ''
        self.received: dict[str, int] = {}
        self.published: dict[str, int] = {}
        self.rejected: dict[str, int] = {}
        self.reasons: deque[str] = deque(maxlen=keep_reasons)
        self.events: deque[Report] = deque(maxlen=keep_reasons)
        self.interpolated = 0
        self.delays: deque[float] = deque(maxlen=keep_delays)
        self.settings: dict[str, object] = {}
        self.extra: dict[str, object] = {}
        self.error: str | None = None
        self._process_time = process_time
        self._monotonic = monotonic
        self._cpu0: float | None = None
        self._wall0: float | None = None
        self._unreported_rejections = 0

    # -- counting
    def mark_active(self) -> None:
        """Start the CPU/wall clocks of the active phase (first input)."""
        if self._cpu0 is None:
            self._cpu0 = self._process_time()
            self._wall0 = self._monotonic()

    def receive(self, topic: str, n: int = 1) -> None:
        self.received[topic] = self.received.get(topic, 0) + n

    def publish(self, topic: str, n: int = 1) -> None:
        self.published[topic] = self.published.get(topic, 0) + n

    def reject(self, topic: str, reason: str) -> None:
        self.rejected[topic] = self.rejected.get(topic, 0) + 1
        self.reasons.append(reason)
        self._unreported_rejections += 1

    def event(self, level: int, message: str, **values: object) -> None:
        self.events.append(Report(level, f'{self.node}: event', message, dict(values)))

    def delay(self, seconds: float) -> None:
        self.delays.append(float(seconds))

    @property
    def has_news(self) -> bool:
        """Rejections since the last report (worth an immediate status message)."""
        return self._unreported_rejections > 0

    # -- reporting
    def cpu(self) -> dict[str, float]:
        if self._cpu0 is None:
            return {'cpu_s_active': 0.0, 'wall_s_active': 0.0, 'cpu_share': 0.0}
        cpu = self._process_time() - self._cpu0
        wall = self._monotonic() - self._wall0
        return {'cpu_s_active': cpu, 'wall_s_active': wall,
                'cpu_share': cpu / wall if wall > 0 else 0.0}

    def reports(self) -> list[Report]:
        """The node's status entries: summary, inputs/outputs, rejections, recent events."""
        level = ERROR if self.error or self.state == 'lost_control' else OK
        if level == OK and (self.rejected or self.interpolated):
            level = WARN
        values: dict[str, object] = {'state': self.state}
        values.update({f'received.{t}': n for t, n in self.received.items()})
        values.update({f'published.{t}': n for t, n in self.published.items()})
        values.update({f'rejected.{t}': n for t, n in self.rejected.items()})
        values['rejected_total'] = sum(self.rejected.values())
        values['interpolated_samples'] = self.interpolated
        lag = percentiles_ms(self.delays)
        values.update({f'processing_delay_{k}': v for k, v in lag.items()})
        values.update(self.cpu())
        values.update(self.extra)
        values.update({f'setting.{k}': v for k, v in self.settings.items()})
        message = self.error or self.detail or self.state
        out = [Report(level, self.node, message, values)]
        if self.reasons:
            out.append(Report(WARN, f'{self.node}: rejected samples',
                              f'{sum(self.rejected.values())} rejected; last: {self.reasons[-1]}',
                              {f'reason.{i}': r for i, r in enumerate(self.reasons)}))
        out.extend(self.events)
        self._unreported_rejections = 0
        return out
