"""Foot-ground contact: smooth heel and toe springs, and the paper's contact outputs ``s``.

Per contact point i (ground frame, y = 0 is the undeformed ground), with smooth positive parts
so that the law is C-infinity in the state (the trackers differentiate it, Eq. 4):

    Fy_i = k_y delta softplus(-y_i / delta) * smoothpos(1 - c_hc ydot_i)      (Hunt-Crossley-like)
    Fx_i = mu Fy_i tanh(Fx_el / (mu Fy_i + f_eps)),  Fx_el = -k_x (x_i - x0_i) - c_x xdot_i

``x0`` (the anchors) are the points' ground x at the start of the contact phase: an elastic
"no-slip" spring, saturated smoothly at the friction limit, holds the foot without the creep of
purely velocity-based friction. The outputs (METHOD.md Eq. 2b)

    s = [fore-aft force, vertical force, moment of the ground forces about the foot COM]

are in N, N, N m (moment counter-clockwise positive about +z).
"""
from __future__ import annotations

import casadi as ca

from nmt_ros.model.parameters import ContactParameters


def softplus(x: ca.SX) -> ca.SX:
    """log(1 + exp(x)), written to stay finite for large |x|."""
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))


def point_force(pos: ca.SX, vel: ca.SX, x0: ca.SX, c: ContactParameters) -> ca.SX:
    """Ground force [Fx, Fy] [N] on one foot point at ``pos`` [m] moving at ``vel`` [m/s]."""
    penetration = c.delta * softplus(-pos[1] / c.delta)
    w = c.damping_smoothing
    damping = w * softplus((1.0 - c.c_hc * vel[1]) / w)
    fy = c.k_y * penetration * damping
    fx_el = -c.k_x * (pos[0] - x0) - c.c_x * vel[0]
    limit = c.mu * fy
    fx = limit * ca.tanh(fx_el / (limit + c.f_eps))
    return ca.vertcat(fx, fy)


def contact_outputs(points: list[ca.SX], forces: list[ca.SX], foot_com: ca.SX) -> ca.SX:
    """s = [sum Fx, sum Fy, sum (p_i - c_foot) x F_i] (METHOD.md Eq. 2b)."""
    fx = sum(f[0] for f in forces)
    fy = sum(f[1] for f in forces)
    moment = sum((pt[0] - foot_com[0]) * f[1] - (pt[1] - foot_com[1]) * f[0]
                 for pt, f in zip(points, forces))
    return ca.vertcat(fx, fy, moment)
