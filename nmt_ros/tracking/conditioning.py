"""Observation conditioning: zero-lag low-pass filters and the derivatives the trackers need.

The paper low-pass filters the angles at 10 Hz and the ground force/moment at 50 Hz. We use a
Butterworth filter run forward and backward (zero phase) and a quintic interpolating spline
through the filtered samples for values and derivatives at any instant (angle rates and
accelerations, force rates).

Offline, the filter sees the whole recording. Live, it sees only ``lookahead_s`` of data
beyond the instant being estimated: :class:`FixedLagConditioner` runs the SAME filter on a
window that ends ``lookahead_s`` after that instant (odd extension at both ends, like
``scipy.signal.filtfilt``'s default padding), which converges to the offline result as the
look-ahead grows. The estimate for time t is final once data up to t + lookahead has arrived.

Any sample rate: a cut-off is used as given only below ``max_cutoff_fraction`` (0.4) of the
stream's Nyquist frequency; above it, it is lowered to that fraction (e.g. the paper's 50 Hz
force filter on a 100 Hz force plate runs at 20 Hz) and the change is reported
(:func:`cutoff_for_rate`, ``ConditionedObservations.notes``). A Butterworth filter with its
cut-off at Nyquist is undefined, and near it no longer attenuates what it should.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.signal import butter, filtfilt


@dataclass(frozen=True)
class ConditioningSettings:
    """Filter cut-offs [Hz] and order, and the live look-ahead [s] (None: offline)."""

    angle_cutoff_hz: float | tuple[float, ...] = 10.0   # one value or one per segment
    force_cutoff_hz: float | tuple[float, ...] = 50.0   # one value or one per channel
    order: int = 2                  # per pass (forward-backward doubles it)
    lookahead_s: float | None = None
    window_s: float = 0.5           # history kept by the live filter
    # Cut-offs above this fraction of a stream's Nyquist frequency are lowered to it.
    max_cutoff_fraction: float = 0.4


def cutoff_for_rate(cutoff_hz: float | tuple[float, ...], rate_hz: float,
                    max_fraction: float = 0.4, what: str = 'cut-off',
                    ) -> tuple[float | tuple[float, ...], str | None]:
    """The cut-off(s) [Hz] usable at ``rate_hz``: each one capped at ``max_fraction`` of the
    Nyquist frequency; and a note saying what was lowered (None if nothing)."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f'sample rate {rate_hz} Hz must be positive')
    if not 0 < max_fraction < 1:
        raise ValueError(f'max_cutoff_fraction {max_fraction} must be in (0, 1)')
    cap = max_fraction * rate_hz / 2
    given = np.atleast_1d(np.asarray(cutoff_hz, dtype=float))
    used = np.minimum(given, cap)
    if np.array_equal(used, given):
        return cutoff_hz, None
    note = (f'{what} {np.unique(given[given > cap]).tolist()} Hz lowered to {cap:g} Hz '
            f'({max_fraction:g} x the Nyquist frequency of {rate_hz:g} Hz)')
    out = float(used[0]) if np.ndim(cutoff_hz) == 0 else tuple(float(v) for v in used)
    return out, note


