"""Passive joint (ligament) torques that keep the joints in their range of motion.

Per OpenSim coordinate q_j [rad] (ankle_angle, knee_angle, hip_flexion), two legs lumped:

    tau_pas,j = legs [k1 exp(k2 (q_j - theta_upper)) + k3 exp(k4 (q_j - theta_lower))] - b qdot_j

k1 < 0, k2 > 0 resists motion past the upper limit; k3 > 0, k4 < 0 past the lower limit.
Numbers (Anderson 1999, as tabulated by Falisse et al. 2019) are in the data file.
"""
from __future__ import annotations

import casadi as ca

from nmt_ros.model.parameters import PassiveJointParameters


def passive_torques(theta: ca.SX, theta_dot: ca.SX, p: PassiveJointParameters) -> ca.SX:
    """tau_pas [N m] (3,) on [ankle_angle, knee_angle, hip_flexion]."""
    out = []
    for j in range(3):
        k1, k2, k3, k4 = (float(v) for v in p.k[j])
        elastic = (k1 * ca.exp(k2 * (theta[j] - float(p.theta_upper[j])))
                   + k3 * ca.exp(k4 * (theta[j] - float(p.theta_lower[j]))))
        out.append(p.legs * elastic - float(p.damping[j]) * theta_dot[j])
    return ca.vertcat(*out)
