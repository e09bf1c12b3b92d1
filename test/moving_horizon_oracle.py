"""An independent numpy implementation of the moving-horizon estimator's residuals: the
oracle the compiled kernel (``nmt_ros.tracking.moving_horizon.segment_kernel``) is tested
against. Residuals and their Jacobians are written out by hand here (chain rule through the
spline basis, load shares, excitations); only the per-point model functions (Eq. 1 and the
contact points' kinematics, with their Jacobians) come from the package.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmt_ros.tracking.moving_horizon.point_functions import excitation
from nmt_ros.tracking.moving_horizon.residuals import GAUSS, LAYOUT, NB, NV, NX, PLATE
from nmt_ros.tracking.moving_horizon.spline import KnotGrid, basis

COLS = {k: np.arange(v.start, v.stop) for k, v in LAYOUT.items()}


@dataclass
class Group:
    """Residual rows of one kind: see the module docstring."""

    seg: np.ndarray           # [P] int, local segment index
    r: np.ndarray             # [P, m]
    J: np.ndarray             # [P, m, 4, len(cols)]
    cols: np.ndarray          # columns within a control point
    Jx: np.ndarray | None = None   # [P, m, NX]

    def cost(self) -> float:
        return float(np.sum(self.r ** 2))


def huber_weights(r: np.ndarray, k: float) -> np.ndarray:
    """IRLS weights sqrt(w): 1 inside k, sqrt(k / |r|) outside (Huber's loss)."""
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, 1e-300)))


