"""Quiet upright stance: the equilibrium, its regulator and the postural sway input.

* Posture (``quiet_stance``): knee and hip slightly flexed (``knee_deg``, ``hip_deg``), the
  ankle angle chosen so that the whole-body centre of mass stands ``com_ahead_m`` in front of
  the ankle (quiet standing: 4-6 cm, Winter 1995), the foot tilt and ankle height from the
  springs' balance (``squat._posture``), anchors under the contact points.
* Muscle activity: the activations holding that posture with the least sum of squares and at
  least ``tone`` each (a plausible resting level of co-contraction, which also leaves the
  regulator room to lower an excitation), the excitations that keep them constant.
* Regulator (``stance_regulator``): LQR on Eq. 1 + 8 linearised at the equilibrium, weights on
  joint angles (``feedback.joint_weights``) stiff at knee and hip and compliant at the ankle:
  the body sways as an inverted pendulum about the ankle (ankle strategy).
* Sway (``sway_signal``, ``sway_directions``): the regulator tracks a slowly wandering target
  posture, the equilibrium of a forward COM offset c(t) (band-limited random, 0.08-0.8 Hz,
  SD ``sway_sd_m``), with that equilibrium's holding excitations as feed-forward. The sway is
  the regulated model's response to it (ankle strategy by the weights), never a held frame.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq, lsq_linear
from scipy.signal import butter, sosfiltfilt

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.squat import _posture
from nmt_ros.study.feedback import joint_weights, linearize, lqr


@dataclass(frozen=True)
class StanceSettings:
    """Quiet-stance posture, muscle tone, regulator weights and sway input."""

    com_ahead_m: float = 0.045      # COM in front of the ankle (m)
    knee_deg: float = -3.0          # knee_angle (-flexion)
    hip_deg: float = 4.0            # hip_flexion
    tone: float = 0.02              # least activation of every muscle
    # regulator weights per rad^2 (angles), m^2 (ankle position); rates x speed_scale
    w_foot: float = 1e3
    w_ankle: float = 2e1
    w_knee: float = 3e3
    w_hip: float = 1e3
    w_r1: float = 1e2
    w_r2: float = 1e2
    w_speed: float = 0.01           # s^2
    w_activation: float = 1e-2
    r_excitation: float = 1.0
    sway_sd_m: float = 0.004        # SD of the COM sway target (m)
    sway_cutoff_hz: float = 0.8     # sway target band (Hz)
    sway_highpass_hz: float = 0.08
    sway_node_hz: float = 50.0      # nodes of the piecewise-linear target
    sway_taper_s: float = 1.0


@dataclass(frozen=True)
class Stance:
    """The quiet-stance equilibrium: q [6], anchors x0 [2] (m), activations a [9], holding
    excitations u [9], joint torques tau [3] (N m)."""

    q: np.ndarray
    x0: np.ndarray
    a: np.ndarray
    u: np.ndarray
    tau: np.ndarray

    @property
    def x(self) -> np.ndarray:
        """The equilibrium state [21] = [q, 0, a]."""
        return np.concatenate([self.q, np.zeros(6), self.a])

    def shifted(self, dx: float) -> Stance:
        """The same stance with the feet dx [m] further forward (the equilibrium is invariant
        under a horizontal translation of the body with its anchors)."""
        q = self.q.copy()
        q[4] += dx
        return replace(self, q=q, x0=self.x0 + dx)

    def placed_on(self, anchors: np.ndarray) -> Stance:
        """The stance whose feet stand on ``anchors`` [2] (m): shifted so that the mean
        anchor matches (the springs' rest lengths then balance to the mean)."""
        return self.shifted(float(np.mean(anchors) - np.mean(self.x0)))


def tone_activations(model: JumperModel, theta: np.ndarray, tau: np.ndarray, tone: float,
                     ) -> np.ndarray:
    """Activations [9] in [tone, 1] with the least sum of squares whose muscle torques (at
    rest) are tau [3] (N m); RuntimeError if the muscles cannot."""
    n = len(model.p.muscles.names)
    l_mt = model.call(model.musculotendon_lengths, theta)[0]
    v = np.zeros(n)
    c = np.asarray(model.call(model.moment_arm_matrix, theta)[0])
    f_pas = model.call(model.muscle_force, np.zeros(n), l_mt, v)[0]
    f_unit = model.call(model.muscle_force, np.ones(n), l_mt, v)[0] - f_pas
    a_mat = c * f_unit[None, :]
    b = tau - c @ f_pas
    w = 1e4 / np.abs(a_mat).max()
    fit = lsq_linear(np.vstack([w * a_mat, np.eye(n)]), np.concatenate([w * b, np.zeros(n)]),
                     bounds=(tone, 1.0), method='bvls', tol=1e-14)
    a = fit.x
    resid = a_mat @ a - b
    if np.abs(resid).max() > 1e-3:
        raise RuntimeError(f'the muscles cannot hold the stance with tone {tone}: torque '
                           f'residual {resid} N m')
    # polish the equality on the free set (the weighted fit leaves ~1e-4 N m)
    free = (a > tone + 1e-9) & (a < 1 - 1e-9)
    if free.any():
        a[free] -= np.linalg.lstsq(a_mat[:, free], resid, rcond=None)[0]
    return np.clip(a, tone, 1.0)


def holding_excitations(model: JumperModel, a: np.ndarray) -> np.ndarray:
    """Excitations [9] keeping activations a constant (adot = 0)."""
    drift, gain = model.call(model.activation_affine, a)
    return np.clip(-np.asarray(drift) / np.asarray(gain), 0.0, 1.0)


def quiet_stance(model: JumperModel, settings: StanceSettings = StanceSettings()) -> Stance:
    """The quiet-stance equilibrium (module docstring)."""
    q, x0 = _posture_for(model, settings)
    tau = _holding_torque(model, q, x0)
    theta = model.call(model.joint_angles, q)[0]
    a = tone_activations(model, theta, tau, settings.tone)
    return Stance(q=q, x0=x0, a=a, u=holding_excitations(model, a), tau=tau)


def stance_weights(settings: StanceSettings = StanceSettings(),
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(Q [21, 21], R [9, 9]) of the stance regulator."""
    st = settings
    q = joint_weights(st.w_foot, st.w_ankle, st.w_knee, st.w_hip, st.w_r1, st.w_r2,
                      st.w_speed, st.w_activation)
    return q, st.r_excitation * np.eye(9)


def stance_regulator(model: JumperModel, stance: Stance,
                     settings: StanceSettings = StanceSettings(),
                     ) -> tuple[np.ndarray, np.ndarray]:
    """LQR gain K [9, 21] and cost-to-go P [21, 21] of the quiet stance."""
    a_mat, b_mat = linearize(model, stance.x, stance.u, stance.x0)
    q, r = stance_weights(settings)
    return lqr(a_mat, b_mat, q, r)


def sway_directions(model: JumperModel, stance: Stance,
                    settings: StanceSettings = StanceSettings(), step_m: float = 0.002,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """d x_eq / d c [21] and d u_eq / d c [9]: how the equilibrium state and its holding
    excitations change per metre of forward COM offset c, feet in place. The posture and its
    torques by central differences of ``quiet_stance``; the activations by the least-norm
    change da producing the torque change (C F_unit da = d tau, every muscle: a smooth
    direction, where the bounded fit's active set would switch)."""
    ends = []
    for sign in (-1.0, 1.0):
        st = replace(settings, com_ahead_m=settings.com_ahead_m + sign * step_m)
        q, x0 = _posture_for(model, st)
        ends.append((q, _holding_torque(model, q, x0)))
    dq = (ends[1][0] - ends[0][0]) / (2 * step_m)
    dtau = (ends[1][1] - ends[0][1]) / (2 * step_m)
    theta = model.call(model.joint_angles, stance.q)[0]
    a_mat = _torque_per_activation(model, theta)
    da = np.linalg.lstsq(a_mat, dtau, rcond=None)[0]
    drift, gain = model.call(model.activation_affine, stance.a)
    # u = -drift(a) / gain(a): du/da by the quotient rule (drift, gain affine in a)
    m = model.p.muscles
    beta = m.tau_act / m.tau_deact
    d_drift, d_gain = -beta / m.tau_act, -(1.0 - beta) / m.tau_act
    du = -(d_drift * np.asarray(gain) - np.asarray(drift) * d_gain) / np.asarray(gain) ** 2 * da
    dx = np.concatenate([dq, np.zeros(6), da])
    return dx, du


def _posture_for(model: JumperModel, st: StanceSettings) -> tuple[np.ndarray, np.ndarray]:
    """Posture q [6] and anchors [2] of the stance settings' COM offset."""
    def com_offset(ankle_deg: float) -> float:
        q, _ = _posture(model, (ankle_deg, st.knee_deg, st.hip_deg))
        return float(model.call(model.com, q)[0][0] - q[4] - st.com_ahead_m)

    ankle = brentq(com_offset, -10.0, 25.0, xtol=1e-12)
    return _posture(model, (ankle, st.knee_deg, st.hip_deg))


def _holding_torque(model: JumperModel, q: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Joint torques [3] (N m) holding posture q at rest on the springs."""
    s = model.call(model.contact_outputs, q, np.zeros(6), x0)[0]
    tau, _ = model.inverse_dynamics(q, np.zeros(6), np.zeros(6), np.asarray(s)[None])
    return tau[0]


def _torque_per_activation(model: JumperModel, theta: np.ndarray) -> np.ndarray:
    """d tau / d a [3, 9] at rest at joint angles theta (rigid tendon: tau affine in a)."""
    n = len(model.p.muscles.names)
    l_mt = model.call(model.musculotendon_lengths, theta)[0]
    v = np.zeros(n)
    c = np.asarray(model.call(model.moment_arm_matrix, theta)[0])
    f_unit = (model.call(model.muscle_force, np.ones(n), l_mt, v)[0]
              - model.call(model.muscle_force, np.zeros(n), l_mt, v)[0])
    return c * f_unit[None, :]


def sway_signal(rng: np.random.Generator, t0: float, t1: float,
                settings: StanceSettings = StanceSettings()) -> tuple[np.ndarray, np.ndarray]:
    """The sway target c(t) [m] (forward COM offset from the mean) on [t0, t1] at
    ``sway_node_hz``: white noise low-passed at ``sway_cutoff_hz`` (Butterworth order 2,
    forward-backward), high-passed at ``sway_highpass_hz``, scaled to SD ``sway_sd_m``, and
    tapered to zero over the first and last ``sway_taper_s`` (joins to other phases)."""
    st = settings
    fs = st.sway_node_hz
    pad = 10.0 / st.sway_highpass_hz
    n_pad = int(np.ceil(pad * fs))
    n = int(np.ceil((t1 - t0) * fs)) + 1
    white = rng.normal(size=n + 2 * n_pad)
    sos = butter(2, [st.sway_highpass_hz, st.sway_cutoff_hz], btype='bandpass', fs=fs,
                 output='sos')
    v = sosfiltfilt(sos, white)[n_pad:n_pad + n]
    v *= st.sway_sd_m / v.std()
    t = t0 + np.arange(n) / fs
    t[-1] = min(t[-1], t1)
    ramp = np.clip(np.minimum(t - t0, t1 - t) / st.sway_taper_s, 0.0, 1.0)
    return t, v * ramp * ramp * (3.0 - 2.0 * ramp)
