"""Static squat: a posture and muscle activations in equilibrium with the contact springs.

Given the three joint angles, the foot tilt th1 and the ankle height r2 are solved so that the
springs carry the body (vertical force and moment balance), with the horizontal anchors placed
under the points (no fore-aft force). The joint torques that hold the posture then follow from
Eq. 1 with qdd = 0, and the activations are the least-squares ones (min sum a^2, 0 <= a <= 1)
whose muscle torques (at zero speed) equal them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize

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
    ankle_height = -float(model.p.contact.points[:, 1].min())

    def pose(z: np.ndarray) -> np.ndarray:
        q = np.zeros(6)
        q[:4] = segment_angles_from_joints(joint_deg, z[0])
        q[5] = ankle_height + z[1]
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


def static_activations(model: JumperModel, q: np.ndarray, tau: np.ndarray,
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Activations a [9] in [0, 1] with min sum a^2 whose muscle torques at rest equal tau.

    At zero speed the force is affine in a (F = F_passive + a F_active), so the torque
    equality C F = tau is linear in a: a small QP (SLSQP, then an exact polish on the free
    set). Returns (a, f). Raises if the torques cannot be produced.
    """
    theta = model.call(model.joint_angles, q)[0]
    lmt = model.call(model.musculotendon_lengths, theta)[0]
    vmt = np.zeros(9)
    C = model.call(model.moment_arm_matrix, theta)[0]
    f_passive = model.call(model.muscle_force, np.zeros(9), lmt, vmt)[0]
    f_unit = model.call(model.muscle_force, np.ones(9), lmt, vmt)[0] - f_passive
    A = C * f_unit[None, :]
    b = np.asarray(tau, dtype=float) - C @ f_passive
    res = minimize(lambda a: 0.5 * a @ a, np.full(9, 0.1), jac=lambda a: a,
                   constraints=[{'type': 'eq', 'fun': lambda a: (A @ a - b) / 100.0,
                                 'jac': lambda a: A / 100.0}],
                   bounds=[(0.0, 1.0)] * 9, method='SLSQP',
                   options={'ftol': 1e-16, 'maxiter': 500})
    if not res.success:
        raise RuntimeError(f'static activations: the torques {tau} cannot be produced at rest '
                           f'({res.message})')
    a = np.clip(res.x, 0.0, 1.0)
    free = (a > 1e-9) & (a < 1 - 1e-9)
    if free.any():
        a[free] += np.linalg.lstsq(A[:, free], b - A @ a, rcond=None)[0]
    return a, f_passive + f_unit * a


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
    a, f = static_activations(model, q, tau)
    # Excitation that holds each activation constant: adot = 0 in Eq. 8a.
    beta = model.p.muscles.tau_act / model.p.muscles.tau_deact
    u = beta * a / (1.0 - (1.0 - beta) * a)
    x = np.concatenate([q, qd, a])
    xdot = model.call(model.musculoskeletal_ode, x, u, x0)[0]
    return StaticSquat(q=q, x0=x0, tau=tau, a=a, u=u, f=f, residual_qdd=xdot[6:12])
