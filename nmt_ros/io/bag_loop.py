"""A long stream from a short bag: its messages repeated end to end with shifted stamps.

Soak and throughput benchmarks need streams of minutes to hours; the shipped bag holds 0.25 s.
:func:`loop_bag` writes copy ``k`` of the chosen topics with every log time, publish time and
header stamp shifted by ``k * period_ns``. The default period is the bag's span plus the
median spacing of its densest topic, so that topic (the 1080 Hz force plate) continues
without a gap or a repeated stamp across the seams; the sparser topics keep their order (the
spacing at a seam may be shorter than their period). Every message must start with a
``std_msgs/Header`` (the observation topics do). ROS-free; memory holds one copy of the
source messages.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np

from msg_adapters.cdr_header import header_stamp_ns, with_header_stamp

from .bags import BagInfo, BagWriter, bag_info, read_raw


@dataclass(frozen=True)
class LoopPlan:
    """How a bag is repeated: ``copies`` copies, each ``period_ns`` after the previous."""

    copies: int
    period_ns: int
    messages_per_copy: dict[str, int]

    def counts(self) -> dict[str, int]:
        """Messages per topic in the looped bag."""
        return {t: n * self.copies for t, n in self.messages_per_copy.items()}


def default_period_ns(log_times_ns: dict[str, np.ndarray]) -> int:
    """The source's span plus the median spacing of its densest topic [ns]."""
    first = min(int(t[0]) for t in log_times_ns.values())
    last = max(int(t[-1]) for t in log_times_ns.values())
    densest = max(log_times_ns.values(), key=lambda t: t.size)
    if densest.size < 2:
        raise ValueError('the bag needs at least two messages on one topic to be looped')
    return last - first + int(np.median(np.diff(densest)))


def loop_bag(source: str | os.PathLike, out: str | os.PathLike, duration_s: float,
             topics: Sequence[str] | None = None, *, period_ns: int | None = None,
             compression: str = 'zstd') -> tuple[BagInfo, LoopPlan]:
    """Write ``out``: ``topics`` of ``source`` (default: all) repeated to cover at least
    ``duration_s`` seconds. Returns the new bag's info and the plan."""
    if not duration_s > 0:
        raise ValueError(f'duration_s must be > 0, got {duration_s!r}')
    info = bag_info(source)
    names = [t.name for t in info.topics] if topics is None else list(topics)
    absent = sorted(set(names) - {t.name for t in info.topics})
    if absent:
        raise KeyError(f'topics not in {source}: {absent}')
    messages = list(read_raw(source, names))
    if not messages:
        raise ValueError(f'{source} has no message on {names}')
    messages.sort(key=lambda m: m.log_time_ns)
    stamps = [header_stamp_ns(m.data) for m in messages]
    log_times = {t: np.array([m.log_time_ns for m in messages if m.topic == t], np.int64)
                 for t in names}
    log_times = {t: v for t, v in log_times.items() if v.size}
    period = default_period_ns(log_times) if period_ns is None else int(period_ns)
    if period <= 0:
        raise ValueError(f'period_ns must be > 0, got {period}')
    copies = max(1, int(np.ceil(duration_s * 1e9 / period)))
    plan = LoopPlan(copies, period, {t: int(v.size) for t, v in log_times.items()})
    by_name = {t.name: t for t in info.topics}
    with BagWriter(out, compression=compression, flush_period_s=None,
                   custom_data={'looped_from': str(Path(source).resolve()),
                                'loop_copies': str(copies), 'loop_period_ns': str(period)},
                   ) as bag:
        for name in log_times:
            t = by_name[name]
            bag.add_topic(name, t.type, list(t.offered_qos) or None, type_hash=t.type_hash)
        for k in range(copies):
            shift = k * period
            for m, stamp in zip(messages, stamps):
                bag.write(m.topic, with_header_stamp(m.data, stamp + shift),
                          m.log_time_ns + shift, m.publish_time_ns + shift)
    return bag_info(out), plan
