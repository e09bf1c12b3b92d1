"""Static squat: a posture and muscle activations in equilibrium with the contact springs.

Given the three joint angles, the foot tilt th1 and the ankle height r2 are solved so that the
springs carry the body (vertical force and moment balance), with the horizontal anchors placed
under the points (no fore-aft force). The joint torques that hold the posture then follow from
Eq. 1 with qdd = 0, and the activations are the least-squares ones (min sum a^2, 0 <= a <= 1)
whose muscle torques (at zero speed) equal them (``rest_activations``, also Stage 2's a0).

Rest activations: at joint angles theta (and speeds theta_dot, zero at rest) the rigid-tendon
force is affine in the activation, F = F(0, l, v) + a (F(1, l, v) - F(0, l, v)), hence
tau = C(theta) F is linear in a. Among the activations in [0, 1] that reproduce tau, take the
one with the least sum of squares (static optimisation). If none reproduces tau (a noisy
Stage-1 torque, say), the bounded least-squares fit is returned instead and flagged
(``exact`` False). The excitation that holds each activation constant (adot = 0) is returned
too.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, lsq_linear, minimize

from nmt_ros.model.jumper import JumperModel


@dataclass(frozen=True)
class StaticSquat:
    """Equilibrium at t = 0: q [6], anchors x0 [2], torques tau [3], activations a [9]."""

    q: np.ndarray
    x0: np.ndarray
    tau: np.ndarray
    a: np.ndarray
    u: np.ndarray
    f: np.ndarray
    residual_qdd: np.ndarray


def segment_angles_from_joints(joint_deg: tuple[float, float, float], foot_tilt: float = 0.0,
                               ) -> np.ndarray:
    """Absolute angles [th1..th4] [rad] from (ankle, knee, hip) [deg] and the foot tilt [rad]."""
    ankle, knee, hip = np.radians(joint_deg)
    th1 = foot_tilt
    th2 = th1 - ankle
    th3 = th2 - knee
    th4 = th3 - hip
    return np.array([th1, th2, th3, th4])


def _posture(model: JumperModel, joint_deg: tuple[float, float, float]) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """Solve (th1, r2) with tau free: whole-body vertical force and moment balance."""
    def pose(z: np.ndarray) -> np.ndarray:
        q = np.zeros(6)
        q[:4] = segment_angles_from_joints(joint_deg, z[0])
        q[5] = model.ankle_height + z[1]
        return q

    def residual(z: np.ndarray) -> np.ndarray:
        q = pose(z)
        x0 = model.anchors_at(q)
        # Whole-body balance: the generalized forces of the rigid-body motions of the whole
        # body (rotation about the ankle with all segments, vertical translation) must vanish.
        # In absolute-angle coordinates these are the sums of rows: rotating every segment by
        # the same angle about the ankle, and translating r2.
        inert = model.call(model.inertial_gravity, q, np.zeros(6))[0]
        contact = model.call(model.contact_generalized, q, np.zeros(6), x0)[0]
        total = inert + contact
        return np.array([total[:4].sum() / 100.0, total[5] / 100.0])

    sol = least_squares(residual, np.array([0.0, -0.002]), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    q = pose(sol.x)
    return q, model.anchors_at(q)


@dataclass(frozen=True)
class RestActivations:
    """Activations at the first sample and how well they reproduce its torques."""

    a: np.ndarray            # [m] in [0, 1]
    f: np.ndarray            # [m] N, musculotendon forces
    u: np.ndarray            # [m] excitations holding a constant
    residual: np.ndarray     # [3] N m, tau - C f
    exact: bool              # tau reproduced (|residual| <= tol)


def rest_activations(model: JumperModel, theta: np.ndarray, tau: np.ndarray,
                     theta_dot: np.ndarray | None = None, tol: float = 1e-6,
                     ) -> RestActivations:
    """a0 [m] in [0, 1] with min sum a^2 such that C(theta) F(a) = tau (see module docstring).

    theta, tau [3] (ankle, knee, hip: rad, N m); theta_dot [3] rad/s (default 0: at rest).
    ``tol`` [N m]: torque residual accepted as exact.
    """
    theta = np.asarray(theta, dtype=float).reshape(3)
    tau = np.asarray(tau, dtype=float).reshape(3)
    theta_dot = np.zeros(3) if theta_dot is None else np.asarray(theta_dot,
                                                                  dtype=float).reshape(3)
    n = len(model.p.muscles.names)
    l_mt = model.call(model.musculotendon_lengths, theta)[0]
    v_mt = model.call(model.musculotendon_velocities, theta, theta_dot)[0]
    C = np.asarray(model.call(model.moment_arm_matrix, theta)[0])
    f_passive = model.call(model.muscle_force, np.zeros(n), l_mt, v_mt)[0]
    f_unit = model.call(model.muscle_force, np.ones(n), l_mt, v_mt)[0] - f_passive
    A = C * f_unit[None, :]
    b = tau - C @ f_passive
    scale = max(1.0, float(np.abs(A).max()))
    a = _least_norm(A / scale, b / scale)
    if a is None or np.max(np.abs(A @ a - b)) > tol:
        # no exact solution in the box: bounded least squares (tiny ridge for uniqueness)
        ridge = 1e-6 * float(np.abs(A).max())
        fit = lsq_linear(np.vstack([A, ridge * np.eye(n)]), np.concatenate([b, np.zeros(n)]),
                         bounds=(0.0, 1.0), method='bvls', tol=1e-12)
        a = np.clip(fit.x, 0.0, 1.0)
    f = f_passive + f_unit * a
    residual = tau - C @ f
    drift, gain = model.call(model.activation_affine, a)
    u = np.clip(-np.asarray(drift) / np.asarray(gain), 0.0, 1.0)
    return RestActivations(a=a, f=f, u=u, residual=residual,
                           exact=bool(np.max(np.abs(residual)) <= tol))


def rest_activations_for_posture(model: JumperModel, q: np.ndarray,
                                 x0: np.ndarray) -> np.ndarray:
    """a0 [m] holding the generalized posture ``q`` [6] at rest on springs anchored at ``x0``.

    The joint torques are those of Eq. 1 with qd = qdd = 0 and the springs' wrench at rest;
    the activations are ``rest_activations`` of them (min sum a^2).
    """
    q = np.asarray(q, dtype=float).reshape(6)
    s0 = model.call(model.contact_outputs, q, np.zeros(6), x0)[0]
    tau0, _ = model.inverse_dynamics(q, np.zeros(6), np.zeros(6), np.asarray(s0)[None])
    theta = model.call(model.joint_angles, q)[0]
    return rest_activations(model, theta, tau0[0]).a


def _least_norm(A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """argmin 1/2 |a|^2 s.t. A a = b, 0 <= a <= 1 (SLSQP, then exact on the free set)."""
    n = A.shape[1]
    res = minimize(lambda a: 0.5 * a @ a, np.full(n, 0.1), jac=lambda a: a,
                   constraints=[{'type': 'eq', 'fun': lambda a: A @ a - b,
                                 'jac': lambda a: A}],
                   bounds=[(0.0, 1.0)] * n, method='SLSQP',
                   options={'ftol': 1e-16, 'maxiter': 500})
    if not res.success:
        return None
    a = np.clip(res.x, 0.0, 1.0)
    free = (a > 1e-9) & (a < 1 - 1e-9)
    if free.any():
        a[free] += np.linalg.lstsq(A[:, free], b - A @ a, rcond=None)[0]
    return np.clip(a, 0.0, 1.0)


def solve_static_squat(model: JumperModel, joint_deg: tuple[float, float, float] = (25.0, -70.0,
                                                                                    80.0),
                       ) -> StaticSquat:
    """Static squat at joint angles (ankle, knee, hip) [deg] (default: SCONE's jump start)."""
    if not model.has_muscles:
        raise ValueError('the model has no muscle paths; cannot solve muscle activations')
    q, x0 = _posture(model, joint_deg)
    qd = np.zeros(6)
    # Joint torques: the T-rows of Eq. 1 at rest (foot, shank, thigh equations are exact once
    # the whole-body balance holds).
    tau, _resid = model.inverse_dynamics(q, qd, np.zeros(6),
                                         model.call(model.contact_outputs, q, qd, x0)[0][None])
    tau = tau[0]
    theta = model.call(model.joint_angles, q)[0]
    rest = rest_activations(model, theta, tau)
    if not rest.exact:
        raise RuntimeError(f'static squat: the muscles cannot hold it (torque residual '
                           f'{rest.residual} N m)')
    a, f, u = rest.a, rest.f, rest.u
    x = np.concatenate([q, qd, a])
    xdot = model.call(model.musculoskeletal_ode, x, u, x0)[0]
    return StaticSquat(q=q, x0=x0, tau=tau, a=a, u=u, f=f, residual_qdd=xdot[6:12])
