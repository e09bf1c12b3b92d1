"""Stage 1: the skeletal motion tracker (SKT), METHOD.md section 2, Eqs. 2-7.

Outputs y = [theta (4 segment angles); s (3 contact outputs)]. Differentiating them until the
joint torques appear (Eq. 3: angles twice; Eq. 4: contact forces once, the springs being
damped) gives v = A(Q) + B(Q) tau with B 7x3; the feedback-linearising law (Eq. 5) solves it
in the weighted least-squares sense for the tracking demand v of Eq. 7:

    v_theta = thetadd_obs - 2 lam_th (thetad - thetad_obs) - lam_th^2 (theta - theta_obs)
    v_s     = sdot_obs    - lam_s (s - s_obs)

Rows are normalised before weighting so that Table 1's weights compare like with like: an
angle row is divided by lam_th^2 * sigma_theta and a contact row by lam_s * sigma_s, i.e. each
row is the tracking error it demands be removed, in units of a reference measurement accuracy
(1 deg for angles, 2 % body weight for forces, 2 % BW x foot length for the moment).

Ground-moment bias (the paper used Kuo's (1998) least squares "including bias"): the moment
reference is ``s3_obs - b`` with a bias estimate b that follows the slow part of the moment
disagreement, bdot = kappa (s3_obs - s3 - b): a recursive (online) form of estimating a slowly
varying offset jointly with the states. kappa = 0 disables it.

The model is simulated FORWARD with these torques (fixed-step RK4, ``substeps`` per force
sample: the closed-loop force dynamics have poles at 1000 rad/s, so RK4 with steps of 0.46 ms
(lam*h ~ 0.46) is well inside its stability region, 2.8; 4 substeps change the torques by
< 0.1 % of peak). Slower force plates get more substeps, so that no step exceeds
``max_step_s`` (by default the step ``substeps`` make at 1080 Hz: 22 per sample at 100 Hz).
Jacobians ds/dQ are exact (automatic differentiation of the model's single definition) or
numerical (central differences, as in the paper). Loss of control (the paper's third
limitation) is detected and reported.

Stability (measured, not assumed): linearised about the static squat, the closed loop with
Table 1's weights has an unstable mode (eigenvalue about +5 1/s, +3 1/s without the bias
estimate): the HAT leans while thigh and shank counter-rotate so that the COM, hence the ground
forces, do not change. Three torques cannot serve seven rows; only when the contact rows weigh
about 100 times less does the loop become stable, and then the torques are poor (knee errors
of 70 %). Over a 0.2 s push the mode grows by about e^1 and is harmless; over seconds of quiet
standing with noisy data it drifts until the loss-of-control checks stop the trial (after
0.5-1.5 s of standing in our tests). Start trials near movement onset (as the paper's data
do); the live node restarts a trial after a loss of control.

This module is the recipe (settings, the compiled closed loop and its RK4 step, the initial
state); ``nmt_ros.tracking.streaming`` runs it on data, live or over a whole recording.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import functools

import casadi as ca
import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.simulation import rk4_step, steps_per_sample
from nmt_ros.tracking.conditioning import ConditionedObservations
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE

N_REF = 18  # theta(4), theta_dot(4), theta_ddot(4), s(3), s_dot(3)


@dataclass(frozen=True)
class SKTSettings:
    """Poles (1/s), least-squares weights (Table 1) and numerics of Stage 1."""

    poles: tuple[float, ...] = (50.0, 50.0, 50.0, 50.0, 1000.0, 1000.0, 1000.0)
    weights: tuple[float, ...] = (0.001, 0.7, 0.8, 1.0, 2.0, 2.0, 1.0)
    # Row scales of Eq. 5 (the error a row demands be removed, in these units): 1 deg for the
    # angles (Table 1's weights carry the per-segment trust), the force plate's noise SD for
    # the contact rows, from the observation specification.
    angle_scale_deg: float | tuple[float, ...] = 1.0   # one value or one per segment
    force_scale_bw: float = OBSERVATION_NOISE.force_sd_bw
    moment_lever_m: float = OBSERVATION_NOISE.moment_lever_m   # moment scale = force x lever
    bias_rate: float = 20.0          # kappa (1/s) of the moment-bias estimate; 0 = off
    # Tikhonov rows sqrt(w) tau / torque_scale added to Eq. 5: keeps the torques determined
    # when the contact rows vanish (flight) and the foot angle's weight is tiny. 0 = off.
    torque_regularization: float = 0.0
    # The foot angle's weight while the model is in flight (None: Table 1's weight always).
    # On the ground the contact holds the foot and 0.001 lets the force rows decide; in the
    # air nothing does, and a free foot absorbs every mismatch between the observed rotations
    # and the model's angular momentum (it spins into the ankle's ligament limits). The weight
    # blends from Table 1's to this one as the model's vertical force falls below
    # liftoff_force_bw: w = w1 + (w_flight - w1) exp(-(Fy / (liftoff_force_bw BW))^2).
    flight_foot_weight: float | None = None
    normalize_rows: bool = True      # False: Table 1 weights on raw rows (rad/s^2, N/s, N m/s)
    torque_scale_nm: float = 100.0
    jacobians: str = 'exact'         # 'exact' | 'numerical'
    fd_step: float = 1e-6            # central-difference step for numerical Jacobians
    substeps: int = 2                # RK4 steps per force-plate sample (h = 0.46 ms)
    # Longest RK4 step [s]: slower force plates get more substeps so that h <= this. None:
    # the step ``substeps`` make at the paper's 1080 Hz (2: 0.46 ms, 22 steps per sample at
    # 100 Hz; the live node's 1: 0.93 ms, 11 at 100 Hz).
    max_step_s: float | None = None
    static_start: bool = True        # the trial starts at rest (the paper's static squat)
    # Lift-off of the tracked model (the rule of model/contact.py): its vertical force falls
    # below the force plate's noise SD (it follows the noisy ~0 N observations in flight with
    # a small contact force), from the observation specification.
    liftoff_force_bw: float = OBSERVATION_NOISE.force_sd_bw
    # Tracking ends this long after the tracked model's lift-off (None: never). In flight only
    # the angles remain as outputs and, for this jump, the joints swing into their stiff
    # ligament limits, where noisy angles demand unbounded torques; the study needs the
    # contact phase and the lift-off state. A trial with landings would set None.
    flight_tracking_s: float | None = 0.005
    # Loss-of-control detection.
    max_angle_error_deg: float = 20.0    # shank, thigh or HAT vs the filtered observation
    max_force_error_bw: float = 1.5      # vertical force vs the filtered observation
    max_torque_nm: float = 2000.0        # any joint (beyond human capacity: diverging)
    min_conditioning: float = 1e-10      # smallest/largest eigenvalue of B'WB

    def with_(self, **kw: object) -> SKTSettings:
        return replace(self, **kw)


@dataclass
class SKTState:
    """Explicit state of the tracker (the recipe is stateless)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    b: float
    x0: np.ndarray


