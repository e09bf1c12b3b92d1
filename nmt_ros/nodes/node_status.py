"""What a node reports on ``/nmt/status``: counters, rejected samples with their reasons,
events (gaps, loss of control, publisher gone), processing delays and CPU, as :class:`Report`
records, one DiagnosticStatus each (``msg_adapters.diagnostics`` builds the message).
ROS-free.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
import math
import time

import numpy as np

OK, WARN, ERROR, STALE = 0, 1, 2, 3   # DiagnosticStatus levels


@dataclass(frozen=True)
class Report:
    """One status entry: level (0..3), name, message, key/values (ROS-free StatusRecord)."""

    level: int
    name: str
    message: str = ''
    values: Mapping[str, object] = field(default_factory=dict)


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
