"""The bounded LQT of Stage 2 ('plan' mode): Eq. 11 with 0 <= u <= 1, a convex QP.

Not in the paper. Eq. 11 discretised on the grid (trapezoid tracking, interval-rate effort,
the same Q, R, P) with bounds on every state step (Stage 2: activations between the exact
activation steps at u = 0 and u = 1) is a convex QP with a banded Hessian; ``solve_bounded_lqt``
solves it by a primal-dual interior point whose Newton systems are block tridiagonal (block
Cholesky = the discrete Riccati recursion of that step's LQT). Its active set says which
muscles sit at a bound over which intervals; ``lqt.discrete_lqt`` then gives the feedback law
of that active set.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


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
        val = 0.5 * np.sum(self.w * np.sum((e @ self.Q) * e, axis=1))
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
    Hessians) whose normal matrix is block-tridiagonal; it is factorised by block Cholesky
    (compiled), the discrete Riccati recursion of that LQT written as a matrix factorisation.
    Cost per iteration O(n m^3); typically 20-40 iterations.
    """
    qp = bounded_lqt_qp(h, C, tau_ref, Q, R, phi, psi, x0, lo, hi, P)
    return interior_point(qp, tol=tol, max_iterations=max_iterations)


def interior_point(qp: BoundedLqtQp, tol: float = 1e-9,
                   max_iterations: int = 80) -> BoundedLqtSolution:
    """Primal-dual interior point (Mehrotra) on ``qp``; tol relative to the gradient (residual)
    and to the cost (duality gap).

    Start: the middle of every reachable interval, multipliers at max(1, |gradient|). Each
    Newton system H + A' diag(z/s) A is block tridiagonal (dense [m, m] diagonal blocks,
    diagonal couplings) and is factorised by block Cholesky - the discrete Riccati recursion
    of that step's LQT (compiled, ``_interior_point_kernel``).
    """
    c = np.ascontiguousarray
    n1, m = qp.shape
    cost0 = qp.cost(np.zeros((n1, m)))
    x, z, iterations, converged, cost = _interior_point_kernel(
        c(qp.T), c(qp.e_diag), c(qp.e_off), c(qp.g_lin), c(qp.la), c(qp.ha), c(qp.lb),
        c(qp.hb), c(qp.lb0), c(qp.hb0), c(qp.x0), cost0, float(tol), int(max_iterations))
    xf = np.vstack([qp.x0, x])
    s_lo, s_hi = qp.constraints(x)
    return BoundedLqtSolution(x=xf, f=qp.phi * xf + qp.psi, slack_lo=s_lo, slack_hi=s_hi,
                              z_lo=z[0], z_hi=z[1], cost=cost, iterations=iterations,
                              converged=converged)


# ---------------------------------------------------------------------------- compiled kernel
# The interior point's work is a few dozen operations on [n-1, m] arrays and one block
# tridiagonal factorisation per iteration, with m = 9: numpy's per-call overhead (~1-3 us per
# ufunc, ~30 us per LAPACK call through scipy) was 95 % of its time (profiled: 14 ms per
# 43-interval window, 1.2 ms per iteration). The same algorithm compiled (numba) costs
# ~0.1 ms per iteration.
@numba.njit(cache=True)
def _block_cholesky(blocks: np.ndarray, coupling: np.ndarray, shift: float,
                    lf: np.ndarray, mf: np.ndarray) -> bool:
    """Cholesky of the symmetric block-tridiagonal matrix with diagonal blocks ``blocks``
    [N, m, m] (+ shift I) and lower off-diagonal blocks diag(coupling) [N-1, m]: L_i (lower)
    into lf [N, m, m], M_i = diag(c_i-1) L_i-1^-T into mf [N, m, m]. False if not positive
    definite."""
    nb, m = blocks.shape[0], blocks.shape[1]
    a = np.empty((m, m))
    for i in range(nb):
        for r in range(m):
            for c in range(m):
                a[r, c] = blocks[i, r, c]
            a[r, r] += shift
        if i > 0:
            # M = diag(c) L_prev^-T, row r: c_r * (L_prev^-1 e_r)' ... solve L_prev y = e_r
            for r in range(m):
                cr = coupling[i - 1, r]
                # row r of L_prev^-T transposed = column r of L_prev^-1 ... via forward solve
                for c in range(m):
                    mf[i, r, c] = 0.0
                if cr != 0.0:
                    # y = L_prev^-1 e_r (forward substitution); M[r, :] = cr * y'
                    for c in range(r, m):
                        acc = 1.0 if c == r else 0.0
                        for k in range(r, c):
                            acc -= lf[i - 1, c, k] * mf[i, r, k]
                        mf[i, r, c] = acc / lf[i - 1, c, c]
                    for c in range(r, m):
                        mf[i, r, c] *= cr
            for r in range(m):          # M is upper triangular: (M M')_rc sums k >= r >= c
                for c in range(r + 1):
                    acc = 0.0
                    for k in range(r, m):
                        acc += mf[i, r, k] * mf[i, c, k]
                    a[r, c] -= acc
        for c in range(m):
            d = a[c, c]
            for k in range(c):
                d -= lf[i, c, k] * lf[i, c, k]
            if not d > 0.0:
                return False
            d = np.sqrt(d)
            lf[i, c, c] = d
            for r in range(c + 1, m):
                acc = a[r, c]
                for k in range(c):
                    acc -= lf[i, r, k] * lf[i, c, k]
                lf[i, r, c] = acc / d
            for r in range(c):
                lf[i, r, c] = 0.0
    return True


