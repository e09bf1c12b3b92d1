"""A camera's frame clock recovered from jittered stamps.

A motion-capture system samples on its own frame clock, at a fixed period, but a driver that
stamps each frame on arrival (rather than with the camera's frame time) adds the transport's
jitter to every stamp. The estimator treats a stamp as the instant the angles were measured,
so +-2 ms of jitter at 120 Hz moves landing samples by a fifth of a frame (measured: the
routine's landing torques 4 points of peak worse, ``bench/bench_unseen_faults.py``).

``FrameClock`` is an alpha-beta tracker of the frame instants: each stamp is assigned to the
frame nearest the clock's prediction (``n >= 1`` periods after the previous frame, so missing
frames are counted), and the prediction moves a fraction ``alpha`` of the way to the stamp
(the period by ``beta``), which averages the jitter over ~``2 / alpha`` frames; a fresh
clock takes the mean of its first residuals instead (its least-squares phase). A stamp
that sits on the predicted instant (uniform stamps, every recording written by a lab's
software) is returned unchanged, bit for bit. A run of ``RESYNC_AFTER`` stamps more than
``resync_fraction`` of a period from their frames (a clock reset) restarts the clock at the
stamp; a lone one (heavy jitter) is taken at its predicted instant. Jitter too large to
tell frames apart (``MAX_JITTER_FRACTION``) leaves the stamps as they are.

Causal and a function of the stamps alone: streaming and batch give the same instants.
"""
from __future__ import annotations

import math

#: consecutive stamps more than ``resync_fraction`` of a period from their frames that
#: restart the clock (fewer are jitter: +-4 ms at 120 Hz passes the bound in 10 % of frames)
RESYNC_AFTER = 4
#: jitter RMS (x the period) above which frames cannot be told apart by the clock (+-0.43
#: periods uniform; measured at 120 Hz: +-3 ms RMS error 1.75 -> 0.25 ms on the clock,
#: +-4 ms 2.3 -> 1.3 but up to a frame off, +-5 ms worse than the stamps)
MAX_JITTER_FRACTION = 0.25


class FrameClock:
    """Frame instants [s] from stamps [s] of a stream sampled at ``period_s``."""

    def __init__(self, period_s: float, alpha: float = 0.03, beta: float | None = None,
                 exact_tol_s: float = 1e-7, resync_fraction: float = 0.45) -> None:
        """``alpha``: the fraction of a stamp's residual the frame instant takes (smaller:
        more smoothing, slower to follow a drifting clock); ``beta``: the fraction per frame
        the period takes (default ``alpha**2 / 4``, the critically damped alpha-beta
        tracker); ``exact_tol_s`` [s]: a residual within it is no jitter (the stamp
        is returned as it is); ``resync_fraction``: a residual beyond it (x period) restarts
        the clock at the stamp."""
        if not (period_s > 0 and math.isfinite(period_s)):
            raise ValueError(f'frame period must be positive and finite, got {period_s!r} s')
        beta = alpha ** 2 / 4 if beta is None else beta
        if not (0 < alpha <= 1 and 0 <= beta < alpha):
            raise ValueError(f'need 0 < alpha <= 1 and 0 <= beta < alpha, got {alpha}, {beta}')
        self.nominal_s = float(period_s)
        self.period_s = float(period_s)
        self.alpha = alpha
        self.beta = beta
        self.exact_tol_s = exact_tol_s
        self.resync_fraction = resync_fraction
        self.last: float | None = None      # the previous frame's instant [s]
        self.frames = 0                     # stamps seen
        self.since_sync = 0                 # stamps regularised since the clock (re)started
        self.regularised = 0                # stamps moved onto the clock
        self.resyncs = 0                    # restarts at a stamp far from its frame
        self.outliers = 0                   # consecutive stamps beyond the resync bound
        self.passed_through = 0             # stamps returned as they are (jitter too large)
        self.returned: float | None = None  # the previous instant returned [s]
        self.residual_ms2 = 0.0             # running mean of the squared residual [ms^2]

    def instant(self, stamp_s: float) -> float:
        """The frame instant [s] of a stamp [s] (stamps strictly increasing; the instants
        too). Where the jitter is too large to tell frames apart (RMS above
        ``MAX_JITTER_FRACTION`` of a period) the stamp itself."""
        on_clock = self._instant(stamp_s)
        if self.frames > 50 and self.jitter_rms_ms > 1e3 * MAX_JITTER_FRACTION * self.period_s:
            self.passed_through += 1
            out = float(stamp_s)
        else:
            out = on_clock
        if self.returned is not None and out <= self.returned:   # at a switch between the two
            out = self.returned + 1e-6
        self.returned = out
        return out

    def _instant(self, stamp_s: float) -> float:
        self.frames += 1
        if self.last is None:
            self.last = float(stamp_s)
            return self.last
        n = max(1, round((stamp_s - self.last) / self.period_s))
        predicted = self.last + n * self.period_s
        r = stamp_s - predicted
        self.residual_ms2 += (r * r * 1e6 - self.residual_ms2) / min(self.frames, 200)
        if abs(r) <= self.exact_tol_s:
            self.outliers = 0
            self.last = float(stamp_s)
            return self.last
        bound = self.resync_fraction * self.period_s
        if abs(r) > bound:
            # a stamp far from its frame: jitter beyond the bound, or the clock reset. Only
            # a run of them (a reset persists) restarts the clock at the stamp; a lone one
            # is taken at the predicted instant and does not move the clock
            self.outliers += 1
            if self.outliers >= RESYNC_AFTER and stamp_s > self.last:
                self.resyncs += 1
                self.outliers = 0
                self.since_sync = 0
                self.period_s = self.nominal_s
                self.last = float(stamp_s)
                return self.last
            self.last = predicted
            return self.last
        self.outliers = 0
        self.regularised += 1
        self.since_sync += 1
        self.period_s += self.beta * r / n
        # the mean of the residuals so far while there are fewer than 1 / alpha of them
        # (the least-squares phase of a fresh clock), then the tracker's fixed gain
        self.last = predicted + max(self.alpha, 1.0 / (self.since_sync + 1)) * r
        return self.last

    @property
    def jitter_rms_ms(self) -> float:
        """RMS of the stamps' residual from the clock over the last ~200 frames [ms]."""
        return math.sqrt(self.residual_ms2)
