"""Observations of a routine: the paper's noise, its bias generalised to minutes, and faults.

Sampling and noise are the paper's (``observations.ObservationSettings``): segment angles at
120 Hz with SD 5, 3, 2, 1 deg (foot, shank, thigh, HAT); ground forces at 1080 Hz with SD 2 %
of body weight, the moment with 2 % BW x 0.17 m.

Default bias (the paper's "non-random noise" generalised to a routine):

* angles: a skin-motion artefact proportional to each segment's excursion from the initial
  stance posture, b_j(t) = +-sigma_j (theta_j(t) - theta_j(0)) / max_t |theta_j - theta_j(0)|:
  peak = the channel's noise SD, zero at t = 0 and whenever the posture returns;
* forces: a load-proportional (gain) error b_F(t) = eps(t) F(t), per channel (fore-aft,
  vertical), eps a smooth random function (``bias_time_scale_s``: white noise low-passed at
  1 / (2 pi tau), forward-backward) scaled so that max_t |b_F| = 2 % BW: zero in flight
  (F = 0 there, as the paper's "no bias at lift-off");
* moment: a centre-of-pressure offset d(t) (smooth random like eps), M_bias = d(t) F_y(t),
  scaled so that max_t |M_bias| = 20 % of the routine's peak |moment|.

Faults (``faults=True``; seeded separately, so a routine with faults has the same noise and
bias as without):

* marker occlusions: ``occlusions_per_min`` gaps of 50-300 ms, each on one segment: the mocap
  keeps publishing frames at 120 Hz with NaN for the occluded segment (as Vicon or Qualisys
  stream a lost segment);
* isolated NaN samples: whole frames of either stream (``nan_frames_per_min`` each);
* force-plate offset drift: an additive random walk (Brownian, low-passed at 1 Hz) per channel
  reaching ``drift_peak_bw`` of BW (moment: x 0.17 m) at its largest over the routine, present
  in flight too;
* spikes: ``spikes_per_min`` single-sample spikes in each stream (force: 20-50 % BW on one
  channel; angle: 10-30 deg on one segment).

Every component is returned (and written to the bag): observations = truth + bias + faults +
noise exactly, NaN where a dropout or occlusion removed the sample.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from nmt_ros.records import Observations, Truth
from nmt_ros.study.observations import ObservationSettings

#: Codes of the dropout masks (``components['angle_dropout']``, ``['wrench_dropout']``).
DROPOUT_NONE, DROPOUT_OCCLUSION, DROPOUT_NAN = 0, 1, 2


@dataclass(frozen=True)
class RoutineObservationSettings:
    """Noise (the paper's), the routine's default bias and the optional faults."""

    base: ObservationSettings = ObservationSettings()
    bias_time_scale_s: float = 3.0        # eps(t), d(t): time scale (2-5 s)
    faults: bool = False
    occlusions_per_min: float = 6.0
    occlusion_s: tuple[float, float] = (0.05, 0.30)
    nan_frames_per_min: float = 4.0
    drift_peak_bw: float = 0.03
    drift_cutoff_hz: float = 1.0
    spikes_per_min: float = 3.0
    force_spike_bw: tuple[float, float] = (0.2, 0.5)
    angle_spike_deg: tuple[float, float] = (10.0, 30.0)
    seed: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


def smooth_random(t: np.ndarray, time_scale_s: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth zero-mean random function at times t [s] with correlation time ~time_scale_s:
    white noise on a 20 Hz grid, low-passed at 1 / (2 pi time_scale_s) (Butterworth order 2,
    forward-backward), linearly interpolated; unit SD."""
    fs = 20.0
    pad = 5.0 * time_scale_s
    tg = np.arange(t[0] - pad, t[-1] + pad + 1.0 / fs, 1.0 / fs)
    sos = butter(2, 1.0 / (2 * np.pi * time_scale_s), fs=fs, output='sos')
    v = sosfiltfilt(sos, rng.normal(size=tg.size))
    v = np.interp(t, tg, v)
    return v / v.std()


def make_routine_observations(truth: Truth, settings: RoutineObservationSettings,
                              body_weight: float) -> tuple[Observations, dict]:
    """Observations of a routine's truth and every component that made them.

    Returns (observations, components): 'angle_bias' [n_a, 4], 'angle_noise',
    'wrench_bias' [n_w, 3] (smooth bias + drift + spikes: all that is not noise),
    'wrench_noise', and with faults 'wrench_drift', 'wrench_spikes', 'angle_spikes',
    'angle_dropout' [n_a, 4] and 'wrench_dropout' [n_w] (codes ``DROPOUT_*``), plus the
    sample indices into the truth ('angle_index', 'wrench_index') and the SDs.
    """
    st = settings
    base = st.base
    seq = np.random.SeedSequence(st.seed)
    rng, rng_faults = (np.random.default_rng(s) for s in seq.spawn(2))
    t_end = float(truth.t[-1])
    t_w = np.arange(0, int(np.floor(t_end * base.wrench_rate_hz + 1e-9)) + 1) \
        / base.wrench_rate_hz
    t_a = np.arange(0, int(np.floor(t_end * base.angle_rate_hz + 1e-9)) + 1) \
        / base.angle_rate_hz
    idx_w = np.rint(np.interp(t_w, truth.t, np.arange(truth.t.size))).astype(int)
    idx_a = np.rint(np.interp(t_a, truth.t, np.arange(truth.t.size))).astype(int)
    if (np.abs(truth.t[idx_w] - t_w).max() > 1e-9 or np.abs(truth.t[idx_a] - t_a).max() > 1e-9):
        raise ValueError('the truth grid must contain the 120 Hz and 1080 Hz sample instants')
    angle_sd = np.radians(base.angle_noise_deg) * base.noise_scale
    wrench_sd = np.array([base.force_noise_bw, base.force_noise_bw,
                          base.force_noise_bw * base.moment_lever_m]) * body_weight \
        * base.noise_scale
    theta = truth.q[idx_a, :4]
    s = truth.s[idx_w]

    # bias: skin motion (angles), gain (forces), centre-of-pressure offset (moment)
    excursion = theta - truth.q[0, :4]
    angle_bias = np.column_stack([
        angle_sd[j] * rng.choice([-1.0, 1.0]) * excursion[:, j] / np.abs(excursion[:, j]).max()
        for j in range(4)])
    wrench_bias = np.zeros((t_w.size, 3))
    for j in range(2):
        raw = smooth_random(t_w, st.bias_time_scale_s, rng) * s[:, j]
        wrench_bias[:, j] = wrench_sd[j] * raw / np.abs(raw).max()
    raw = smooth_random(t_w, st.bias_time_scale_s, rng) * s[:, 1]
    moment_peak = float(np.abs(truth.s[:, 2]).max())
    wrench_bias[:, 2] = base.moment_bias_fraction * moment_peak * base.noise_scale \
        * raw / np.abs(raw).max()
    angle_noise = rng.normal(size=(t_a.size, 4)) * angle_sd
    wrench_noise = rng.normal(size=(t_w.size, 3)) * wrench_sd
    components = {'angle_bias': angle_bias, 'angle_noise': angle_noise,
                  'wrench_bias': wrench_bias.copy(), 'wrench_noise': wrench_noise,
                  'angle_sd': angle_sd, 'wrench_sd': wrench_sd,
                  'angle_index': idx_a, 'wrench_index': idx_w,
                  'smooth_wrench_bias': wrench_bias.copy(),
                  'smooth_angle_bias': angle_bias.copy()}
    angles = theta + angle_bias + angle_noise
    wrench = s + wrench_bias + wrench_noise
    info = {'settings': st.as_dict(), 'angle_sd_rad': angle_sd.tolist(),
            'wrench_sd': wrench_sd.tolist(),
            'force_bias_peak_n': float(wrench_sd[0]),
            'moment_bias_peak_nm': float(np.abs(wrench_bias[:, 2]).max())}
    if st.faults:
        faults = _faults(t_a, t_w, body_weight, st, rng_faults)
        angles = angles + faults['angle_spikes']
        wrench = wrench + faults['wrench_drift'] + faults['wrench_spikes']
        components['wrench_bias'] = (wrench_bias + faults['wrench_drift']
                                     + faults['wrench_spikes'])
        components['angle_bias'] = angle_bias + faults['angle_spikes']
        angles[faults['angle_dropout'] != DROPOUT_NONE] = np.nan
        wrench[faults['wrench_dropout'] != DROPOUT_NONE] = np.nan
        components.update(faults)
        info['faults'] = faults['facts']
    obs = Observations(t_angles=t_a, angles=angles, t_wrench=t_w, wrench=wrench, info=info)
    return obs, components


def _events(rng: np.random.Generator, rate_per_min: float, t_end: float) -> int:
    """How many events of a Poisson process of the given rate fall in [0, t_end] s."""
    return int(rng.poisson(rate_per_min * t_end / 60.0))


def _faults(t_a: np.ndarray, t_w: np.ndarray, body_weight: float,
            st: RoutineObservationSettings, rng: np.random.Generator) -> dict:
    """Occlusions, NaN frames, drift and spikes (module docstring)."""
    t_end = float(t_w[-1])
    n_a, n_w = t_a.size, t_w.size
    angle_dropout = np.zeros((n_a, 4), dtype=np.int8)
    wrench_dropout = np.zeros(n_w, dtype=np.int8)
    occlusions = []
    for _ in range(_events(rng, st.occlusions_per_min, t_end)):
        seg = int(rng.integers(4))
        length = float(rng.uniform(*st.occlusion_s))
        start = float(rng.uniform(0.5, t_end - length))
        sel = (t_a >= start) & (t_a < start + length)
        angle_dropout[sel, seg] = DROPOUT_OCCLUSION
        occlusions.append({'segment': seg, 'start_s': start, 'duration_s': length})
    nan_a = rng.integers(1, n_a, _events(rng, st.nan_frames_per_min, t_end))
    angle_dropout[nan_a, :] = np.where(angle_dropout[nan_a, :] == DROPOUT_NONE, DROPOUT_NAN,
                                       angle_dropout[nan_a, :])
    nan_w = rng.integers(1, n_w, _events(rng, st.nan_frames_per_min, t_end))
    wrench_dropout[nan_w] = DROPOUT_NAN
    # drift: Brownian per channel, low-passed, scaled to its peak
    lever = np.array([1.0, 1.0, st.base.moment_lever_m])
    walk = np.cumsum(rng.normal(size=(n_w, 3)), axis=0)
    sos = butter(2, st.drift_cutoff_hz, fs=1.0 / (t_w[1] - t_w[0]), output='sos')
    walk = sosfiltfilt(sos, walk, axis=0)
    walk -= walk[0]
    drift = st.drift_peak_bw * body_weight * lever * walk / np.abs(walk).max(axis=0)
    # spikes
    wrench_spikes = np.zeros((n_w, 3))
    spikes_w = []
    for _ in range(_events(rng, st.spikes_per_min, t_end)):
        k, ch = int(rng.integers(1, n_w)), int(rng.integers(3))
        amp = float(rng.uniform(*st.force_spike_bw) * body_weight * lever[ch]
                    * rng.choice([-1.0, 1.0]))
        wrench_spikes[k, ch] += amp
        spikes_w.append({'t_s': float(t_w[k]), 'channel': ch, 'size': amp})
    angle_spikes = np.zeros((n_a, 4))
    spikes_a = []
    for _ in range(_events(rng, st.spikes_per_min, t_end)):
        k, seg = int(rng.integers(1, n_a)), int(rng.integers(4))
        amp = float(np.radians(rng.uniform(*st.angle_spike_deg)) * rng.choice([-1.0, 1.0]))
        angle_spikes[k, seg] += amp
        spikes_a.append({'t_s': float(t_a[k]), 'segment': seg, 'size_rad': amp})
    facts = {'occlusions': occlusions, 'angle_nan_frames_s': sorted(t_a[nan_a].tolist()),
             'wrench_nan_frames_s': sorted(t_w[nan_w].tolist()),
             'drift_peak_n': (np.abs(drift).max(axis=0)).tolist(),
             'force_spikes': spikes_w, 'angle_spikes': spikes_a}
    return {'angle_dropout': angle_dropout, 'wrench_dropout': wrench_dropout,
            'wrench_drift': drift, 'wrench_spikes': wrench_spikes,
            'angle_spikes': angle_spikes, 'facts': facts}
