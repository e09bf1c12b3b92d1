"""The bounded LQT of Stage 2 ('plan' mode): Eq. 11 with 0 <= u <= 1, a convex QP.

Not in the paper. Eq. 11 discretised on the grid (trapezoid tracking, interval-rate effort,
the same Q, R, P) with bounds on every state step (Stage 2: activations between the exact
activation steps at u = 0 and u = 1) is a convex QP with a banded Hessian; ``solve_bounded_lqt``
solves it by a primal-dual interior point whose Newton systems are block tridiagonal (banded
Cholesky = the discrete Riccati recursion of that step's LQT). Its active set says which
muscles sit at a bound over which intervals; ``lqt.discrete_lqt`` then gives the feedback law
of that active set.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import get_lapack_funcs


@dataclass(frozen=True)
class BoundedLqtSolution:
    """Solution of ``solve_bounded_lqt`` on a grid of n samples (x[0] = the given x0)."""

    x: np.ndarray              # [n, m] states (Stage 2: activations)
    f: np.ndarray              # [n, m] outputs f = phi x + psi (Stage 2: forces)
    slack_lo: np.ndarray       # [n-1, m] x_i+1 - (lo_a x_i + lo_b) >= 0
    slack_hi: np.ndarray       # [n-1, m] (hi_a x_i + hi_b) - x_i+1 >= 0
    z_lo: np.ndarray           # [n-1, m] multipliers (>= 0)
    z_hi: np.ndarray           # [n-1, m]
    cost: float                # the discretised Eq. 11
    iterations: int
    converged: bool

    def position(self) -> np.ndarray:
        """Where x_i+1 lies in its reachable interval, 0 (lower bound) .. 1 (upper) [n-1, m]."""
        width = self.slack_lo + self.slack_hi
        return np.clip(self.slack_lo / np.where(width > 0, width, 1.0), 0.0, 1.0)


class _BandedLayout:
    """Index maps into LAPACK's lower banded storage (bandwidth m) of a block-tridiagonal
    matrix with N dense diagonal blocks [m, m] and diagonal off-diagonal blocks."""

    def __init__(self, nb: int, m: int) -> None:
        r, c = np.tril_indices(m)
        base = np.arange(nb)[:, None] * m
        self.shape = (m + 1, nb * m)
        self.band = np.broadcast_to(r - c, (nb, r.size)).ravel()
        self.col = (base + c).ravel()
        self.rows, self.cols = r, c
        self.coupling_col = (base[:-1] + np.arange(m)).ravel()

    def fill(self, blocks: np.ndarray, coupling: np.ndarray) -> np.ndarray:
        ab = np.zeros(self.shape)
        ab[self.band, self.col] = blocks[:, self.rows, self.cols].ravel()
        ab[-1, self.coupling_col] = coupling.ravel()
        return ab


@dataclass(frozen=True)
class BoundedLqtQp:
    """Eq. 11 in discrete time with bounds on the state steps, as a QP in x_1..x_n-1.

    Objective 1/2 x' H x + g_lin' x + const with H block tridiagonal: diagonal blocks
    T_i + diag(e_diag_i) [n-1, m, m], off-diagonal blocks diag(e_off_i) [n-2, m] between
    x_i+1 and x_i+2; constraints x_i+1 - la_i x_i >= lb_i and ha_i x_i + hb_i - x_i+1 >= 0
    (x_0 the data, folded into lb0, hb0 of the first interval). Built by ``bounded_lqt_qp``.
    """

    h: float                   # s
    x0: np.ndarray             # [m]
    C: np.ndarray              # [n, p, m]
    tau_ref: np.ndarray        # [n, p]
    Q: np.ndarray              # [p, p]
    P: np.ndarray | None       # [p, p]
    phi: np.ndarray            # [n, m]
    psi: np.ndarray            # [n, m]
    w: np.ndarray              # [n] trapezoid weights (s)
    k_eff: np.ndarray          # [m] R / h
    la: np.ndarray             # [n-1, m] lower bound: slope
    lb: np.ndarray             # [n-1, m] ... offset
    ha: np.ndarray             # [n-1, m] upper bound: slope
    hb: np.ndarray             # [n-1, m] ... offset
    lb0: np.ndarray            # [n-1, m] lb with la x_0 added in the first interval
    hb0: np.ndarray            # [n-1, m] hb with ha x_0 added in the first interval
    T: np.ndarray              # [n-1, m, m] tracking Hessian blocks
    e_diag: np.ndarray         # [n-1, m] effort Hessian, diagonal
    e_off: np.ndarray          # [n-2, m] effort Hessian, coupling of neighbours
    g_lin: np.ndarray          # [n-1, m] linear term

    @property
    def shape(self) -> tuple[int, int]:
        """(n - 1, m): the unknowns x_1..x_n-1."""
        return self.g_lin.shape

    def hess_vec(self, x: np.ndarray) -> np.ndarray:
        """H x for x [n-1, m]."""
        out = np.einsum('kij,kj->ki', self.T, x) + self.e_diag * x
        out[:-1] += self.e_off * x[1:]
        out[1:] += self.e_off * x[:-1]
        return out

    def previous(self, x: np.ndarray) -> np.ndarray:
        """x_i for the intervals i = 0..n-2 (x_0 the data; zero for directions)."""
        return np.vstack([np.zeros((1, x.shape[1])), x[:-1]])

    def constraints(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c_lo, c_hi) [n-1, m], both >= 0 when x [n-1, m] is feasible."""
        xp = self.previous(x)
        return x - self.la * xp - self.lb0, self.ha * xp + self.hb0 - x

    def at_z(self, z_lo: np.ndarray, z_hi: np.ndarray) -> np.ndarray:
        """A' z for c_lo = x_i+1 - la x_i - ..., c_hi = ha x_i + ... - x_i+1."""
        out = z_lo - z_hi
        out[:-1] += -self.la[1:] * z_lo[1:] + self.ha[1:] * z_hi[1:]
        return out

    def cost(self, x: np.ndarray) -> float:
        """The discretised Eq. 11 at x [n-1, m] (constant included)."""
        xf = np.vstack([self.x0, x])
        f = self.phi * xf + self.psi
        e = self.tau_ref - np.einsum('npm,nm->np', self.C, f)
        val = 0.5 * np.sum(self.w * np.einsum('np,pq,nq->n', e, self.Q, e))
        val += 0.5 * np.sum(self.k_eff * np.diff(f, axis=0) ** 2)
        if self.P is not None:
            val += 0.5 * float(e[-1] @ np.asarray(self.P, dtype=float) @ e[-1])
        return float(val)