class SkeletalTracker:
    """Stage 1 as a recipe: the closed loop (Eqs. 2-7) compiled once, and its fixed-step RK4
    in step with the data. Stateless (Drake's System): the state is an :class:`SKTState`
    passed in and returned; ``nmt_ros.tracking.streaming.Stage1Stream`` holds it."""

    def __init__(self, model: JumperModel, settings: SKTSettings = SKTSettings(),
                 rate_hz: float = 1080.0) -> None:
        if settings.jacobians not in ('exact', 'numerical'):
            raise ValueError("jacobians must be 'exact' or 'numerical'")
        self.model = model
        self.settings = settings
        self.rate_hz = rate_hz
        # RK4 steps per output sample: the settings' or more, so that h <= max_step_s.
        max_step = (settings.max_step_s if settings.max_step_s is not None
                    else 1.0 / (1080.0 * settings.substeps))
        self.substeps = steps_per_sample(rate_hz, max_step, settings.substeps)
        self.dt = 1.0 / (rate_hz * self.substeps)   # RK4 step [s]
        self._build()

    def _build(self) -> None:
        m, st = self.model, self.settings
        q = ca.SX.sym('q', 6)
        qd = ca.SX.sym('qd', 6)
        b = ca.SX.sym('b')
        ref = ca.SX.sym('ref', N_REF)
        x0 = ca.SX.sym('x0', 2)
        th_o, thd_o, thdd_o = ref[0:4], ref[4:8], ref[8:12]
        s_o, sd_o = ref[12:15], ref[15:18]

        f_drift, g_gain = m.drift_and_gain(q, qd, x0)       # Eq. 2a: [qd; qdd] = F + G tau
        qdd_free, qdd_gain = f_drift[6:12], g_gain[6:12, :]
        s = m.contact_outputs(q, qd, x0)
        if st.jacobians == 'exact':
            _, ds_dq, ds_dqd = m.contact_outputs_jacobian(q, qd, x0)
        else:
            h = st.fd_step
            cols_q, cols_qd = [], []
            for i in range(6):
                e = ca.DM.zeros(6)
                e[i] = h
                cols_q.append((m.contact_outputs(q + e, qd, x0)
                               - m.contact_outputs(q - e, qd, x0)) / (2 * h))
                cols_qd.append((m.contact_outputs(q, qd + e, x0)
                                - m.contact_outputs(q, qd - e, x0)) / (2 * h))
            ds_dq, ds_dqd = ca.horzcat(*cols_q), ca.horzcat(*cols_qd)
        # Eq. 3-4: [thetadd; sdot] = A + B tau
        a_th, b_th = qdd_free[0:4], qdd_gain[0:4, :]
        a_s = ds_dq @ qd + ds_dqd @ qdd_free
        b_s = ds_dqd @ qdd_gain
        A = ca.vertcat(a_th, a_s)
        B = ca.vertcat(b_th, b_s)
        # Eq. 7 with the moment reference corrected by the bias estimate b.
        lam = ca.DM(st.poles)
        s_ref = s_o - ca.vertcat(0, 0, b)
        bdot = st.bias_rate * (s_o[2] - s[2] - b)
        sd_ref = sd_o - ca.vertcat(0, 0, bdot)
        v_th = thdd_o - 2 * lam[0:4] * (qd[0:4] - thd_o) - lam[0:4] ** 2 * (q[0:4] - th_o)
        v_s = sd_ref - lam[4:7] * (s - s_ref)
        v = ca.vertcat(v_th, v_s)
        # Eq. 5: weighted least squares on normalised rows.
        bw = m.p.body_weight
        angle_sigma = np.radians(np.broadcast_to(st.angle_scale_deg, (4,)))
        sigma = ca.DM(list(angle_sigma) + [st.force_scale_bw * bw] * 2
                      + [st.force_scale_bw * bw * st.moment_lever_m])
        order_gain = ca.vertcat(lam[0:4] ** 2, lam[4:7])
        row_w = ca.sqrt(ca.DM(st.weights))
        if st.flight_foot_weight is not None:
            airborne = ca.exp(-(s[1] / (st.liftoff_force_bw * bw)) ** 2)
            row_w = ca.vertcat(ca.sqrt(st.weights[0] + (st.flight_foot_weight - st.weights[0])
                                       * airborne), row_w[1:])
        if st.normalize_rows:
            row_w = row_w / (order_gain * sigma)
        Bw = B * ca.repmat(row_w, 1, 3)
        rw = (v - A) * row_w
        normal = Bw.T @ Bw + (st.torque_regularization / st.torque_scale_nm ** 2) * ca.DM.eye(3)
        tau = ca.solve(normal, Bw.T @ rw)
        qdd = qdd_free + qdd_gain @ tau
        residual = Bw @ tau - rw                     # unexplained demand, per row
        self.closed_loop = ca.Function(
            'skt_closed_loop', [q, qd, b, ref, x0],
            [ca.vertcat(qd, qdd), bdot, tau, ca.vertcat(q[0:4], s), residual, normal],
            ['q', 'qd', 'b', 'ref', 'x0'],
            ['Qdot', 'bdot', 'tau', 'y', 'residual', 'normal'])
        self.rhs = ca.Function('skt_rhs', [q, qd, b, ref, x0], [ca.vertcat(qd, qdd), bdot])

    def fine_times(self, t0: float, n_samples: int) -> np.ndarray:
        """RK4 stage instants for n output samples after t0 (half-step grid)."""
        k = self.substeps * n_samples
        return t0 + np.arange(0, 2 * k + 1) * (self.dt / 2)

    def advance(self, state: SKTState, refs: np.ndarray) -> tuple[SKTState, dict]:
        """Integrate over len(refs)//(2*self.substeps) output samples; refs on ``fine_times``.

        Returns the new state and the outputs at each output sample's END instant.
        """
        rhs = self.rhs
        n_sub = (refs.shape[0] - 1) // 2
        dt = self.dt
        x0 = state.x0
        y = np.concatenate([state.q, state.qd, [state.b]])
        outs = []
        for k in range(n_sub):
            # RK4 evaluates at 0, h/2 and h: the references on the half-step grid.
            stage_refs = refs[2 * k:2 * k + 3]

            def f(t_rel: float, yy: np.ndarray, stage_refs: np.ndarray = stage_refs,
                  ) -> np.ndarray:
                ref = stage_refs[int(round(2 * t_rel / dt))]
                qdot, bdot = rhs(yy[:6], yy[6:12], yy[12], ref, x0)
                return np.append(np.asarray(qdot).ravel(), float(bdot))

            y = rk4_step(f, 0.0, y, dt)
            if (k + 1) % self.substeps == 0:
                outs.append((y[:12].copy(), float(y[12]), refs[2 * k + 2]))
        Q, b = y[:12], float(y[12])
        new = SKTState(t=state.t + n_sub * dt, q=Q[:6].copy(), qd=Q[6:].copy(), b=b, x0=x0)
        return new, self.outputs(outs, x0)

    def outputs(self, outs: list, x0: np.ndarray) -> dict:
        """Torques, outputs and diagnostics at the output samples (one batched call)."""
        Qs = np.array([o[0] for o in outs])
        bs = np.array([o[1] for o in outs])
        refs = np.array([o[2] for o in outs])
        m = self.model
        Qdot, _, tau, y, resid, normal = m.batch(self.closed_loop, Qs[:, :6], Qs[:, 6:],
                                                  bs[:, None], refs, x0)
        finite = np.isfinite(normal).all(axis=(1, 2))
        cond = np.full(len(outs), np.nan)
        if finite.any():
            eig = np.linalg.eigvalsh(normal[finite])
            cond[finite] = eig[:, 0] / eig[:, -1]
        return {'Q': Qs, 'qdd': Qdot[:, 6:], 'tau': tau, 'y': y, 'b': bs, 'ref': refs,
                'residual': resid, 'conditioning': cond}

    def check_control(self, out: dict, t: np.ndarray) -> list[dict]:
        """Loss-of-control events (first per kind) in a block of outputs."""
        st = self.settings
        events = []
        y, ref = out['y'], out['ref']
        finite = np.isfinite(out['Q']).all(axis=1) & np.isfinite(out['tau']).all(axis=1)
        err_angle = np.degrees(np.abs(y[:, 1:4] - ref[:, 1:4])).max(axis=1)
        err_force = np.abs(y[:, 5] - ref[:, 13]) / self.model.p.body_weight
        checks = [
            (~finite, 'non-finite state or torque (the simulation diverged)'),
            (err_angle > st.max_angle_error_deg,
             f'segment angle error above {st.max_angle_error_deg:g} deg'),
            (err_force > st.max_force_error_bw,
             f'vertical ground force error above {st.max_force_error_bw:g} BW'),
            (~(out['conditioning'] >= st.min_conditioning),
             'the least-squares system lost rank (torques no longer determined)'),
            (np.abs(out['tau']).max(axis=1) > st.max_torque_nm,
             f'joint torque above {st.max_torque_nm:g} N m (the tracker is diverging)'),
        ]
        for mask, reason in checks:
            if mask.any():
                i = int(np.argmax(mask))
                events.append({'t': float(t[i]), 'reason': reason,
                               'angle_error_deg': float(err_angle[i]),
                               'force_error_bw': float(err_force[i])})
        return events


