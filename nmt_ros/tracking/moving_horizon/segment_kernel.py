"""One spline segment's Gauss-Newton block, compiled: residuals, Jacobian and J'J in C.

A segment uses four control points c (4 x NV) and the plate parameters p (NX): together
z [NB + NX]. Its residuals (``residuals`` documents each term) are those of the samples that
fall in it and of its two Gauss points. The kernel computes, for one segment,

    r(z), J = dr/dz,  H = J'J,  g = -J'r,  cost = 1/2 r'r

with the Huber weights of the samples, the contact points' load shares and weights held at
their current values (iteratively reweighted least squares: they scale rows, they are not
differentiated). CasADi builds r, J and the products J'J, J'r symbolically (SX), generated as
C and compiled once (``nmt_ros.model.compiled``), then mapped over the segments of an update.
Samples are passed padded to a fixed capacity per segment with a 0/1 mask (padding and NaN
channels carry no weight).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from nmt_ros.model.compiled import compiled
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.point_map import PointMap
from nmt_ros.tracking.moving_horizon.point_functions import contact_kinematics_function
from nmt_ros.tracking.moving_horizon.residuals import GAUSS, LAYOUT, NV, NX, PLATE


@dataclass(frozen=True)
class KernelSpec:
    """What a kernel is compiled for: sample capacities per segment and the weights."""

    angle_capacity: int
    wrench_capacity: int
    dt: float                     # knot spacing [s]
    angle_sd: tuple               # [4] rad
    wrench_sd: tuple              # [3]
    huber_k: float
    sd_dyn: tuple                 # [6] per row of Eq. 1
    sd_height: float
    sd_slip: float
    full_load: float              # N: above this vertical force the points are held...
    free_load: float              # N: ...below this they are free (airborne)
    stiffness: float
    w_u: float
    w_du: float
    rho: float
    tau_act: float
    tau_deact: float
    wrench_accel_sd: tuple        # [3] prior SD of the wrench's 2nd derivative [N/s^2 sqrt(s)]
    share_free: bool = False      # differentiate the contact points' load shares
    full_share: float = 0.2       # a point with this share of the vertical force is held
    release_sd: float = 0.0       # a point lifted by more than this x sd_height lets go
    support_sd: float = 0.0       # m: the lowest point stands on the ground under load (0: off)
    free_foot_sd: float = 0.0     # rad: the foot angle's SD where a point is free (0: as held)


def _basis(u: ca.SX, dt: float) -> list[list[ca.SX]]:
    """Cubic B-spline weights [order][k] (value, 1st, 2nd derivative) at local u."""
    u2, u3 = u * u, u * u * u
    b0 = [(1 - u) ** 3, 3 * u3 - 6 * u2 + 4, -3 * u3 + 3 * u2 + 3 * u + 1, u3]
    b1 = [-3 * (1 - u) ** 2, 9 * u2 - 12 * u, -9 * u2 + 6 * u + 3, 3 * u2]
    b2 = [6 * (1 - u), 18 * u - 12, -18 * u + 6, 6 * u]
    return [[b / 6.0 for b in b0], [b / (6.0 * dt) for b in b1],
            [b / (6.0 * dt ** 2) for b in b2]]


def _huber(r: ca.SX, k: float) -> ca.SX:
    a = ca.fabs(r)
    return ca.if_else(a <= k, 1.0, ca.sqrt(k / ca.fmax(a, 1e-12)))


def build_kernel(model: JumperModel, spec: KernelSpec) -> ca.Function:
    """The compiled one-segment kernel: (c [4 NV], p [NX], u_a [A], y_a [A, 4] (row-major),
    m_a [A, 4], u_w [W], y_w [W, 3], m_w [W, 3], scale, colloc, relax [2]) -> (H [NB + NX]^2,
    g [NB + NX], cost, angle cost, angle rows, wrench cost, wrench rows).

    ``scale`` divides Eq. 1 and the contact rows (a continuation at a cold start; 1 after);
    ``colloc`` (0/1) switches the Gauss-point terms (0: a segment's extra samples);
    ``relax`` multiplies the SDs of two priors at this segment (1: as specified): the ground
    wrench's 2nd derivative and the excitations' rate (around a landing, where both
    change faster than anywhere else: ``SlidingWindow.prior_relaxation``)."""
    s = spec
    c = ca.SX.sym('c', 4 * NV)
    p = ca.SX.sym('p', NX)
    A, W = s.angle_capacity, s.wrench_capacity
    u_a, y_a, m_a = ca.SX.sym('u_a', A), ca.SX.sym('y_a', 4 * A), ca.SX.sym('m_a', 4 * A)
    u_w, y_w, m_w = ca.SX.sym('u_w', W), ca.SX.sym('y_w', 3 * W), ca.SX.sym('m_w', 3 * W)
    scale, colloc = ca.SX.sym('scale'), ca.SX.sym('colloc')
    relax = ca.SX.sym('relax', 2)
    ctrl = [c[k * NV:(k + 1) * NV] for k in range(4)]

    def at(u: ca.SX, block: str, order: int) -> ca.SX:
        B = _basis(u, s.dt)[order]
        sl = LAYOUT[block]
        return sum(B[k] * ctrl[k][sl] for k in range(4))

    rows: list[ca.SX] = []         # residuals (held weights as symbols)
    held: list[ca.SX] = []         # symbols of the held weights
    held_values: list[ca.SX] = []  # their values
    groups: dict[str, list[ca.SX]] = {'angles': [], 'wrench': []}

    def hold(value: ca.SX, name: str) -> ca.SX:
        sym = ca.SX.sym(name, value.shape[0])
        held.append(sym)
        held_values.append(value)
        return sym

    kinematics = contact_kinematics_function(model)

    def contact(q: ca.SX, qd: ca.SX, sg: ca.SX) -> tuple[ca.SX, ...]:
        """The kinematic contact at one instant: generalised forces of the wrench, heel and
        toe heights [2], slips [2], their load shares [2] (from the centre of pressure), the
        load factor (0 airborne .. 1 loaded) and how firmly each point is held [2] (0..1)."""
        gen_s, pos, vel, com = kinematics(q, qd, sg)
        fx, fy, mz = sg[0], sg[1], sg[2]
        m_heel = (pos[0] - com[0]) * fy - (pos[1] - com[1]) * fx
        m_toe = (pos[2] - com[0]) * fy - (pos[3] - com[1]) * fx
        span = m_toe - m_heel
        ok = ca.logic_and(fy > 1.0, ca.fabs(span) > 1e-3)
        toe = ca.if_else(ok, ca.fmin(ca.fmax((mz - m_heel) / ca.if_else(ok, span, 1.0), 0.0),
                                     1.0), 0.5)
        shares = ca.vertcat(1 - toe, toe)
        loaded = ca.fmin(ca.fmax((fy - s.free_load) / (s.full_load - s.free_load), 0.0), 1.0)
        held_by = ca.fmin(shares / s.full_share, 1.0) * loaded
        heights = ca.vertcat(pos[1], pos[3])
        if s.release_sd > 0:   # a point the motion lifts is let go (redescending weight)
            lift = ca.fmax(heights + shares * fy / s.stiffness, 0) / s.sd_height
            held_by = held_by / (1 + (lift / s.release_sd) ** 2) ** 2
        return gen_s, heights, ca.vertcat(vel[0], vel[2]), shares, fy, loaded, held_by

    sd_a = ca.DM(s.angle_sd)
    for i in range(A):
        q_i = at(u_a[i], 'q', 0)
        r = (q_i[0:4] - y_a[4 * i:4 * i + 4]) / sd_a
        w = hold(_huber(r, s.huber_k), f'hw_a{i}') * m_a[4 * i:4 * i + 4]
        if s.free_foot_sd > 0:
            # the foot's angle sample weighs as free_foot_sd where the ground does not hold
            # both contact points (a heel rise, a flight): there the mocap alone tells it
            held_by = contact(q_i, at(u_a[i], 'q', 1), at(u_a[i], 's', 0))[-1]
            both = held_by[0] * held_by[1]
            boost = ca.sqrt(both + (1 - both) * (s.angle_sd[0] / s.free_foot_sd) ** 2)
            w = w * ca.vertcat(hold(boost, f'foot_free{i}'), 1, 1, 1)
        rows.append(w * r)
        groups['angles'].append(w * r)
    sd_w = ca.DM(s.wrench_sd)
    b, d = p[PLATE['b']], p[PLATE['cop']][0]
    for i in range(W):
        sw = at(u_w[i], 's', 0)
        reading = ca.vertcat(sw[0] + b[0], sw[1] + b[1], sw[2] + d * sw[1] + b[2])
        r = (reading - y_w[3 * i:3 * i + 3]) / sd_w
        w = hold(_huber(r, s.huber_k), f'hw_w{i}') * m_w[3 * i:3 * i + 3]
        rows.append(w * r)
        groups['wrench'].append(w * r)

    quad = np.sqrt(s.dt / 2.0)
    sd_dyn = ca.DM(s.sd_dyn)
    beta = s.tau_act / s.tau_deact
    T = ca.DM(model.T)
    for g_u in GAUSS:
        q, qd, qdd = (at(g_u, 'q', k) for k in range(3))
        a, ad, add = (at(g_u, 'a', k) for k in range(3))
        sg = at(g_u, 's', 0)
        tau_m, _ = model.muscle_torques(q, qd, a)
        gen_s, heights, slips, shares, fy, loaded, held_by = contact(q, qd, sg)
        rhs = (model.inertial_gravity(q, qd) + gen_s
               + T @ (tau_m + model.passive_torques(q, qd)))
        rows.append(colloc * (model.mass_matrix(q) @ qdd - rhs) / (sd_dyn * scale))
        # kinematic contact: heel and toe, load shares held (see residuals.contact_group)
        share = shares if s.share_free else hold(shares, 'share')
        r_height = (heights + share * fy / s.stiffness) / (s.sd_height * scale)
        weight = hold(ca.sqrt(held_by), 'weight')
        rows.append(colloc * weight * r_height)
        rows.append(colloc * weight * slips / (s.sd_slip * scale))
        if s.support_sd > 0:   # under load the foot's lowest point is on the ground
            sinkage = heights + share * fy / s.stiffness
            rows.append(colloc * hold(loaded, 'loaded') * ca.mmin(sinkage)
                        / (s.support_sd * scale))
        # excitations (Eq. 8a inverted): effort, smoothness, bounds on u and a
        den = ca.fmax(1 - (1 - beta) * a, beta)   # a <= 1 exact; beyond, kept finite
        u = (s.tau_act * ad + beta * a) / den
        udot = (s.tau_act * add + beta * ad + (1 - beta) * u * ad) / den
        over_u = u - ca.fmin(ca.fmax(u, 0.0), 1.0)
        over_a = a - ca.fmin(ca.fmax(a, 0.0), 1.0)
        rows.append(colloc * quad * ca.vertcat(np.sqrt(s.w_u) * u,
                                               np.sqrt(s.w_du) * udot / relax[1],
                                               np.sqrt(s.rho) * over_u,
                                               np.sqrt(s.rho) * over_a))
        # the ground wrench is smooth (a smoothing-spline prior on its 2nd derivative)
        rows.append(colloc * quad * at(g_u, 's', 2) / (ca.DM(s.wrench_accel_sd) * relax[0]))
    z = ca.vertcat(c, p)
    r_all = ca.vertcat(*rows)
    J = ca.jacobian(r_all, z)
    a_cost = sum(ca.sumsqr(x) for x in groups['angles'])
    w_cost = sum(ca.sumsqr(x) for x in groups['wrench'])
    hsym, hval = ca.vertcat(*held), ca.vertcat(*held_values)
    r_all, J, a_cost, w_cost = ca.substitute([r_all, J, a_cost, w_cost], [hsym], [hval])
    inputs = [c, p, u_a, y_a, m_a, u_w, y_w, m_w, scale, colloc, relax]
    names = ['c', 'p', 'u_a', 'y_a', 'm_a', 'u_w', 'y_w', 'm_w', 'scale', 'colloc', 'relax']
    rows_fn = ca.Function('mhe_segment_rows', inputs,
                          [r_all, J, a_cost, ca.sum1(m_a), w_cost, ca.sum1(m_w)],
                          names, ['r', 'J', 'a_cost', 'a_rows', 'w_cost', 'w_rows'],
                          {'cse': True})
    # J'J and J'r as SX products of the rows' expressions, J'J's upper triangle mirrored (a
    # product commutes exactly, so the mirror equals the lower triangle's own sums): the same
    # sums in the same order as the sparse MX product used until 2026-12-07 (outputs bit for
    # bit the same), as straight-line code without its index loops, transposes and copies
    sx_in = [ca.SX.sym(n, x.shape[0]) for n, x in zip(names, inputs)]
    r, Js, ac, ar, wc, wr = rows_fn(*sx_in)
    H = ca.densify(ca.triu2symm(ca.triu(ca.mtimes(Js.T, Js))))
    g = ca.densify(-ca.mtimes(Js.T, r))
    kernel = ca.Function('mhe_segment', sx_in, [H, g, 0.5 * ca.sumsqr(r), ac, ar, wc, wr],
                         names, ['H', 'g', 'cost', 'a_cost', 'a_rows', 'w_cost', 'w_rows'],
                         {'cse': True})
    return compiled(kernel)


def capacity(rate_hz: float, knot_rate_hz: float) -> int:
    """Samples of a stream at rate_hz that can fall in one knot interval (+1 for jitter)."""
    return int(np.ceil(rate_hz / knot_rate_hz - 1e-9)) + 1




class SegmentKernel:
    """The compiled kernel mapped over segments (``model.point_map.PointMap``), with its
    sample capacities; built once per model and spec in a process (kept in ``_KERNELS``)."""

    def __init__(self, model: JumperModel, spec: KernelSpec) -> None:
        key = (id(model), spec)
        if key not in _KERNELS:
            if len(_KERNELS) >= 4:
                _KERNELS.pop(next(iter(_KERNELS)))
            _KERNELS[key] = (model, PointMap(build_kernel(model, spec)))
        self.map = _KERNELS[key][1]
        self.angle_capacity = spec.angle_capacity
        self.wrench_capacity = spec.wrench_capacity

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """The kernel's outputs per segment: views of its buffers, valid until the next call
        (``SlidingWindow.evaluate`` adds them up at once)."""
        return self.map(*args, copy=False)


_KERNELS: dict[tuple, tuple] = {}