def bounded_lqt_qp(h: float, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                   R: np.ndarray, phi: np.ndarray, psi: np.ndarray, x0: np.ndarray,
                   lo: tuple[np.ndarray, np.ndarray], hi: tuple[np.ndarray, np.ndarray],
                   P: np.ndarray | None = None) -> BoundedLqtQp:
    """The QP of ``solve_bounded_lqt`` (arguments as there)."""
    C = np.asarray(C, dtype=float)
    tau_ref = np.asarray(tau_ref, dtype=float)
    n, p, m = C.shape
    phi = np.asarray(phi, dtype=float)
    psi = np.asarray(psi, dtype=float)
    r = np.asarray(R, dtype=float)
    if r.ndim != 1:
        raise ValueError('solve_bounded_lqt needs a diagonal R [m]')
    Q = np.asarray(Q, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    if n < 2:
        raise ValueError('need at least 2 samples')
    la, lb, ha, hb = (np.broadcast_to(np.asarray(v, dtype=float), (n - 1, m))
                      for v in (*lo, *hi))
    w = np.full(n, h)
    w[0] = w[-1] = 0.5 * h
    # tracking: per sample, in x (samples 1..n-1)
    ctq = np.swapaxes(C, 1, 2) @ Q                                  # [n, m, p]
    T = w[:, None, None] * (ctq @ C)
    b_track = w[:, None] * np.einsum('nmp,np->nm', ctq, tau_ref - np.einsum('npm,nm->np', C,
                                                                             psi))
    if P is not None:
        ctp = C[-1].T @ np.asarray(P, dtype=float)
        T[-1] += ctp @ C[-1]
        b_track[-1] += ctp @ (tau_ref[-1] - C[-1] @ psi[-1])
    T = phi[1:, :, None] * T[1:] * phi[1:, None, :]                 # [n-1, m, m]
    g_lin = -phi[1:] * b_track[1:]
    # effort: rho_i = phi_i+1 x_i+1 - phi_i x_i + (psi_i+1 - psi_i), interval i = 0..n-2
    k_eff = r / h
    d_psi = np.diff(psi, axis=0)
    d_psi[0] -= phi[0] * x0                                         # x_0 is data
    e_diag = np.zeros((n - 1, m))
    e_diag += k_eff * phi[1:] ** 2                                  # as x_i+1 (x-sample i)
    e_diag[:-1] += k_eff * phi[1:-1] ** 2                           # as x_i (intervals 1..)
    e_off = -k_eff * phi[1:-1] * phi[2:]                            # [n-2, m]
    g_lin = g_lin + k_eff * phi[1:] * d_psi
    g_lin[:-1] -= k_eff * phi[1:-1] * d_psi[1:]
    lb0 = lb.copy()
    hb0 = hb.copy()
    lb0[0] += la[0] * x0
    hb0[0] += ha[0] * x0
    return BoundedLqtQp(h=h, x0=x0, C=C, tau_ref=tau_ref, Q=Q, P=P, phi=phi, psi=psi, w=w,
                        k_eff=k_eff, la=la, lb=lb, ha=ha, hb=hb, lb0=lb0, hb0=hb0, T=T,
                        e_diag=e_diag, e_off=e_off, g_lin=g_lin)


def solve_bounded_lqt(h: float, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                      R: np.ndarray, phi: np.ndarray, psi: np.ndarray, x0: np.ndarray,
                      lo: tuple[np.ndarray, np.ndarray], hi: tuple[np.ndarray, np.ndarray],
                      P: np.ndarray | None = None, tol: float = 1e-9,
                      max_iterations: int = 80) -> BoundedLqtSolution:
    """Eq. 11 in discrete time with bounds on the state steps (a convex QP), interior point.

    Grid of n samples, step h [s]; outputs f_i = phi_i x_i + psi_i (elementwise, [n, m]); cost
    1/2 e_n-1' P e_n-1 + 1/2 sum_i w_i e_i' Q e_i + 1/2 sum_i h eta_i' R eta_i with
    e_i = tau_ref_i - C_i f_i (trapezoid weights w), eta_i = (f_i+1 - f_i)/h the interval's
    rate (R diagonal [m]); subject to lo_a x_i + lo_b <= x_i+1 <= hi_a x_i + hi_b per element
    (lo, hi = (slope, offset), each [m] or [n-1, m]); x_0 = x0 given.

    For Stage 2, x are the activations, the bounds are the exact activation steps at u = 0
    and u = 1, and this is the LQT of Eq. 11 (fdot = eta, tau = C f) with the excitation
    limits 0 <= u <= 1 imposed. Primal-dual interior point (Mehrotra predictor-corrector).
    Each Newton step is the unconstrained discrete LQT with time-varying weights (the barrier
    Hessians) whose normal matrix is block-tridiagonal; it is factorised by banded Cholesky,
    which is the discrete Riccati recursion of that LQT written as a matrix factorisation.
    Cost per iteration O(n m^3); typically 20-40 iterations.
    """
    qp = bounded_lqt_qp(h, C, tau_ref, Q, R, phi, psi, x0, lo, hi, P)
    return interior_point(qp, tol=tol, max_iterations=max_iterations)


def interior_point(qp: BoundedLqtQp, tol: float = 1e-9,
                   max_iterations: int = 80) -> BoundedLqtSolution:
    """Primal-dual interior point (Mehrotra) on ``qp``; tol relative to the gradient (residual)
    and to the cost (duality gap)."""
    la, ha, T, x0 = qp.la, qp.ha, qp.T, qp.x0
    n1, m = qp.shape
    diag_idx = np.arange(m)
    # strictly feasible start: the middle of the reachable interval at every step
    x = np.empty((n1, m))
    xi = x0
    for i in range(n1):
        xi = 0.5 * ((la[i] + ha[i]) * xi + qp.lb[i] + qp.hb[i])
        x[i] = xi
    sl = np.stack(qp.constraints(x))                     # slacks [2, n-1, m] (lo, hi)
    z_scale = max(1.0, float(np.max(np.abs(qp.hess_vec(x) + qp.g_lin))))
    z = np.full_like(sl, z_scale)                        # multipliers
    n_con = sl.size
    converged = False
    g_norm = 1.0 + float(np.max(np.abs(qp.g_lin)))
    pbtrf, pbtrs = get_lapack_funcs(('pbtrf', 'pbtrs'), (x,))
    layout = _BandedLayout(n1, m)
    iterations = 0
    while iterations < max_iterations:
        rd = qp.hess_vec(x) + qp.g_lin - qp.at_z(z[0], z[1])
        gap = float(np.sum(sl * z))
        if np.max(np.abs(rd)) <= tol * g_norm and gap <= tol * (1.0 + abs(qp.cost(x))):
            converged = True
            break
        iterations += 1
        mu = gap / n_con
        dd = z / sl
        # normal matrix H + A' diag(z/s) A: block tridiagonal with diagonal couplings
        blocks = T.copy()
        extra = dd[0] + dd[1]
        extra[:-1] += la[1:] ** 2 * dd[0, 1:] + ha[1:] ** 2 * dd[1, 1:]
        blocks[:, diag_idx, diag_idx] += qp.e_diag + extra
        coupling = qp.e_off - la[1:] * dd[0, 1:] - ha[1:] * dd[1, 1:]
        ab = layout.fill(blocks, coupling)
        chol, info = pbtrf(ab, lower=1)
        shift = 1e-14 * float(ab[0].max())
        while info != 0 and shift < 1e-6 * float(ab[0].max()):
            # rounding near the solution (z/s spans many decades): a tiny diagonal shift
            ab[0] += shift
            chol, info = pbtrf(ab, lower=1)
            shift *= 100
        if info != 0:
            break                          # return the last iterate (converged False)

        ops = (chol, pbtrs, rd, sl, z, la, ha, qp.at_z, qp.previous)
        _, ds_a, dz_a = _ip_direction(sl * z, *ops)      # predictor (affine scaling)
        a_aff = _ip_max_step(sl, z, ds_a, dz_a)
        mu_aff = float(np.sum((sl + a_aff * ds_a) * (z + a_aff * dz_a))) / n_con
        sigma = (mu_aff / mu) ** 3
        dx, ds, dz = _ip_direction(sl * z + ds_a * dz_a - sigma * mu, *ops)   # corrector
        alpha = min(1.0, 0.99 * _ip_max_step(sl, z, ds, dz))
        x = x + alpha * dx
        sl = sl + alpha * ds
        z = z + alpha * dz
    xf = np.vstack([x0, x])
    s_lo, s_hi = qp.constraints(x)
    return BoundedLqtSolution(x=xf, f=qp.phi * xf + qp.psi, slack_lo=s_lo, slack_hi=s_hi,
                              z_lo=z[0], z_hi=z[1], cost=qp.cost(x), iterations=iterations,
                              converged=converged)


def _ip_direction(rc: np.ndarray, chol: np.ndarray, pbtrs: Callable, rd: np.ndarray,
                  sl: np.ndarray, z: np.ndarray, la: np.ndarray, ha: np.ndarray,
                  at_z: Callable, prev: Callable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton direction (dx, ds, dz) of the primal-dual system for complementarity targets rc
    (the slacks equal the constraints, which are linear: no primal residual)."""
    q = rc / sl
    rhs = -rd - at_z(q[0], q[1])
    dx = pbtrs(chol, rhs.ravel(), lower=1)[0].reshape(rd.shape)
    dxp = prev(dx)
    ds = np.stack([dx - la * dxp, ha * dxp - dx])
    return dx, ds, -(rc + z * ds) / sl


def _ip_max_step(s: np.ndarray, z: np.ndarray, ds: np.ndarray, dz: np.ndarray) -> float:
    """Largest alpha <= 1 keeping s + alpha ds >= 0 and z + alpha dz >= 0."""
    ratio = np.concatenate([np.where(ds < 0, -s / np.where(ds < 0, ds, -1.0), np.inf).ravel(),
                            np.where(dz < 0, -z / np.where(dz < 0, dz, -1.0), np.inf).ravel()])
    return float(min(1.0, ratio.min()))