def _static_residual_function(model: JumperModel, st: SKTSettings) -> ca.Function:
    """Residual (and its Jacobian) of the static-start posture problem, z = [th1..th4, dr2].

    Rows: whole-body static balance (rigid rotation about the ankle and vertical translation:
    the joint torques cancel in these combinations), weighted heavily; the angles' deviation
    from the observed ones and the moment's from the observed moment, normalised and weighted
    as the rows of Eq. 5. The anchors sit under the contact points (springs unstretched).
    Built once per model and the settings it depends on (weights and row scales).
    """
    relevant = SKTSettings(weights=st.weights, angle_scale_deg=st.angle_scale_deg,
                           force_scale_bw=st.force_scale_bw, moment_lever_m=st.moment_lever_m)
    return _static_residual(model, relevant)


# Bounded: a process builds one or two (model, settings) pairs; at most 8 are kept alive.
@functools.lru_cache(maxsize=8)
def _static_residual(model: JumperModel, st: SKTSettings) -> ca.Function:
    """The compiled residual of :func:`_static_residual_function` (cached)."""
    z = ca.SX.sym('z', 5)
    th_obs = ca.SX.sym('theta_obs', 4)
    m_obs = ca.SX.sym('moment_obs')
    q = ca.vertcat(z[0:4], 0.0, model.ankle_height + z[4])
    zero = ca.DM.zeros(6)
    x0 = model.positions(q)[4][0, :].T
    gen = model.inertial_gravity(q, zero) + model.contact_generalized(q, zero, x0)
    s = model.contact_outputs(q, zero, x0)
    bw = model.p.body_weight
    w = np.sqrt(np.asarray(st.weights))
    balance = ca.vertcat(ca.sum1(gen[0:4]) / (0.01 * bw), gen[5] / (0.001 * bw)) * 1e3
    angles = ca.DM(w[:4] / np.radians(np.broadcast_to(st.angle_scale_deg, (4,)))) * (
        z[0:4] - th_obs)
    moment = w[6] * (s[2] - m_obs) / (st.force_scale_bw * bw * st.moment_lever_m)
    r = ca.vertcat(balance, angles, moment)
    return ca.Function('skt_static_residual', [z, th_obs, m_obs], [r, ca.jacobian(r, z)])