def points(C: np.ndarray, first: int, grid: KnotGrid, t: np.ndarray, orders: int,
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(local segment [P], basis [P, orders, 4], values [P, orders, NV]) at instants t."""
    j, u = grid.locate(t)
    seg = j - first
    B = basis(u, grid.dt)[:, :orders]
    idx = seg[:, None] + np.arange(4)[None, :]
    return seg, B, np.einsum('pok,pkv->pov', B, C[idx])


def _diag_jacobian(B: np.ndarray, w: np.ndarray) -> np.ndarray:
    """[P, m, 4, m]: d (w_i x_i(t)) / d c for one block of m variables; B [P, 4] weights."""
    m = w.shape[-1]
    return (B[:, None, :, None] * np.eye(m)[None, :, None, :]
            * np.broadcast_to(w, (B.shape[0], m))[:, :, None, None])


def angle_group(C: np.ndarray, first: int, grid: KnotGrid, t: np.ndarray, theta: np.ndarray,
                sd: np.ndarray, huber_k: float, free_foot: tuple | None = None) -> Group:
    """Mocap samples: (q_1..4(t) - theta_obs) / sd. ``free_foot`` = (fn, weights, sd_free):
    the foot's rows weigh as sd_free where the ground does not hold both contact points
    (their held weights h_heel h_toe = b: 1/sd^2 -> b/sd^2 + (1 - b)/sd_free^2, held)."""
    seg, B, v = points(C, first, grid, t, 3 if free_foot else 1)
    valid = np.isfinite(theta)
    r = np.where(valid, (v[:, 0, 0:4] - np.nan_to_num(theta)) / sd, 0.0)
    w = huber_weights(r, huber_k) * valid
    if free_foot is not None:
        fn, cw, sd_free = free_foot
        s = v[:, 0, LAYOUT['s']]
        kin = fn(v[:, 0, LAYOUT['q']], v[:, 1, LAYOUT['q']], v[:, 2, LAYOUT['q']],
                 v[:, 0, LAYOUT['a']], s)[2]
        both = np.prod(held_weights(s, kin, cw)[1], axis=1)
        w[:, 0] *= np.sqrt(both + (1.0 - both) * (sd[0] / sd_free) ** 2)
    return Group(seg, r * w, _diag_jacobian(B[:, 0], w / sd), COLS['q'][:4])


def plate_reading(s: np.ndarray, plate: np.ndarray) -> np.ndarray:
    """What the plate reads [P, 3] for the true wrench s [P, 3] and its error model."""
    b, d = plate[PLATE['b']], plate[PLATE['cop']][0]
    return np.column_stack([s[:, 0] + b[0], s[:, 1] + b[1], s[:, 2] + d * s[:, 1] + b[2]])


def wrench_group(C: np.ndarray, first: int, grid: KnotGrid, plate: np.ndarray,
                 t: np.ndarray, s_obs: np.ndarray, sd: np.ndarray, huber_k: float) -> Group:
    """Force-plate samples: (plate reading of s(t) - s_obs) / sd."""
    seg, B, v = points(C, first, grid, t, 1)
    s = v[:, 0, LAYOUT['s']]
    valid = np.isfinite(s_obs)
    r = np.where(valid, (plate_reading(s, plate) - np.nan_to_num(s_obs)) / sd, 0.0)
    w = huber_weights(r, huber_k) * valid / sd            # [P, 3]
    d = plate[PLATE['cop']][0]
    D = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, d, 1.0]])
    J = w[:, :, None, None] * D[None, :, None, :] * B[:, 0, None, :, None]
    P = t.size
    Jx = np.zeros((P, 3, NX))
    Jx[:, :, 0:3] = np.eye(3)[None]
    Jx[:, 2, 3] = s[:, 1]
    return Group(seg, r * w * sd, J, COLS['s'], Jx * w[:, :, None])


def collocation_times(grid: KnotGrid, segments: np.ndarray) -> np.ndarray:
    """Two Gauss-Legendre points per segment (global indices) [2 n] (s)."""
    return (grid.t_ref + (np.asarray(segments)[:, None] + GAUSS[None, :]) * grid.dt).ravel()


@dataclass(frozen=True)
class CollocationWeights:
    """Weights of the collocation-point residuals (see ``MovingHorizonSettings``)."""

    sd_height: float            # m: a loaded contact point's height vs its sinkage
    sd_slip: float              # m/s: a loaded contact point's horizontal speed
    full_load: float            # N: vertical force above which points are held
    free_load: float            # N: below which they are free
    full_share: float           # share of the vertical force at which a point is fully held
    stiffness: float            # N/m: sinkage = load / stiffness (the contact springs')
    wrench_accel_sd: np.ndarray  # [3]
    w_u: float
    w_du: float
    rho: float
    tau_act: float
    tau_deact: float
    release_sd: float = 0.0     # a point lifted by more than this x sd_height lets go
    support_sd: float = 0.0     # m: under load the lowest point's height vs its sinkage


def collocation_groups(C: np.ndarray, first: int, grid: KnotGrid, segments: np.ndarray,
                       fn: object, w: CollocationWeights) -> list[Group]:
    """Dynamics, contact and excitation terms at the Gauss points of ``segments`` (global)."""
    t = collocation_times(grid, segments)
    seg, B, v = points(C, first, grid, t, 3)
    P = t.size
    q, qd, qdd = v[:, 0, LAYOUT['q']], v[:, 1, LAYOUT['q']], v[:, 2, LAYOUT['q']]
    a, s = v[:, 0, LAYOUT['a']], v[:, 0, LAYOUT['s']]
    r_dyn, J_dyn, kin, J_kin = fn(q, qd, qdd, a, s)
    # Eq. 1 on q (value, rate, acceleration), a and s
    cols_d = np.concatenate([COLS['q'], COLS['a'], COLS['s']])
    Jd = np.zeros((P, 6, 4, cols_d.size))
    for k in range(3):
        Jd[:, :, :, 0:6] += J_dyn[:, :, None, 6 * k:6 * k + 6] * B[:, k, None, :, None]
    Jd[:, :, :, 6:15] = J_dyn[:, :, None, 18:27] * B[:, 0, None, :, None]
    Jd[:, :, :, 15:18] = J_dyn[:, :, None, 27:30] * B[:, 0, None, :, None]
    groups = [Group(seg, r_dyn, Jd, cols_d), contact_group(seg, B, s, kin, J_kin, w)]
    # excitations (Eq. 8a inverted): effort, smoothness, bounds on u and a
    ad, add = v[:, 1, LAYOUT['a']], v[:, 2, LAYOUT['a']]
    ex = excitation(a, ad, add, w.tau_act, w.tau_deact)
    quad = np.sqrt(grid.dt / 2.0)
    ku, kd = quad * np.sqrt(w.w_u), quad * np.sqrt(w.w_du)
    over = np.where(ex.u > 1.0, ex.u - 1.0, np.where(ex.u < 0.0, ex.u, 0.0))
    active = (over != 0.0) * np.sqrt(w.rho) * quad
    a_over = np.where(a > 1.0, a - 1.0, np.where(a < 0.0, a, 0.0))
    a_active = (a_over != 0.0) * np.sqrt(w.rho) * quad
    r_ex = np.concatenate([ku * ex.u, kd * ex.udot, active * over, a_active * a_over], axis=1)
    na = a.shape[1]
    Je = np.zeros((P, 4 * na, 4, na))
    eye = np.eye(na)[None, :, None, :]
    for rows, partials in ((slice(0, na), (ku * ex.du_da, ku * ex.du_dad, None)),
                           (slice(na, 2 * na), (kd * ex.dud_da, kd * ex.dud_dad,
                                                kd * ex.dud_dadd)),
                           (slice(2 * na, 3 * na), (active * ex.du_da, active * ex.du_dad,
                                                    None)),
                           (slice(3 * na, 4 * na), (a_active, None, None))):
        for k, d in enumerate(partials):
            if d is not None:
                Je[:, rows] += d[:, :, None, None] * B[:, k, None, :, None] * eye
    groups.append(Group(seg, r_ex, Je, COLS['a']))
    s_acc = v[:, 2, LAYOUT['s']]
    groups.append(Group(seg, quad * s_acc / w.wrench_accel_sd,
                        _diag_jacobian(B[:, 2], quad / w.wrench_accel_sd), COLS['s']))
    return groups


def load_shares(s: np.ndarray, kin: np.ndarray) -> np.ndarray:
    """Share [P, 2] of the vertical force on heel and toe: with the fore-aft force split like
    the vertical one, the moment about the foot COM is linear in the toe's share w,
    M = (1 - w) m_heel + w m_toe with m_i = (x_i - x_c) Fy - (y_i - y_c) Fx; clipped to
    [0, 1]; half and half when the vertical force is ~0. kin as ``contact_group``'s."""
    fx, fy, moment = s[:, 0], s[:, 1], s[:, 2]
    xc, yc = kin[:, 8], kin[:, 9]
    m_heel = (kin[:, 0] - xc) * fy - (kin[:, 1] - yc) * fx
    m_toe = (kin[:, 2] - xc) * fy - (kin[:, 3] - yc) * fx
    span = m_toe - m_heel
    ok = (fy > 1.0) & (np.abs(span) > 1e-3)
    toe = np.where(ok, np.clip((moment - m_heel) / np.where(ok, span, 1.0), 0.0, 1.0), 0.5)
    return np.column_stack([1.0 - toe, toe])


def contact_group(seg: np.ndarray, B: np.ndarray, s: np.ndarray, kin: np.ndarray,
                  J_kin: np.ndarray, w: CollocationWeights) -> Group:
    """Kinematic contact: each contact point i carries F_i = share_i Fy (``load_shares``);
    weighted by min(F_i / full_load, 1) it stays at height -F_i / stiffness (the springs'
    sinkage; the height rows also involve Fy) and does not slide (horizontal speed 0). The
    shares and weights are evaluated at the current point and held (IRLS-like).
    kin [P, 10] = heel x, y, toe x, y, their rates, foot COM x, y; J_kin [P, 10, 12]."""
    P = s.shape[0]
    share, held_by, ramp = held_weights(s, kin, w)
    load = np.maximum(share * s[:, 1:2], 0.0)                       # [P, 2] N
    y = kin[:, [1, 3]]
    weight = np.sqrt(held_by)
    xdot = kin[:, [4, 6]]
    r = np.concatenate([weight * (y + load / w.stiffness) / w.sd_height,
                        weight * xdot / w.sd_slip], axis=1)             # [P, 4]
    cols = np.concatenate([COLS['q'], COLS['s']])
    J = np.zeros((P, 4, 4, cols.size))
    for row, k, sd in ((0, 1, w.sd_height), (1, 3, w.sd_height), (2, 4, w.sd_slip),
                       (3, 6, w.sd_slip)):
        wk = weight[:, row % 2] / sd
        J[:, row, :, 0:6] = wk[:, None, None] * (J_kin[:, k, None, 0:6] * B[:, 0, :, None]
                                                 + J_kin[:, k, None, 6:12] * B[:, 1, :, None])
    for i in range(2):   # height rows also depend on the load = share_i Fy (share held)
        J[:, i, :, 6 + 1] = (weight[:, i] * share[:, i]
                             / (w.stiffness * w.sd_height))[:, None] * B[:, 0, :]
    sink = y + share * s[:, 1:2] / w.stiffness      # each point's height + its sinkage
    r[:, :2] = weight * sink / w.sd_height
    if w.support_sd > 0:
        # under load the lowest point (height + sinkage, the smaller one) is on the ground:
        # one more row, weighted by the load ramp (held), shares held
        low = np.argmin(sink, axis=1)
        rows = np.arange(P)
        k = np.array([1, 3])[low]
        ws = ramp[:, 0] / w.support_sd
        r = np.concatenate([r, (ws * sink[rows, low])[:, None]], axis=1)
        Js = np.zeros((P, 1, 4, cols.size))
        Js[:, 0, :, 0:6] = ws[:, None, None] * (J_kin[rows, k, None, 0:6] * B[:, 0, :, None]
                                                + J_kin[rows, k, None, 6:12]
                                                * B[:, 1, :, None])
        Js[:, 0, :, 6 + 1] = (ws * share[rows, low] / w.stiffness)[:, None] * B[:, 0, :]
        J = np.concatenate([J, Js], axis=1)
    return Group(seg, r, J, cols)


def held_weights(s: np.ndarray, kin: np.ndarray, w: CollocationWeights,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Load shares [P, 2] (``load_shares``), how firmly each point is held [P, 2] (its share
    up to full_share, times the load ramp, times the redescending release of a lifted point)
    and the load ramp [P, 1] (0 airborne .. 1 loaded)."""
    share = load_shares(s, kin)
    ramp = np.clip((s[:, 1:2] - w.free_load) / (w.full_load - w.free_load), 0.0, 1.0)
    held_by = np.minimum(share / w.full_share, 1.0) * ramp
    if w.release_sd > 0:   # redescending: the lift above the sinkage, in sd_height units
        lift = np.maximum(kin[:, [1, 3]] + share * s[:, 1:2] / w.stiffness, 0.0) / w.sd_height
        held_by = held_by / (1.0 + (lift / w.release_sd) ** 2) ** 2
    return share, held_by, ramp


def segment_blocks(groups: list[Group], segments: np.ndarray,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton blocks of the local ``segments`` [S] (sorted): H [S, NB + NX, NB + NX],
    g = -J'r [S, NB + NX] and the cost 1/2 sum r^2 per segment [S]. Every group's rows are
    placed in one dense row block per segment, then H = J'J is one batched product."""
    S = segments.size
    used = np.zeros(S, dtype=np.int64)
    layout = []
    for grp in groups:
        if grp.seg.size == 0:
            continue
        P, m = grp.r.shape
        slot = np.searchsorted(segments, grp.seg)
        order = np.argsort(slot, kind='stable')
        slot = slot[order]
        uniq, start, count = np.unique(slot, return_index=True, return_counts=True)
        rank = np.arange(P) - np.repeat(start, count)
        row0 = used[slot] + rank * m
        used[uniq] += count * m
        layout.append((grp, order, slot, row0))
    R = int(used.max()) if S else 0
    Jd = np.zeros((S, max(R, 1), NB + NX))
    rd = np.zeros((S, max(R, 1)))
    for grp, order, slot, row0 in layout:
        P, m = grp.r.shape
        nc = grp.cols.size
        idx = (np.arange(4)[:, None] * NV + grp.cols[None, :]).ravel()
        J = grp.J[order].reshape(P, m, 4 * nc)
        rows = row0[:, None] + np.arange(m)[None, :]
        Jd[slot[:, None, None], rows[:, :, None], idx[None, None, :]] = J
        if grp.Jx is not None:
            Jd[slot[:, None, None], rows[:, :, None],
               (NB + np.arange(NX))[None, None, :]] = grp.Jx[order]
        rd[slot[:, None], rows] = grp.r[order]
    Jt = Jd.transpose(0, 2, 1)
    return Jt @ Jd, -np.einsum('sir,sr->si', Jt, rd), 0.5 * np.einsum('sr,sr->s', rd, rd)
