"""Replay timing, without ROS: when is each recorded message due on the wall clock?

A recorded message at bag time ``t`` is due at wall time ``wall0 + (t - t0) / rate``, where
``t0`` is the first message's bag time and ``wall0`` the (monotonic) wall time playback
started. Like ``ros2 bag play --clock HZ``, clock ticks can be interleaved at a fixed
*wall* rate; a tick carries the bag time reached at that instant,
``t0 + (wall - wall0) * rate``. Late events are emitted at once (never dropped) and report
how late they were, so a slow consumer shows up in ``ReplayEvent.late_ns``.

:class:`ReplayScheduler` is a generator driver: iterate :meth:`ReplayScheduler.run` and
publish each event. ``now_ns`` and ``sleep`` are injected, so tests run on a fake clock and a
ROS node can reuse it unchanged (``nmt_ros.nodes.bag_player``; the observation publisher).
"""
from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
import math
import operator
import os
import threading
import time
from typing import Any

MESSAGE = 'message'
CLOCK = 'clock'


@dataclass(frozen=True)
class ReplayEvent:
    """One due event: a recorded item (``kind='message'``) or a clock tick."""

    kind: str
    bag_time_ns: int
    item: Any = None
    late_ns: int = 0


class Lateness:
    """Distribution of how late events were sent [ns], in bounded memory (for hours of
    replay): a histogram with bins 2 % wide from 1 us to 100 s (exact count, sum and max;
    percentiles to within a bin's width)."""

    EDGES_NS = tuple(int(1000 * 1.02 ** i) for i in range(931))  # 1 us .. ~100 s

    def __init__(self) -> None:
        self.counts = [0] * (len(self.EDGES_NS) + 1)
        self.n = 0
        self.max_ns = 0
        self.sum_ns = 0

    def add(self, late_ns: int) -> None:
        late_ns = max(0, int(late_ns))
        self.counts[bisect.bisect_right(self.EDGES_NS, late_ns)] += 1
        self.n += 1
        self.sum_ns += late_ns
        self.max_ns = max(self.max_ns, late_ns)

    def percentile_ns(self, q: float) -> float:
        """The ``q``-th percentile (0..100) [ns]: upper edge of the bin holding it (NaN
        when empty)."""
        if self.n == 0:
            return math.nan
        rank = q / 100.0 * self.n
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if c and seen >= rank:
                return float(self.EDGES_NS[i]) if i < len(self.EDGES_NS) else float(self.max_ns)
        return float(self.max_ns)

    def summary_ms(self) -> dict[str, float]:
        """n, mean, p50, p99, max [ms]."""
        return {'n': self.n, 'mean_ms': self.sum_ns / self.n / 1e6 if self.n else math.nan,
                'p50_ms': self.percentile_ns(50) / 1e6, 'p99_ms': self.percentile_ns(99) / 1e6,
                'max_ms': self.max_ns / 1e6}