def _flat_foot_angle(model: JumperModel) -> float:
    """Foot angle [rad] at which its heel and toe points are at the same height."""
    (hx, hy), (tx, ty) = model.p.contact.points
    return float(-np.arctan2(ty - hy, tx - hx))


def initial_state(model: JumperModel, ref0: np.ndarray,
                  settings: SKTSettings = SKTSettings()) -> SKTState:
    """Initial state of the tracked model from the observations at t = 0.

    ``static_start`` (the paper's jump starts from a static squat): the posture closest to
    the observed angles, in the same normalised, weighted sense as Eq. 5, that is in static
    equilibrium on its springs and reproduces the observed ground moment; rates are zero.
    Otherwise: the filtered observed angles and rates, with the ankle height that makes the
    springs carry the observed vertical force. In both cases r1 = 0 and the horizontal anchors
    are placed under the contact points (springs unstretched).
    """
    from scipy.optimize import least_squares

    st = settings
    ankle_h = model.ankle_height
    zero = np.zeros(6)

    def pose(z: np.ndarray) -> np.ndarray:
        return np.r_[z[:4], 0.0, ankle_h + z[4]]

    if st.static_start:
        fn = _static_residual_function(model, st)
        args = (ref0[0:4], ref0[14])

        def residual(z: np.ndarray) -> np.ndarray:
            return np.asarray(fn(z, *args)[0]).ravel()

        def jacobian(z: np.ndarray) -> np.ndarray:
            return np.asarray(fn(z, *args)[1])

        # Bounds: each angle within 15 deg of its observation, the ankle within 5 cm of its
        # unloaded height. Start from the foot flat on both contact points (the observed foot
        # angle is the noisiest channel; from it a heel-up local minimum is often found).
        centre = np.r_[ref0[0:4], 0.0]
        span = np.r_[np.full(4, np.radians(15.0)), 0.05]
        flat = _flat_foot_angle(model)
        z0 = np.clip(np.r_[flat, ref0[1:4], -0.002], centre - span, centre + span)
        # dogbox: 6 evaluations (1 ms) where trf takes ~400 on this small bounded problem.
        sol = least_squares(residual, z0, jac=jacobian, bounds=(centre - span, centre + span),
                            method='dogbox', xtol=1e-12, ftol=1e-12, gtol=1e-12)
        q = pose(sol.x)
        return SKTState(t=0.0, q=q, qd=zero.copy(), b=0.0, x0=model.anchors_at(q))

    q = pose(np.r_[ref0[0:4], 0.0])
    qd = np.zeros(6)
    qd[:4] = ref0[4:8]
    fy_obs = float(ref0[13])
    lo, hi = -0.05, 0.2
    for _ in range(200):  # bisection on the vertical force (monotone in r2)
        mid = 0.5 * (lo + hi)
        q[5] = ankle_h + mid
        fy = float(model.call(model.contact_outputs, q, qd, model.anchors_at(q))[0][1])
        lo, hi = (mid, hi) if fy > fy_obs else (lo, mid)
    q[5] = ankle_h + 0.5 * (lo + hi)
    return SKTState(t=0.0, q=q, qd=qd, b=0.0, x0=model.anchors_at(q))


def flight_state(ref0: np.ndarray, ankle: np.ndarray, ankle_rate: np.ndarray,
                 anchors: np.ndarray) -> SKTState:
    """Initial state of a trial that starts in flight (off the ground, nothing to balance):
    the filtered observed angles and rates of ``ref0`` (``reference_arrays`` at t = 0), the
    ankle centre ``ankle`` [2] (m) and its rate ``ankle_rate`` [2] (m/s) as measured, and the
    contact anchors ``anchors`` [2] (m): the heel's and toe's ground x where the foot lands."""
    q = np.r_[ref0[0:4], np.asarray(ankle, dtype=float)]
    qd = np.r_[ref0[4:8], np.asarray(ankle_rate, dtype=float)]
    return SKTState(t=0.0, q=q, qd=qd, b=0.0, x0=np.asarray(anchors, dtype=float).copy())


def reference_arrays(cond: ConditionedObservations, t: np.ndarray) -> np.ndarray:
    """Stack the conditioned observations at times t into [n, 18] tracker references."""
    smp = cond.sample(t)
    return np.hstack([smp['theta'], smp['theta_dot'], smp['theta_ddot'], smp['s'],
                      smp['s_dot']])
