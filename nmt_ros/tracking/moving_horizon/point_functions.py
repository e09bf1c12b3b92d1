"""The model at one instant, as the moving-horizon estimator needs it (CasADi, compiled).

At a collocation point the estimator checks the equations of motion with the ground wrench
s = [Fx, Fy, M about the foot COM] as an estimated input (METHOD.md Eq. 1, the wrench applied
to the foot as the paper's Eq. 2b outputs define it), and the contact points' kinematics
(``residuals``: a loaded point stays on the ground and does not slide):

    r_dyn = W_dyn [ M(q) qdd - I(q, qd) - J_fc(q)' [Fx, Fy] - e_th1 M_z - T (tau_m + tau_pas) ]

with tau_m = C(theta) F_MT(a, l_MT(theta), v_MT(theta, theta_dot)) the muscles' joint torques
(Eq. 8b, 10b) and W_dyn = 1 / sigma_dyn per row. Both with their Jacobians, in one function
compiled to C (``nmt_ros.model.compiled``).

The excitations follow from the activation trajectory by inverting Eq. 8a (affine in u):
u = (tau_act adot + beta a) / (1 - (1 - beta) a); they are elementwise, written in numpy
(``excitation``).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from nmt_ros.model.compiled import compiled
from nmt_ros.model.jumper import JumperModel

#: Columns of the collocation Jacobian: q, qd, qdd (6 each), a (9), s (3).
DYN_COLUMNS = 30


def wrench_generalized_forces(model: JumperModel, q: ca.SX, s: ca.SX) -> ca.SX:
    """Generalized forces [6] of the wrench s = [Fx, Fy, Mz] acting at the foot COM."""
    foot_com = model.positions(q)[3][:, 0]
    jac = ca.jacobian(foot_com, q)
    return jac.T @ s[0:2] + ca.vertcat(s[2], ca.SX.zeros(5))


def trunk_residual_function(model: JumperModel) -> ca.Function:
    """(q, e) -> the loads that close Eq. 1's residual e [6] (generalized forces, M qdd -
    rhs): joint torques [3] (N m; ankle, knee, hip), a force on the HAT at its COM [2] (N)
    and a moment on the HAT [1] (N m), with e = T tau + J_hat' f + e_hat m, solved bottom-up
    (the basis of ``JumperModel.inverse_dynamics(residual_at='hat')``). The joint torques
    are what the muscles miss of the net torques of the motion and the ground wrench; the
    HAT's loads, what a planar rigid trunk cannot explain (as OpenSim's residual actuators
    sit on the pelvis)."""
    q, e = ca.SX.sym('q', 6), ca.SX.sym('e', 6)
    T = np.asarray(model.T, dtype=float)
    n_angles = T.shape[0] - 2
    hat = np.zeros((n_angles, 1))
    hat[n_angles - 1, 0] = 1.0
    solve_angles = ca.DM(np.linalg.inv(np.hstack([T[:n_angles], hat])))
    j_hat = ca.jacobian(model.positions(q)[3][:, n_angles - 1], q)    # [2 x 6]
    f = e[n_angles:]
    torques = solve_angles @ (e - j_hat.T @ f)[:n_angles]   # the joints', then the HAT's
    return ca.Function('trunk_residuals', [q, e],
                       [ca.vertcat(torques[:n_angles - 1], f, torques[n_angles - 1])])


def contact_kinematics_function(model: JumperModel) -> ca.Function:
    """(q, qd, s) -> (generalized forces of s [6], heel and toe positions [4] (x, y each),
    their velocities [4], foot COM [2]): the pieces of Eq. 1 and of the kinematic contact
    that need derivatives with respect to q (for use inside other expressions)."""
    q, qd, s = ca.SX.sym('q', 6), ca.SX.sym('qd', 6), ca.SX.sym('s', 3)
    pos = ca.vec(model.positions(q)[4])
    return ca.Function('contact_kinematics', [q, qd, s], [
        wrench_generalized_forces(model, q, s), pos, ca.jacobian(pos, q) @ qd,
        model.positions(q)[3][:, 0]])


def collocation_function(model: JumperModel, sigma_dyn: np.ndarray) -> ca.Function:
    """(q, qd, qdd, a, s) -> (r_dyn [6], dr_dyn/d(q, qd, qdd, a, s) [6 x 30],
    contact kinematics k [10] = heel x, y, toe x, y, their rates, foot COM x, y;
    dk/d(q, qd) [10 x 12]).
    """
    q, qd, qdd = (ca.SX.sym(n, 6) for n in ('q', 'qd', 'qdd'))
    a = ca.SX.sym('a', len(model.p.muscles.names))
    s = ca.SX.sym('s', 3)
    tau_m, _ = model.muscle_torques(q, qd, a)
    rhs = (model.inertial_gravity(q, qd) + wrench_generalized_forces(model, q, s)
           + ca.DM(model.T) @ (tau_m + model.passive_torques(q, qd)))
    r_dyn = ca.DM(1.0 / np.asarray(sigma_dyn, dtype=float)) * (model.mass_matrix(q) @ qdd - rhs)
    pts = model.positions(q)[4]                    # [2 x n_points]: rows x, y
    pos = ca.vec(pts)                              # heel x, heel y, toe x, toe y
    vel = ca.jacobian(pos, q) @ qd
    kin = ca.vertcat(pos, vel, model.positions(q)[3][:, 0])
    fn = ca.Function('mhe_collocation', [q, qd, qdd, a, s],
                     [r_dyn, ca.densify(ca.jacobian(r_dyn, ca.vertcat(q, qd, qdd, a, s))),
                      kin, ca.densify(ca.jacobian(kin, ca.vertcat(q, qd)))], {'cse': True})
    return compiled(fn)


def output_function(model: JumperModel) -> ca.Function:
    """(q, qd, qdd, a, s) -> (tau_m [3] N m, f [9] N, theta [3] rad, theta_dot [3] rad/s,
    tau_r [3] N m): tau_r, the joint torques the muscles miss (the joint part of Eq. 1's
    residual, ``trunk_residual_function``): tau_m + tau_r is the net joint torque of the
    estimated motion and ground wrench, bottom-up, with the rest of the residual on the HAT."""
    q, qd, qdd = ca.SX.sym('q', 6), ca.SX.sym('qd', 6), ca.SX.sym('qdd', 6)
    a = ca.SX.sym('a', len(model.p.muscles.names))
    s = ca.SX.sym('s', 3)
    tau_m, f = model.muscle_torques(q, qd, a)
    rhs = (model.inertial_gravity(q, qd) + wrench_generalized_forces(model, q, s)
           + ca.DM(model.T) @ (tau_m + model.passive_torques(q, qd)))
    tau_r = trunk_residual_function(model)(q, model.mass_matrix(q) @ qdd - rhs)[:3]
    return ca.Function('mhe_outputs', [q, qd, qdd, a, s],
                       [tau_m, f, model.joint_angles(q), model.joint_angles(qd), tau_r])


@dataclass(frozen=True)
class Excitation:
    """u, udot and their partial derivatives (elementwise, [P, 9] each) from a, adot, addot."""

    u: np.ndarray
    udot: np.ndarray
    du_da: np.ndarray
    du_dad: np.ndarray
    dud_da: np.ndarray
    dud_dad: np.ndarray
    dud_dadd: np.ndarray


def excitation(a: np.ndarray, ad: np.ndarray, add: np.ndarray, tau_act: float,
               tau_deact: float) -> Excitation:
    """Eq. 8a inverted: u = (tau_act adot + beta a) / (1 - (1 - beta) a), beta = tau_act /
    tau_deact, and its rate udot, with derivatives (a in [0, 1] keeps the denominator >=
    beta > 0)."""
    beta = tau_act / tau_deact
    inv = 1.0 / np.maximum(1.0 - (1.0 - beta) * a, beta)   # a <= 1 exact; beyond, finite
    u = (tau_act * ad + beta * a) * inv
    du_da = (beta + (1.0 - beta) * u) * inv
    du_dad = tau_act * inv
    udot = (tau_act * add + beta * ad + (1.0 - beta) * u * ad) * inv
    dud_dad = (beta + (1.0 - beta) * u + (1.0 - beta) * ad * du_dad) * inv
    dud_da = (1.0 - beta) * (ad * du_da + udot) * inv
    return Excitation(u=u, udot=udot, du_da=du_da, du_dad=du_dad, dud_da=dud_da,
                      dud_dad=dud_dad, dud_dadd=tau_act * inv)