class ReplayScheduler:
    """Paces items by their bag time at ``rate`` x real time, optionally with clock ticks.

    ``time_of(item)`` gives an item's bag time in ns (default: ``item.log_time_ns``). ``stop``
    (a callable returning True, or an object with ``is_set()`` such as ``threading.Event``)
    ends the run between events and during waits (checked at least every ``poll_s``).
    """

    def __init__(self, rate: float = 1.0, *, clock_hz: float | None = None,
                 now_ns: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep,
                 start_delay_s: float = 0.0, poll_s: float = 0.05) -> None:
        if not rate > 0:
            raise ValueError(f'rate must be > 0, got {rate!r}')
        if clock_hz is not None and not clock_hz > 0:
            raise ValueError(f'clock rate must be > 0 Hz, got {clock_hz!r}')
        self.rate = float(rate)
        self.clock_period_ns = None if clock_hz is None else int(round(1e9 / clock_hz))
        self._now = now_ns
        self._sleep = sleep
        self._delay_ns = int(round(start_delay_s * 1e9))
        self._poll_ns = int(poll_s * 1e9)
        self.t0_ns: int | None = None
        self.wall0_ns: int | None = None

    def bag_to_wall(self, bag_time_ns: int) -> int:
        """Wall (monotonic) time at which bag time ``bag_time_ns`` is due."""
        return self.wall0_ns + int(round((bag_time_ns - self.t0_ns) / self.rate))

    def wall_to_bag(self, wall_ns: int) -> int:
        """Bag time reached at wall time ``wall_ns``."""
        return self.t0_ns + int(round((wall_ns - self.wall0_ns) * self.rate))

    def _wait_until(self, deadline_ns: int, stopped: Callable[[], bool]) -> bool:
        """Sleep until ``deadline_ns``; False if stopped first."""
        while True:
            if stopped():
                return False
            remaining = deadline_ns - self._now()
            if remaining <= 0:
                return True
            self._sleep(min(remaining, self._poll_ns) * 1e-9)

    def run(self, items: Iterable[Any],
            time_of: Callable[[Any], int] = operator.attrgetter('log_time_ns'),
            stop: Any = None) -> Iterator[ReplayEvent]:
        """Yield each item (and clock tick) when it is due."""
        if stop is None:
            def stopped() -> bool:
                return False
        elif hasattr(stop, 'is_set'):
            stopped = stop.is_set
        else:
            stopped = stop
        iterator = iter(items)
        pending = next(iterator, None)
        if pending is None:
            return
        self.t0_ns = int(time_of(pending))
        self.wall0_ns = self._now() + self._delay_ns
        next_tick = self.wall0_ns if self.clock_period_ns else None
        while pending is not None:
            t = int(time_of(pending))
            deadline = self.bag_to_wall(t)
            while next_tick is not None and next_tick <= deadline:
                if not self._wait_until(next_tick, stopped):
                    return
                yield ReplayEvent(CLOCK, self.wall_to_bag(next_tick), None,
                                  self._now() - next_tick)
                next_tick += self.clock_period_ns
            if not self._wait_until(deadline, stopped):
                return
            yield ReplayEvent(MESSAGE, t, pending, self._now() - deadline)
            pending = next(iterator, None)


class ReadAhead:
    """``items``, read ahead on a thread into a bounded queue (``max_batches`` lists of
    ``batch`` items); the reading starts when this is made, so a replay can fill the queue
    while it waits for its subscribers.

    Reading a bag is bursty: the MCAP reader decompresses and decodes a whole chunk (thousands
    of messages, tens of ms) when it reaches it, which stalled a paced replay by up to 155 ms
    here. Read ahead, the pacing loop only waits on its own schedule. Filled before the replay
    begins, the first chunks' decoding (0.4 s of CPU each on ``bags/routine``'s ~10,000
    messages per chunk) no longer competes with the trackers' cold start on a 2-core machine;
    ``reader_nice`` (Linux: per thread) lowers the reader thread's priority for the chunks
    read during the replay. An exception of the reader is raised where the item it would have
    produced is consumed. ``close()`` (or closing the iterator) stops the reader.
    """

    def __init__(self, items: Iterable[Any], *, batch: int = 256, max_batches: int = 64,
                 reader_nice: int = 0) -> None:
        self._queue: deque[list[Any] | BaseException | None] = deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read,
                                        args=(items, batch, max_batches, reader_nice),
                                        name='replay_reader', daemon=True)
        self._thread.start()

    def _read(self, items: Iterable[Any], batch: int, max_batches: int, nice: int) -> None:
        queue, cond, stop = self._queue, self._cond, self._stop
        if nice:
            try:      # Linux applies a thread id's priority to that thread alone
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
            except (AttributeError, OSError):
                pass
        chunk: list[Any] = []
        try:
            for item in items:
                chunk.append(item)
                if len(chunk) >= batch:
                    with cond:
                        while len(queue) >= max_batches and not stop.is_set():
                            cond.wait(0.1)
                        if stop.is_set():
                            return
                        queue.append(chunk)
                        cond.notify_all()
                    chunk = []
            end: list[Any] | BaseException | None = None
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            end = exc
        with cond:
            if chunk:
                queue.append(chunk)
            queue.append(end)
            cond.notify_all()

    def __iter__(self) -> Iterator[Any]:
        queue, cond = self._queue, self._cond
        try:
            while True:
                with cond:
                    while not queue:
                        cond.wait(0.1)
                    got = queue.popleft()
                    cond.notify_all()
                if got is None:
                    return
                if isinstance(got, BaseException):
                    raise got
                yield from got
        finally:
            self.close()

    def close(self) -> None:
        """Stop the reader (what it read and nobody took is dropped)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
