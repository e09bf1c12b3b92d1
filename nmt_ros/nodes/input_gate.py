"""What a tracker node accepts from an input stream, and the trial time of its samples.

ROS-free (tested without a ROS graph, ``test/test_node_infrastructure.py``):

- :class:`StreamGate` checks one input stream's stamps (duplicate, out of order, before the
  trial start) and spacing. Gaps longer than ``gap_factor`` periods are filled by linear
  interpolation at the nominal period (the zero-lag filters and Stage 2 need uniform
  samples) and reported; a gap longer than ``max_gap_s`` ends the trial instead.
- :class:`TrialClock`: trial time ``t = (stamp - epoch) * 1e-9`` s with the epoch fixed by a
  parameter or by the first accepted observation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NS_PER_S = 1_000_000_000


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


class StreamGate:
    """Arrival checks of one periodic stream (stamps in int ns).

    ``period_s``: nominal sample period. A sample whose stamp is not after the previous
    accepted one is rejected (duplicate or out of order); stamps before ``not_before_ns``
    are rejected. A spacing above ``gap_factor`` periods is a gap: up to ``max_gap_s`` it is
    filled with samples linearly interpolated at the nominal period (``fill_gaps``; else only
    reported, for a consumer that bridges gaps itself); longer gaps ask the caller to end the
    trial (``restart``) and start a new one with this sample.
    """

    def __init__(self, name: str, period_s: float, gap_factor: float = 1.5,
                 max_gap_s: float = 0.5, fill_gaps: bool = True) -> None:
        if not period_s > 0:
            raise ValueError(f'{name}: period must be > 0 s, got {period_s!r}')
        if not gap_factor > 1:
            raise ValueError(f'{name}: gap_factor must be > 1, got {gap_factor!r}')
        self.name = name
        self.period_ns = int(round(period_s * NS_PER_S))
        self.gap_factor = float(gap_factor)
        self.max_gap_ns = int(round(max_gap_s * NS_PER_S))
        self.fill_gaps = bool(fill_gaps)
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
        if dt > self.gap_factor * self.period_ns and not self.fill_gaps:
            gap = (f'{self.name}: gap of {dt / 1e6:.1f} ms after {fmt_stamp(last.stamp_ns)}; '
                   'not filled (bridged by the estimator)')
        elif dt > self.gap_factor * self.period_ns:
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