@numba.njit(cache=True)
def _block_solve(lf: np.ndarray, mf: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> None:
    """Solve with the factors of ``_block_cholesky``: out [N, m] = A^-1 rhs [N, m]."""
    nb, m = rhs.shape
    y = np.empty(m)
    for i in range(nb):
        for r in range(m):
            acc = rhs[i, r]
            if i > 0:
                for k in range(m):
                    acc -= mf[i, r, k] * out[i - 1, k]
            for k in range(r):
                acc -= lf[i, r, k] * out[i, k]
            out[i, r] = acc / lf[i, r, r]
    for i in range(nb - 1, -1, -1):
        for r in range(m):
            y[r] = out[i, r]
        if i < nb - 1:
            for r in range(m):
                acc = 0.0
                for k in range(m):
                    acc += mf[i + 1, k, r] * out[i + 1, k]
                y[r] -= acc
        for r in range(m - 1, -1, -1):
            acc = y[r]
            for k in range(r + 1, m):
                acc -= lf[i, k, r] * out[i, k]
            out[i, r] = acc / lf[i, r, r]


@numba.njit(cache=True)
def _hess_vec(T: np.ndarray, e_diag: np.ndarray, e_off: np.ndarray, x: np.ndarray,
              out: np.ndarray) -> None:
    n1, m = x.shape
    for i in range(n1):
        for r in range(m):
            acc = e_diag[i, r] * x[i, r]
            for c in range(m):
                acc += T[i, r, c] * x[i, c]
            if i < n1 - 1:
                acc += e_off[i, r] * x[i + 1, r]
            if i > 0:
                acc += e_off[i - 1, r] * x[i - 1, r]
            out[i, r] = acc


@numba.njit(cache=True)
def _at_z(la: np.ndarray, ha: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray,
          out: np.ndarray) -> None:
    n1, m = z_lo.shape
    for i in range(n1):
        for r in range(m):
            v = z_lo[i, r] - z_hi[i, r]
            if i < n1 - 1:
                v += -la[i + 1, r] * z_lo[i + 1, r] + ha[i + 1, r] * z_hi[i + 1, r]
            out[i, r] = v


@numba.njit(cache=True)
def _direction(rc: np.ndarray, rd: np.ndarray, sl: np.ndarray, z: np.ndarray,
               la: np.ndarray, ha: np.ndarray, lf: np.ndarray, mf: np.ndarray,
               dx: np.ndarray, ds: np.ndarray, dz: np.ndarray) -> None:
    """Newton direction (dx, ds, dz) of the primal-dual system for complementarity targets
    rc [2, N, m] (the slacks equal the constraints, which are linear: no primal residual)."""
    n1, m = rd.shape
    q = rc / sl
    rhs = np.empty((n1, m))
    _at_z(la, ha, q[0], q[1], rhs)
    for i in range(n1):
        for r in range(m):
            rhs[i, r] = -rd[i, r] - rhs[i, r]
    _block_solve(lf, mf, rhs, dx)
    for i in range(n1):
        for r in range(m):
            xp = dx[i - 1, r] if i > 0 else 0.0
            ds[0, i, r] = dx[i, r] - la[i, r] * xp
            ds[1, i, r] = ha[i, r] * xp - dx[i, r]
    for j in range(2):
        for i in range(n1):
            for r in range(m):
                dz[j, i, r] = -(rc[j, i, r] + z[j, i, r] * ds[j, i, r]) / sl[j, i, r]


@numba.njit(cache=True)
def _max_step(s: np.ndarray, z: np.ndarray, ds: np.ndarray, dz: np.ndarray) -> float:
    """Largest alpha <= 1 keeping s + alpha ds >= 0 and z + alpha dz >= 0."""
    alpha = 1.0
    for j in range(2):
        for i in range(s.shape[1]):
            for r in range(s.shape[2]):
                if ds[j, i, r] < 0:
                    alpha = min(alpha, -s[j, i, r] / ds[j, i, r])
                if dz[j, i, r] < 0:
                    alpha = min(alpha, -z[j, i, r] / dz[j, i, r])
    return alpha


@numba.njit(cache=True)
def _interior_point_kernel(T: np.ndarray, e_diag: np.ndarray, e_off: np.ndarray,
                           g_lin: np.ndarray, la: np.ndarray, ha: np.ndarray, lb: np.ndarray,
                           hb: np.ndarray, lb0: np.ndarray, hb0: np.ndarray, x0: np.ndarray,
                           cost0: float, tol: float, max_iterations: int,
                           ) -> tuple[np.ndarray, np.ndarray, int, bool, float]:
    """``interior_point`` compiled: returns (x [N, m], z [2, N, m], iterations, converged,
    cost at x). cost0: the QP's cost at x = 0 (its constant term)."""
    n1, m = g_lin.shape
    x = np.empty((n1, m))
    xi = x0.copy()
    for i in range(n1):
        for r in range(m):
            xi[r] = 0.5 * ((la[i, r] + ha[i, r]) * xi[r] + lb[i, r] + hb[i, r])
            x[i, r] = xi[r]
    sl = np.empty((2, n1, m))
    for i in range(n1):
        for r in range(m):
            xp = x[i - 1, r] if i > 0 else 0.0
            sl[0, i, r] = x[i, r] - la[i, r] * xp - lb0[i, r]
            sl[1, i, r] = ha[i, r] * xp + hb0[i, r] - x[i, r]
    hx = np.empty((n1, m))
    _hess_vec(T, e_diag, e_off, x, hx)
    z_scale = max(1.0, np.max(np.abs(hx + g_lin)))
    z = np.full((2, n1, m), z_scale)
    n_con = 2 * n1 * m
    g_norm = 1.0 + np.max(np.abs(g_lin))
    lf = np.zeros((n1, m, m))
    mf = np.zeros((n1, m, m))
    blocks = np.empty((n1, m, m))
    coupling = np.empty((max(n1 - 1, 0), m))
    rd = np.empty((n1, m))
    az = np.empty((n1, m))
    dx = np.empty((n1, m))
    ds = np.empty((2, n1, m))
    dz = np.empty((2, n1, m))
    dx_a = np.empty((n1, m))
    ds_a = np.empty((2, n1, m))
    dz_a = np.empty((2, n1, m))
    converged = False
    iterations = 0
    while iterations < max_iterations:
        _hess_vec(T, e_diag, e_off, x, hx)
        _at_z(la, ha, z[0], z[1], az)
        rmax = 0.0
        for i in range(n1):
            for r in range(m):
                rd[i, r] = hx[i, r] + g_lin[i, r] - az[i, r]
                rmax = max(rmax, abs(rd[i, r]))
        gap = np.sum(sl * z)
        if rmax <= tol * g_norm:
            cost = cost0
            for i in range(n1):
                for r in range(m):
                    cost += x[i, r] * (0.5 * hx[i, r] + g_lin[i, r])
            if gap <= tol * (1.0 + abs(cost)):
                converged = True
                break
        iterations += 1
        mu = gap / n_con
        dmax = 0.0
        for i in range(n1):
            for r in range(m):
                d0, d1 = z[0, i, r] / sl[0, i, r], z[1, i, r] / sl[1, i, r]
                extra = d0 + d1
                if i < n1 - 1:
                    e0, e1 = z[0, i + 1, r] / sl[0, i + 1, r], z[1, i + 1, r] / sl[1, i + 1, r]
                    extra += la[i + 1, r] ** 2 * e0 + ha[i + 1, r] ** 2 * e1
                    coupling[i, r] = e_off[i, r] - la[i + 1, r] * e0 - ha[i + 1, r] * e1
                for c in range(m):
                    blocks[i, r, c] = T[i, r, c]
                blocks[i, r, r] += e_diag[i, r] + extra
                dmax = max(dmax, blocks[i, r, r])
        ok = _block_cholesky(blocks, coupling, 0.0, lf, mf)
        shift = 1e-14 * dmax
        total = 0.0
        while not ok and shift < 1e-6 * dmax:
            # rounding near the solution (z/s spans many decades): a tiny diagonal shift
            total += shift
            ok = _block_cholesky(blocks, coupling, total, lf, mf)
            shift *= 100
        if not ok:
            break                          # return the last iterate (converged False)
        _direction(sl * z, rd, sl, z, la, ha, lf, mf, dx_a, ds_a, dz_a)   # predictor
        a_aff = _max_step(sl, z, ds_a, dz_a)
        mu_aff = np.sum((sl + a_aff * ds_a) * (z + a_aff * dz_a)) / n_con
        sigma = (mu_aff / mu) ** 3
        _direction(sl * z + ds_a * dz_a - sigma * mu, rd, sl, z, la, ha, lf, mf, dx, ds, dz)
        alpha = min(1.0, 0.99 * _max_step(sl, z, ds, dz))
        x += alpha * dx
        sl += alpha * ds
        z += alpha * dz
    _hess_vec(T, e_diag, e_off, x, hx)
    cost = cost0
    for i in range(n1):
        for r in range(m):
            cost += x[i, r] * (0.5 * hx[i, r] + g_lin[i, r])
    return x, z, iterations, converged, cost
