"""Noisy, biased "measurements" made from the actual performance (METHOD.md section 1.3).

* Segment angles sampled at 120 Hz, ground force and moment at 1080 Hz (samples of the truth
  at those instants; the truth is computed on the 1080 Hz grid, so 120 Hz is every 9th).
* Gaussian noise, SD 5, 3, 2, 1 deg for foot, shank, thigh, HAT; 2 % of body weight for the
  fore-aft and vertical forces; the moment's SD is 2 % of body weight times the foot's
  heel-to-toe length (0.17 m). These numbers are the observation specification,
  ``nmt_ros.tracking.observation_noise`` (why the moment's SD is what it is: there).
* Smooth bias ("non-random noise": skin motion, offsets) with a peak magnitude equal to the
  channel's noise SD and a random sign per channel. Two shapes (``bias_shape``):
  'motion' (default): skin-motion artefact, which follows the segment's own excursion,
      b(t) = +-sigma (theta(t) - theta(0)) / max|theta - theta(0)|   (zero at t = 0);
      force-plate offsets drift as one smooth lobe over the contact phase,
      b(t) = +-sigma sin(pi t / t_lo) for t <= t_lo, 0 after (zero at 0 and at lift-off);
  'harmonic': a random mix of ``bias_harmonics`` low harmonics (zero at t = 0 for angles,
      at 0 and lift-off for forces), normalised to the same peak: harsher, motion-like
      content up to ~5 Hz that no filter can separate from the movement (robustness sweeps).
  The ground moment's bias has the force shape with peak 20 % of the actual moment's peak.
* Low-pass filtering (10 Hz angles, 50 Hz forces) is the trackers' business, not done here.
All random draws come from one seeded generator: the same settings give the same data.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from nmt_ros.records import Observations, Truth
from nmt_ros.tracking.observation_noise import BIAS_SHAPES, OBSERVATION_NOISE, ObservationNoise


@dataclass(frozen=True)
class ObservationSettings:
    """How observations are made from the truth. The noise and bias defaults are the
    observation specification (``OBSERVATION_NOISE``, the paper's), which the trackers'
    weights derive from too; these fields (flat, as bags store them) let sweeps vary them."""

    angle_rate_hz: float = 120.0
    wrench_rate_hz: float = 1080.0
    angle_noise_deg: tuple[float, float, float, float] = OBSERVATION_NOISE.angle_sd_deg
    force_noise_bw: float = OBSERVATION_NOISE.force_sd_bw
    moment_lever_m: float = OBSERVATION_NOISE.moment_lever_m
    moment_bias_fraction: float = OBSERVATION_NOISE.moment_bias_fraction
    bias_shape: str = OBSERVATION_NOISE.bias_shape            # one of BIAS_SHAPES
    bias_harmonics: int = OBSERVATION_NOISE.bias_harmonics
    noise_scale: float = 1.0          # multiplies every noise SD and bias (sweeps)
    seed: int = 0

    @property
    def noise(self) -> ObservationNoise:
        """These settings' noise and bias as an observation specification (unscaled)."""
        return ObservationNoise(angle_sd_deg=self.angle_noise_deg,
                                force_sd_bw=self.force_noise_bw,
                                moment_lever_m=self.moment_lever_m,
                                moment_bias_fraction=self.moment_bias_fraction,
                                bias_shape=self.bias_shape, bias_harmonics=self.bias_harmonics)


def _smooth_shape(t: np.ndarray, period: float, rng: np.random.Generator, harmonics: int,
                  zero_at_end: bool) -> np.ndarray:
    """A random smooth shape with peak magnitude 1, zero at t = 0 (and at ``period``)."""
    c = rng.normal(size=harmonics)
    k = np.arange(1, harmonics + 1)
    phase = (k if zero_at_end else k - 0.5)[None, :] * np.pi * t[:, None] / period
    g = np.sin(phase) @ c
    if zero_at_end:
        g = np.where(t <= period, g, 0.0)
    return g / np.abs(g).max()


def make_observations(truth: Truth, settings: ObservationSettings = ObservationSettings(),
                      body_weight: float | None = None) -> tuple[Observations, dict]:
    """Observations and the exact noise/bias that made them (for checks and the bag).

    Returns (observations, components) with components = {'angle_bias', 'angle_noise',
    'wrench_bias', 'wrench_noise', 'angle_sd', 'wrench_sd'} (arrays aligned with the
    observations).
    """
    st = settings
    rng = np.random.default_rng(st.seed)
    if body_weight is None:
        raise ValueError('body_weight [N] is required for the force noise')
    t_end = float(truth.t[-1])
    # Sample instants: exact multiples of the periods (the truth grid is 1080 Hz from 0).
    t_w = np.arange(0, int(np.floor(t_end * st.wrench_rate_hz + 1e-9)) + 1) / st.wrench_rate_hz
    t_a = np.arange(0, int(np.floor(t_end * st.angle_rate_hz + 1e-9)) + 1) / st.angle_rate_hz
    idx_w = np.rint(np.interp(t_w, truth.t, np.arange(truth.t.size))).astype(int)
    idx_a = np.rint(np.interp(t_a, truth.t, np.arange(truth.t.size))).astype(int)
    if (np.abs(truth.t[idx_w] - t_w).max() > 1e-9 or np.abs(truth.t[idx_a] - t_a).max() > 1e-9):
        raise ValueError('the truth grid must contain the 120 Hz and 1080 Hz sample instants')

    angle_sd = st.noise.angle_sd_rad() * st.noise_scale
    wrench_sd = st.noise.wrench_sd(body_weight) * st.noise_scale
    moment_peak = np.abs(truth.s[truth.contact_mask(), 2]).max()

    bias_peaks = np.array([wrench_sd[0], wrench_sd[1],
                           st.moment_bias_fraction * moment_peak * st.noise_scale])
    if st.bias_shape == 'harmonic':
        angle_shapes = [_smooth_shape(t_a, t_end, rng, st.bias_harmonics, zero_at_end=False)
                        for _ in range(4)]
        wrench_shapes = [_smooth_shape(t_w, truth.liftoff_s, rng, st.bias_harmonics,
                                       zero_at_end=True) for _ in range(3)]
    elif st.bias_shape == 'motion':
        excursion = truth.q[idx_a, :4] - truth.q[0, :4]
        angle_shapes = [excursion[:, j] / np.abs(excursion[:, j]).max() for j in range(4)]
        lobe = np.where(t_w <= truth.liftoff_s, np.sin(np.pi * t_w / truth.liftoff_s), 0.0)
        wrench_shapes = [lobe] * 3
    else:
        raise ValueError(f'bias_shape must be one of {BIAS_SHAPES}, not {st.bias_shape!r}')
    angle_bias = np.column_stack([angle_sd[j] * rng.choice([-1.0, 1.0]) * angle_shapes[j]
                                  for j in range(4)])
    wrench_bias = np.column_stack([bias_peaks[j] * rng.choice([-1.0, 1.0]) * wrench_shapes[j]
                                   for j in range(3)])
    angle_noise = rng.normal(size=(t_a.size, 4)) * angle_sd
    wrench_noise = rng.normal(size=(t_w.size, 3)) * wrench_sd

    obs = Observations(
        t_angles=t_a, angles=truth.q[idx_a, :4] + angle_bias + angle_noise,
        t_wrench=t_w, wrench=truth.s[idx_w] + wrench_bias + wrench_noise,
        info={'settings': asdict(st), 'angle_sd_rad': angle_sd.tolist(),
              'wrench_sd': wrench_sd.tolist(), 'moment_bias_peak_nm': float(bias_peaks[2])})
    components = {'angle_bias': angle_bias, 'angle_noise': angle_noise,
                  'wrench_bias': wrench_bias, 'wrench_noise': wrench_noise,
                  'angle_sd': angle_sd, 'wrench_sd': wrench_sd,
                  'angle_index': idx_a, 'wrench_index': idx_w}
    return obs, components
