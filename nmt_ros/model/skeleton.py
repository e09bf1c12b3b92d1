"""Skeleton: kinematics and the skeletal equations of motion (METHOD.md Eq. 1), symbolically.

Generalized coordinates ``q[6] = [th1, th2, th3, th4, r1, r2]``: absolute angles [rad] of foot,
shank, thigh and HAT (counter-clockwise about +z, 0 upright) and the ankle centre (r1 fore-aft,
r2 vertical) [m] in the ground frame. Expressions are CasADi SX built once; numeric functions
are made from them in ``jumper.py``, so the simulator, the trackers and the optimiser share
one definition.

Eq. 1 is written ``M(q) qdd = I(q, qd) + S(q, qd) + T tau + T tau_pas(q, qd)`` with
``I = -h(q, qd) + Q_g(q)`` (velocity-product and gravity generalized forces), ``S`` the contact
generalized forces, ``T`` the constant 6x3 map of joint torques ``tau = [ankle, knee, hip]``
(generalized forces of the OpenSim coordinates ``ankle_angle``, ``knee_angle``,
``hip_flexion``) and ``tau_pas`` the passive ligament torques (``joint_limits.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from nmt_ros.model.parameters import JumperParameters

#: d(joint angles)/dq: ankle = th1 - th2, knee = th2 - th3, hip = th3 - th4.
JOINT_MAP = np.array([
    [1.0, -1.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, -1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, -1.0, 0.0, 0.0],
])
#: T (6x3): joint torques -> generalized forces (Eq. 1), the transpose of ``JOINT_MAP``.
T_MATRIX = JOINT_MAP.T.copy()
#: Index of each segment's angle in q.
ANGLE_INDEX = {'foot': 0, 'shank': 1, 'thigh': 2, 'hat': 3}


def rotation(th: ca.SX) -> ca.SX:
    """2-D rotation matrix of angle ``th`` [rad]."""
    c, s = ca.cos(th), ca.sin(th)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


@dataclass
class Kinematics:
    """Ground-frame positions [m] (2x1 SX) of joint centres, COMs and contact points."""

    ankle: ca.SX
    knee: ca.SX
    hip: ca.SX
    com: dict[str, ca.SX]
    contact_points: list[ca.SX]


def kinematics(q: ca.SX, p: JumperParameters) -> Kinematics:
    """Forward kinematics of the chain foot -> shank -> thigh -> HAT."""
    seg = p.segments
    rot = [rotation(q[i]) for i in range(4)]
    ankle = q[4:6]
    knee = ankle - rot[1] @ seg['shank'].distal_joint
    hip = knee - rot[2] @ seg['thigh'].distal_joint
    com = {
        'foot': ankle + rot[0] @ seg['foot'].com,
        'shank': knee + rot[1] @ seg['shank'].com,
        'thigh': hip + rot[2] @ seg['thigh'].com,
        'hat': hip + rot[3] @ seg['hat'].com,
    }
    points = [ankle + rot[0] @ p.contact.points[i] for i in range(p.contact.points.shape[0])]
    return Kinematics(ankle=ankle, knee=knee, hip=hip, com=com, contact_points=points)


def joint_angles(q: ca.SX) -> ca.SX:
    """OpenSim joint coordinates [ankle_angle, knee_angle, hip_flexion] [rad]."""
    return ca.DM(JOINT_MAP) @ q


def center_of_mass(q: ca.SX, p: JumperParameters) -> ca.SX:
    """Whole-body centre of mass [m] (2x1)."""
    kin = kinematics(q, p)
    total = p.total_mass
    return sum(p.segments[n].mass * kin.com[n] for n in kin.com) / total


@dataclass
class Dynamics:
    """Terms of Eq. 1 as SX: M [6x6], I = -h + Q_g [6]."""

    mass_matrix: ca.SX
    inertial_gravity: ca.SX


def dynamics(q: ca.SX, qd: ca.SX, p: JumperParameters) -> Dynamics:
    """Mass matrix and I(q, qd) of Eq. 1 by the projection (Kane/Jacobian) method.

    M = sum_i m_i J_i' J_i + Izz_i e_i e_i';  h = sum_i m_i J_i' (dJ_i/dt qd);
    Q_g = sum_i J_i' [0, -m_i g].  Rotational velocity-product terms vanish in 2-D.
    """
    kin = kinematics(q, p)
    n = q.shape[0]
    mass_matrix = ca.SX.zeros(n, n)
    h = ca.SX.zeros(n, 1)
    q_g = ca.SX.zeros(n, 1)
    for name, c in kin.com.items():
        s = p.segments[name]
        jac = ca.jacobian(c, q)
        e = ca.SX.zeros(1, n)
        e[ANGLE_INDEX[name]] = 1.0
        mass_matrix += s.mass * (jac.T @ jac) + s.izz * (e.T @ e)
        acc_bias = ca.jacobian(jac @ qd, q) @ qd  # dJ/dt qd
        h += s.mass * (jac.T @ acc_bias)
        q_g += jac.T @ ca.vertcat(0.0, -s.mass * p.gravity)
    return Dynamics(mass_matrix=mass_matrix, inertial_gravity=-h + q_g)


def mechanical_energy(q: ca.SX, qd: ca.SX, p: JumperParameters) -> ca.SX:
    """Kinetic + gravitational potential energy [J] (no springs, no muscles)."""
    d = dynamics(q, qd, p)
    kinetic = 0.5 * qd.T @ d.mass_matrix @ qd
    com = center_of_mass(q, p)
    return kinetic + p.total_mass * p.gravity * com[1]


def point_force_generalized(point: ca.SX, q: ca.SX, force: ca.SX) -> ca.SX:
    """Generalized force of a force [2] applied at a body-fixed point (J' F)."""
    return ca.jacobian(point, q).T @ force
