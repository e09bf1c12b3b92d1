"""Force-plate channels clipped by a saturated amplifier, found as they stream.

An amplifier or converter driven past its range reads its limit: the channel repeats one
value, exactly, while the true load is beyond it. Taken as a measurement, a clipped landing
impact tells the estimator the body decelerated less than it did (measured on the routine
clipped at 2.2 BW: landing knee / hip torques 17 / 16 % of peak off against 6 / 8 %
unclipped, ``bench/bench_unseen_faults.py``). Taken as missing, the estimator bridges it
with the dynamics and the channels still measured (8 / 8 %).

A channel is saturated at a sample when its reading is at least ``min_level`` in magnitude
and equals the previous sample's exactly, or equals a level already found saturated. The
first sample of a run is only recognisable at the second: ``check`` says so, and the caller
withdraws it if it still can. Measurement noise makes exact repeats of a live load
impossible; the magnitude floor keeps out the exact zeros of a lab's thresholded flight
phases and the repeats of a coarsely quantised quiet stance, and a channel whose readings
below the floor repeat often (a signal held between samples, up-sampled by repetition) is
not checked at all (``held``).
"""
from __future__ import annotations

import numpy as np

CHANNELS = ('Fx', 'Fy', 'Mz')          # the planar plate sample's channels [N, N, N m]
#: a channel whose non-zero readings below the floor repeat exactly more often than this
#: (of at least HELD_MIN_SAMPLES; judged every HELD_EVERY) is held or coarsely quantised and
#: not checked: noise makes a repeat rare (2 % BW noise on 1 N steps: ~2 %), a signal
#: up-sampled 2x by repetition repeats half its readings
HELD_REPEAT_FRACTION = 0.2
HELD_MIN_SAMPLES = 200
HELD_EVERY = 50


class PlateSaturation:
    """Causal detector of clipped channels in a stream of plate samples."""

    def __init__(self, min_level: np.ndarray) -> None:
        """``min_level`` [per channel, the channel's unit]: readings below it in magnitude
        are never taken for saturation (``inf``: the channel is not checked)."""
        self.min_level = np.asarray(min_level, dtype=float)
        self.previous: list[float] | None = None     # the previous sample's readings
        self._floor = self.min_level.tolist()
        self.levels: list[set[float]] = [set() for _ in self.min_level]
        self.saturated = np.zeros(self.min_level.size, dtype=np.int64)  # samples per channel
        self.runs = 0                  # runs of saturated samples begun (any channel)
        self.in_run = False
        self._none = np.zeros(self.min_level.size, dtype=bool)
        self._none.flags.writeable = False
        # readings below the floor (non-zero) and how many repeat the previous one exactly: a
        # signal held between samples (up-sampled by repetition) or coarsely quantised repeats
        # at any load, so a repeat is no sign of saturation there
        self.low_count = [0] * self.min_level.size        # per channel
        self.low_repeats = [0] * self.min_level.size
        self.held = np.zeros(self.min_level.size, dtype=bool)   # channels not checked
        self._held = self.held.tolist()
        self.samples = 0
        self.newly_held: np.ndarray | None = None  # channels found held at the last check

    def check(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """(saturated channels of ``y`` [bool per channel], channels of the previous sample
        found saturated only now [bool per channel], whether a run begins here). ``y`` is
        copied: the caller may mark the saturated channels missing in its own array."""
        y = np.array(y, dtype=float)
        self.newly_held = None
        # the common case (no channel high) in Python floats and ints
        values, floor, previous = y.tolist(), self._floor, self.previous
        high = False
        for c, v in enumerate(values):
            mag = abs(v)
            if mag >= floor[c]:                     # False for NaN
                high = high or not self._held[c]
            elif previous is not None and mag > 0:
                self.low_count[c] += 1
                self.low_repeats[c] += v == previous[c]
        if previous is not None:
            self.samples += 1
            if self.samples % HELD_EVERY == 0:
                self._judge_held()
        self.previous = values
        if not high:
            self.in_run = False
            return self._none, self._none, False
        mag = np.abs(y)
        high = (mag >= self.min_level) & ~self.held
        now = np.zeros(y.size, dtype=bool)
        before = np.zeros(y.size, dtype=bool)
        for c in np.flatnonzero(high):
            v = float(y[c])
            if v in self.levels[c]:
                now[c] = True
            elif previous is not None and v == previous[c]:
                now[c] = before[c] = True
                self.levels[c].add(v)
        self.saturated += now + before
        begins = bool(now.any()) and not self.in_run
        self.in_run = bool(now.any())
        self.runs += begins
        return now, before, begins

    def _judge_held(self) -> None:
        count, repeats = np.array(self.low_count), np.array(self.low_repeats)
        held = (count >= HELD_MIN_SAMPLES) & (repeats > HELD_REPEAT_FRACTION * count)
        new = held & ~self.held
        if new.any():
            self.held |= new
            self.newly_held = new
            self._held = self.held.tolist()
