"""Initial activations for Stage 2 from the first reference sample (the live node has no truth).

Stage 2 starts its muscle state from activations a0 (``NeuromuscularTracker.start_stream`` /
``track``). A jump starts from rest, so a0 should make the muscles produce the first torque
sample tau_ref(0): at joint angles theta (and speeds theta_dot, zero at rest) the rigid-tendon
force is affine in the activation, F = F(0, l, v) + a (F(1, l, v) - F(0, l, v)), hence
tau = C(theta) F is linear in a. Among the activations in [0, 1] that reproduce tau, take the
one with the least sum of squares (the static-optimisation criterion also used for the squat,
``nmt_ros.model.squat``). If no activation in [0, 1] reproduces tau (a noisy Stage-1 torque,
say), the bounded least-squares fit is returned instead and flagged (``exact`` False).
The excitation that holds each activation constant (adot = 0) is returned too.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear, minimize

from nmt_ros.model.jumper import JumperModel


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
