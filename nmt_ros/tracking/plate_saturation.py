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
phases and the repeats of a coarsely quantised quiet stance.
"""
from __future__ import annotations

import numpy as np

CHANNELS = ('Fx', 'Fy', 'Mz')          # the planar plate sample's channels [N, N, N m]


class PlateSaturation:
    """Causal detector of clipped channels in a stream of plate samples."""

    def __init__(self, min_level: np.ndarray) -> None:
        """``min_level`` [per channel, the channel's unit]: readings below it in magnitude
        are never taken for saturation (``inf``: the channel is not checked)."""
        self.min_level = np.asarray(min_level, dtype=float)
        self.previous: np.ndarray | None = None
        self.levels: list[set[float]] = [set() for _ in self.min_level]
        self.saturated = np.zeros(self.min_level.size, dtype=np.int64)  # samples per channel
        self.runs = 0                  # runs of saturated samples begun (any channel)
        self.in_run = False
        self._none = np.zeros(self.min_level.size, dtype=bool)
        self._none.flags.writeable = False

    def check(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """(saturated channels of ``y`` [bool per channel], channels of the previous sample
        found saturated only now [bool per channel], whether a run begins here)."""
        y = np.asarray(y, dtype=float)
        high = np.abs(y) >= self.min_level          # False for NaN
        if not high.any():                          # the common case, cheaply
            self.previous = y
            self.in_run = False
            return self._none, self._none, False
        now = np.zeros(y.size, dtype=bool)
        before = np.zeros(y.size, dtype=bool)
        for c in np.flatnonzero(high):
            v = float(y[c])
            if v in self.levels[c]:
                now[c] = True
            elif self.previous is not None and v == self.previous[c]:
                now[c] = before[c] = True
                self.levels[c].add(v)
        self.previous = y
        self.saturated += now + before
        begins = bool(now.any()) and not self.in_run
        self.in_run = bool(now.any())
        self.runs += begins
        return now, before, begins
