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

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
import operator
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