def lowpass_zero_lag(y: np.ndarray, rate_hz: float, cutoff_hz: float | tuple[float, ...],
                     order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass of samples y [n, k] taken at ``rate_hz``.

    Forward-backward (filtfilt) with Gustafsson's method for the initial conditions (the ends
    are not pinned to the noisy first and last samples, as odd/even padding would do).
    ``cutoff_hz`` is one value or one per column.
    """
    y = np.asarray(y, dtype=float)
    cut = np.broadcast_to(np.asarray(cutoff_hz, dtype=float), y.shape[1:] or (1,))
    out = np.empty_like(y)
    for c in np.unique(cut):
        if not 0 < c < rate_hz / 2:
            raise ValueError(f'cut-off {c} Hz must be in (0, {rate_hz / 2}) Hz')
        b, a = butter(order, c / (rate_hz / 2))
        cols = np.nonzero(cut == c)[0] if y.ndim > 1 else slice(None)
        out[..., cols] = filtfilt(b, a, y[..., cols], axis=0, method='gust')
    return out


class SmoothSignal:
    """A filtered, uniformly sampled signal with values and derivatives at any instant."""

    def __init__(self, t: np.ndarray, y: np.ndarray, rate_hz: float,
                 cutoff_hz: float | tuple[float, ...],
                 order: int = 2, degree: int = 5) -> None:
        t = np.asarray(t, dtype=float)
        if t.size < degree + 1:
            raise ValueError(f'need at least {degree + 1} samples, got {t.size}')
        if np.any(np.diff(t) <= 0):
            raise ValueError('sample times must be strictly increasing')
        self.t = t
        self.rate_hz = float(rate_hz)
        self.cutoff_hz = cutoff_hz
        self.raw = np.asarray(y, dtype=float)
        self.filtered = lowpass_zero_lag(self.raw, rate_hz, cutoff_hz, order)
        self._spline = make_interp_spline(t, self.filtered, k=degree, axis=0)
        self._d1 = self._spline.derivative(1)
        self._d2 = self._spline.derivative(2)

    def shifted(self, dt: float) -> SmoothSignal:
        """The same signal on a time axis moved by ``-dt`` [s] (what was at time dt is at 0):
        the filtered samples and their spline are kept, so a later start of the trial sees
        no filter edge there."""
        out = SmoothSignal.__new__(SmoothSignal)
        out.__dict__.update(self.__dict__)
        out.t = self.t - dt
        degree = self._spline.k
        out._spline = make_interp_spline(out.t, self.filtered, k=degree, axis=0)
        out._d1 = out._spline.derivative(1)
        out._d2 = out._spline.derivative(2)
        return out

    def __call__(self, t: np.ndarray | float, derivative: int = 0) -> np.ndarray:
        """Value (or 1st/2nd derivative) at ``t``, clamped to the sampled interval."""
        tt = np.clip(t, self.t[0], self.t[-1])
        return (self._spline, self._d1, self._d2)[derivative](tt)


@dataclass
class ConditionedObservations:
    """Filtered observations: segment angles (10 Hz) and ground wrench (50 Hz)."""

    angles: SmoothSignal   # [.., 4] rad
    wrench: SmoothSignal   # [.., 3] N, N, N m
    notes: tuple[str, ...] = ()   # what the conditioning changed (lowered cut-offs)

    def sample(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """theta, theta_dot, theta_ddot [n, 4] and s, s_dot [n, 3] at times t [n]."""
        return {'theta': self.angles(t), 'theta_dot': self.angles(t, 1),
                'theta_ddot': self.angles(t, 2), 's': self.wrench(t),
                's_dot': self.wrench(t, 1)}

    @property
    def t_end(self) -> float:
        return float(min(self.angles.t[-1], self.wrench.t[-1]))

    def shifted(self, dt: float) -> ConditionedObservations:
        """Both streams with time moved by ``-dt`` [s]: trial time 0 is the recording's dt,
        filtered over the whole recording (``SmoothSignal.shifted``)."""
        return ConditionedObservations(angles=self.angles.shifted(dt),
                                       wrench=self.wrench.shifted(dt), notes=self.notes)

    def final_until(self) -> float:
        """Offline: every instant of the recording is final."""
        return self.t_end


def sample_rate(t: np.ndarray) -> float:
    """Rate [Hz] of uniformly spaced sample times t [n] (s); ValueError if they are not."""
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size == 0:
        raise ValueError('need at least two samples')
    mean = float(dt.mean())
    if np.abs(dt - mean).max() > 0.05 * mean:
        raise ValueError('samples must be uniformly spaced (resample or fill gaps first); '
                         f'spacing ranges {dt.min():.6f}..{dt.max():.6f} s')
    return 1.0 / mean


def nominal_rate(rate_hz: float) -> float:
    """A measured sample rate [Hz] rounded to 1 mHz: header stamps are rounded to the
    nanosecond, which moves a rate measured from them by up to ~1e-7 of itself (1080 Hz
    reads 1079.99991 from one 925926 ns interval); the trackers' output grid k / rate must
    fall on the recorded instants."""
    return round(float(rate_hz), 3)


def condition(t_angles: np.ndarray, angles: np.ndarray, t_wrench: np.ndarray,
              wrench: np.ndarray, settings: ConditioningSettings = ConditioningSettings(),
              ) -> ConditionedObservations:
    """Offline (zero-lag, whole record) conditioning of both streams."""
    for name, t, x in (('angle', t_angles, angles), ('wrench', t_wrench, wrench)):
        bad = np.argwhere(~np.isfinite(np.asarray(x, dtype=float)))
        if bad.size or not np.isfinite(np.asarray(t, dtype=float)).all():
            where = (f'sample {bad[0][0]} (t = {t[bad[0][0]]:.4f} s), column {bad[0][1]}'
                     if bad.size else 'in the time stamps')
            raise ValueError(f'{name} observations must be finite: NaN or inf at {where} '
                             f'({len(bad)} values); drop or fill them first')
    return _conditioned(t_angles, angles, sample_rate(t_angles), t_wrench, wrench,
                        sample_rate(t_wrench), settings)


def _conditioned(t_angles: np.ndarray, angles: np.ndarray, angle_rate_hz: float,
                 t_wrench: np.ndarray, wrench: np.ndarray, wrench_rate_hz: float,
                 settings: ConditioningSettings) -> ConditionedObservations:
    """Both streams filtered at cut-offs valid for their rates (:func:`cutoff_for_rate`)."""
    cut_a, note_a = cutoff_for_rate(settings.angle_cutoff_hz, angle_rate_hz,
                                    settings.max_cutoff_fraction, 'angle cut-off')
    cut_w, note_w = cutoff_for_rate(settings.force_cutoff_hz, wrench_rate_hz,
                                    settings.max_cutoff_fraction, 'force cut-off')
    return ConditionedObservations(
        angles=SmoothSignal(t_angles, angles, angle_rate_hz, cut_a, settings.order),
        wrench=SmoothSignal(t_wrench, wrench, wrench_rate_hz, cut_w, settings.order),
        notes=tuple(n for n in (note_a, note_w) if n))


class FixedLagConditioner:
    """Live conditioning with a fixed look-ahead: the offline filter on a sliding window.

    Feed samples with ``add_angles``/``add_wrench``; ``final_until()`` is the latest instant
    whose estimate no longer changes (last sample time minus the look-ahead);
    ``sample(t)`` evaluates both streams at instants t <= final_until().
    """

    def __init__(self, settings: ConditioningSettings, angle_rate_hz: float = 120.0,
                 wrench_rate_hz: float = 1080.0) -> None:
        if settings.lookahead_s is None:
            raise ValueError('FixedLagConditioner needs settings.lookahead_s (seconds)')
        self.settings = settings
        self.rates = (angle_rate_hz, wrench_rate_hz)
        self._t: list[list[float]] = [[], []]
        self._y: list[list[np.ndarray]] = [[], []]
        self._cache: tuple[float, ConditionedObservations] | None = None
        self.closed = False

    def close(self) -> None:
        """End of the data: every instant up to the last sample becomes final."""
        self.closed = True

    def add_angles(self, t: float, theta: np.ndarray) -> None:
        self._add(0, t, theta)

    def add_wrench(self, t: float, s: np.ndarray) -> None:
        self._add(1, t, s)

    def _add(self, k: int, t: float, y: np.ndarray) -> None:
        if self.closed:
            raise ValueError('the conditioner was closed (end of data); start a new one')
        if self._t[k] and t <= self._t[k][-1]:
            raise ValueError(f'sample at t = {t:.6f} s is not after the previous one '
                             f'({self._t[k][-1]:.6f} s)')
        self._t[k].append(float(t))
        self._y[k].append(np.asarray(y, dtype=float))
        keep = self.settings.window_s + self.settings.lookahead_s + 0.1
        while self._t[k] and self._t[k][-1] - self._t[k][0] > keep:
            self._t[k].pop(0)
            self._y[k].pop(0)
        self._cache = None

    def final_until(self) -> float:
        """Latest instant whose estimate is final (-inf before enough data)."""
        if len(self._t[0]) < 6 or len(self._t[1]) < 6:
            return -np.inf
        last = min(self._t[0][-1], self._t[1][-1])
        return last if self.closed else last - self.settings.lookahead_s

    def _conditioned(self) -> ConditionedObservations:
        key = (self._t[0][-1], self._t[1][-1])
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, _conditioned(
                np.array(self._t[0]), np.array(self._y[0]), self.rates[0],
                np.array(self._t[1]), np.array(self._y[1]), self.rates[1], self.settings))
        return self._cache[1]

    def sample(self, t: np.ndarray) -> dict[str, np.ndarray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.max() > self.final_until() + 1e-12:
            raise ValueError(f'estimates are final only up to {self.final_until():.4f} s, '
                             f'asked for {t.max():.4f} s')
        return self._conditioned().sample(t)
