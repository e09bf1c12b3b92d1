"""Linear-quadratic tracking (LQT) of Stage 2: Riccati (Eq. 12) and adjoint (Eq. 13), Eq. 14.

System (METHOD.md Eq. 10): fdot = eta, tau = C(t) f, i.e. A = 0, B = I, with f[m] the
musculotendon forces, C(t)[p, m] the moment arms and tau_ref(t)[p] the torque reference.
Cost (Eq. 11): J = 1/2 e(tf)' P e(tf) + 1/2 int (e' Q e + eta' R eta) dt, e = tau_ref - C f.
Integrated backward from tf:

    -Wdot = -W R^-1 W + C' Q C,                W(tf) = C' P C               (12)
    -gdot = -(R^-1 W)' g + C' Q tau_ref,       g(tf) = C' P tau_ref(tf)     (13)
    eta   = -R^-1 W f + R^-1 g                                              (14)

Integrator (why): the closed-loop rates sqrt(eig(R^-1 C'QC)) reach ~1300 1/s for the paper's
weights, so an explicit scheme needs steps < ~1 ms and substeps on a 120 Hz grid. Instead each
grid interval is solved EXACTLY for frozen coefficients: M = C'QC is held at the interval mean
of its end values and b = C'Q tau_ref varies linearly (second order in h overall, exact for
constant C). With Wt = R^-1/2 W R^-1/2, gt = R^-1/2 g, Mt = R^-1/2 M R^-1/2 = V diag(mu^2) V'
and s = backward time, the Hamiltonian flow [[0, I], [mu^2, 0]] is diagonal in V, and the
linear-fractional (Davison-Maki / Moebius) map of one step, Z = V' Wt V, x = mu h, is

    Z1 = diag(mu tanh x) + E K E,    K = (I + Z0 D)^-1 Z0,   E = sech x,  D = tanh(x)/mu
    gh1 = E (I + Z0 D)^-1 gh0 + [D - E K N] bh_a + [Pb - E K Pd] beta

(gh = V' gt, bh = V' R^-1/2 b, N, Pb, Pd closed-form functions of x, below). Every factor is
bounded (E, tanh <= 1, D <= h): no exponential growth, no overflow for any step, Z1 is
symmetric and positive semi-definite whenever Z0 is, and the co-contraction directions
(mu = 0, unobservable) are handled by the series of the same functions. The same exact step
for a general (A, B) uses the matrix exponential of the augmented Hamiltonian
(``solve_lqt(..., A=, B=)``); the two paths agree for A = 0, B = I (tested).

The forward closed loop fdot = R^-1 (g - W f) is likewise solved exactly per interval
(``closed_loop_coefficients``; exponential integrator, W frozen at the interval mean, g linear).
Any step is stable. Accuracy: second order where mu h is small; where mu h >> 1 the stiff modes
sit at the quasi-steady value of the frozen coefficients, which lags the time variation of C by
O(h) - so the Stage 2 tracker refines coarse inputs to <= 1 ms internally (``max_step``).

Bounds (not in the paper; Stage 2's default 'plan' mode): ``solve_bounded_lqt`` solves Eq. 11
discretised on the grid with bounds on every state step (Stage 2: activations between the
exact activation steps at u = 0 and u = 1), a convex QP, by a primal-dual interior point whose
Newton systems are block tridiagonal (banded Cholesky = the discrete Riccati recursion of that
step's LQT). ``discrete_lqt`` is the Riccati / adjoint / feedback recursion (Eqs. 12-14 in
discrete time) of the same discretised cost for given held elements (the QP's active set);
without held elements it converges to the continuous solution at second order in h (tested).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, get_lapack_funcs

#: Below this x = mu h the step functions are evaluated by their Taylor series.
_SERIES_X = 0.02


# ---------------------------------------------------------------------------- step functions
def _sech(x: np.ndarray) -> np.ndarray:
    e = np.exp(-x)
    return 2.0 * e / (1.0 + e * e)


def _step_functions(mu: np.ndarray, h: float) -> dict[str, np.ndarray]:
    """Exact-step coefficients [..., m] for modes with rate mu >= 0 over a step h.

    lam_t = mu tanh x, sech = sech x, d = tanh(x)/mu, n = (1 - sech x)/mu^2,
    pb = (x tanh x - 1 + sech x)/mu^2, pd = (tanh(x)/mu - h sech x)/mu^2, x = mu h.
    """
    x = mu * h
    small = x < _SERIES_X
    xs = np.where(small, 1.0, x)             # safe denominators
    x2 = x * x
    th = np.tanh(x)
    se = _sech(x)
    d = np.where(small, h * (1 - x2 / 3 + 2 * x2 * x2 / 15), h * th / xs)
    n = np.where(small, h * h * (0.5 - 5 * x2 / 24 + 61 * x2 * x2 / 720),
                 h * h * (1 - se) / xs ** 2)
    pb = np.where(small, h * h * (0.5 - x2 / 8 + 7 * x2 * x2 / 144),
                  h * h * (x * th - 1 + se) / xs ** 2)
    pd = np.where(small, h ** 3 * (1 / 6 - 3 * x2 / 40 + 31 * x2 * x2 / 1008),
                  h ** 3 * (th / xs - se) / xs ** 2)
    return {'lam_t': mu * th, 'sech': se, 'd': d, 'n': n, 'pb': pb, 'pd': pd}


def _decay_functions(omega: np.ndarray, h: float) -> tuple[np.ndarray, ...]:
    """exp(-x), h phi1(x), h phi2(x) for ydot = -omega y + gamma(t), gamma linear, x = omega h.

    y(h) = exp(-x) y0 + h phi1 gamma0 + h phi2 (gamma1 - gamma0),
    phi1 = (1 - exp(-x))/x, phi2 = (x - 1 + exp(-x))/x^2.
    """
    x = np.maximum(omega, 0.0) * h
    small = x < _SERIES_X
    xs = np.where(small, 1.0, x)
    ex = np.exp(-x)
    phi1 = np.where(small, 1 - x / 2 + x * x / 6 - x ** 3 / 24, (1 - ex) / xs)
    phi2 = np.where(small, 0.5 - x / 6 + x * x / 24 - x ** 3 / 120, (x - 1 + ex) / xs ** 2)
    return ex, h * phi1, h * phi2


def _sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def _inv_sqrt_spd(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R^-1/2 and R^1/2 of a symmetric positive-definite R (or a diagonal given as [m])."""
    r = np.asarray(r, dtype=float)
    if r.ndim == 1:
        if np.any(r <= 0):
            raise ValueError('R must be positive definite')
        return np.diag(1 / np.sqrt(r)), np.diag(np.sqrt(r))
    w, u = np.linalg.eigh(_sym(r))
    if np.any(w <= 0):
        raise ValueError('R must be positive definite')
    return (u / np.sqrt(w)) @ u.T, (u * np.sqrt(w)) @ u.T


# ---------------------------------------------------------------------------- the grid recipe
@dataclass(frozen=True)
class LqtGrid:
    """Per-sample and per-interval data of the A = 0, B = I problem on a uniform grid.

    All matrices in the scaled coordinates (Wt = R^-1/2 W R^-1/2, gt = R^-1/2 g,
    ft = R^1/2 f). Intervals i = [t_i, t_i+1], i = 0..n-2. Independent of the window: the
    backward sweeps of every window share it.
    """

    t: np.ndarray              # [n] s
    h: float                   # s
    r_inv_sqrt: np.ndarray     # [m, m]  R^-1/2
    r_sqrt: np.ndarray         # [m, m]  R^1/2
    m_tilde: np.ndarray        # [n, m, m]  R^-1/2 C'QC R^-1/2 at the samples
    b_tilde: np.ndarray        # [n, m]     R^-1/2 C'Q tau_ref at the samples
    wt_terminal: np.ndarray    # [n, m, m]  R^-1/2 C'PC R^-1/2 (terminal value if tf = t_i)
    gt_terminal: np.ndarray    # [n, m]     R^-1/2 C'P tau_ref
    v: np.ndarray              # [n-1, m, m]  eigenvectors of the interval-mean m_tilde
    coef: dict[str, np.ndarray]  # [n-1, m]: _step_functions + projected forcing

    @property
    def n(self) -> int:
        return self.t.shape[0]

    @property
    def m(self) -> int:
        return self.m_tilde.shape[-1]

    def unscale_w(self, wt: np.ndarray) -> np.ndarray:
        """W = R^1/2 Wt R^1/2 (any leading axes)."""
        return self.r_sqrt @ wt @ self.r_sqrt

    def unscale_g(self, gt: np.ndarray) -> np.ndarray:
        """g = R^1/2 gt (any leading axes)."""
        return gt @ self.r_sqrt.T


def _uniform_step(t: np.ndarray) -> float:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError('t must be a 1-D grid of at least 2 samples')
    dt = np.diff(t)
    h = float(dt.mean())
    if h <= 0 or np.max(np.abs(dt - h)) > 1e-4 * h:   # (time stamps in ns jitter ~1e-6 h)
        raise ValueError('t must be uniform and increasing')
    return h


def prepare_grid(t: np.ndarray, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                 R: np.ndarray, P: np.ndarray | None = None) -> LqtGrid:
    """Precompute the scaled problem and the exact-step coefficients of every interval.

    t [n] uniform (s); C [n, p, m]; tau_ref [n, p]; Q [p, p]; R [m, m] SPD (or its diagonal
    [m]); P [p, p] terminal weight (default 0). Vectorised over samples (batched eigh).
    """
    h = _uniform_step(t)
    C = np.asarray(C, dtype=float)
    tau_ref = np.asarray(tau_ref, dtype=float)
    n, p, m = C.shape
    if tau_ref.shape != (n, p) or np.shape(t) != (n,):
        raise ValueError(f'shapes: t {np.shape(t)}, C {C.shape}, tau_ref {tau_ref.shape}')
    Q = np.asarray(Q, dtype=float)
    P = np.zeros((p, p)) if P is None else np.asarray(P, dtype=float)
    r_is, r_s = _inv_sqrt_spd(R)
    ct = C @ r_is                                          # [n, p, m]  C R^-1/2
    ctt = np.swapaxes(ct, 1, 2)
    m_tilde = _sym(ctt @ Q @ ct)
    b_tilde = np.einsum('nip,np->ni', ctt @ Q, tau_ref)
    wt_terminal = _sym(ctt @ P @ ct)
    gt_terminal = np.einsum('nip,np->ni', ctt @ P, tau_ref)
    mu2, v = np.linalg.eigh(0.5 * (m_tilde[1:] + m_tilde[:-1]))
    mu = np.sqrt(np.maximum(mu2, 0.0))
    coef = _step_functions(mu, h)
    # the adjoint's forcing over each interval, b linear from b(t_i+1) (s = 0) to b(t_i),
    # projected on the interval's eigenvectors: it does not depend on the recursion
    vt = np.swapaxes(v, 1, 2)
    ba = (vt @ b_tilde[1:, :, None])[..., 0]
    beta = (vt @ (b_tilde[:-1] - b_tilde[1:])[..., None])[..., 0] / h
    coef['lin'] = coef['d'] * ba + coef['pb'] * beta      # through diag(mu tanh x)
    coef['quad'] = coef['n'] * ba + coef['pd'] * beta     # through E K
    return LqtGrid(t=np.asarray(t, dtype=float), h=h, r_inv_sqrt=r_is, r_sqrt=r_s,
                   m_tilde=m_tilde, b_tilde=b_tilde, wt_terminal=wt_terminal,
                   gt_terminal=gt_terminal, v=v, coef=coef)


def concat_grids(first: LqtGrid, second: LqtGrid) -> LqtGrid:
    """Join two grids; ``second`` starts at the last sample of ``first`` (shared sample)."""
    if abs(second.t[0] - first.t[-1]) > 1e-9 * max(1.0, abs(first.t[-1])) or \
            abs(second.h - first.h) > 1e-4 * first.h:
        raise ValueError('grids must share their joining sample and step')
    per_sample = ('t', 'm_tilde', 'b_tilde', 'wt_terminal', 'gt_terminal')
    joined = {k: np.concatenate([getattr(first, k), getattr(second, k)[1:]])
              for k in per_sample}
    return LqtGrid(h=first.h, r_inv_sqrt=first.r_inv_sqrt, r_sqrt=first.r_sqrt,
                   v=np.concatenate([first.v, second.v]),
                   coef={k: np.concatenate([first.coef[k], second.coef[k]]) for k in first.coef},
                   **joined)


def tail_grid(grid: LqtGrid, k: int) -> LqtGrid:
    """The grid without its first k samples (and intervals)."""
    per_sample = ('t', 'm_tilde', 'b_tilde', 'wt_terminal', 'gt_terminal')
    return LqtGrid(h=grid.h, r_inv_sqrt=grid.r_inv_sqrt, r_sqrt=grid.r_sqrt, v=grid.v[k:],
                   coef={name: c[k:] for name, c in grid.coef.items()},
                   **{name: getattr(grid, name)[k:] for name in per_sample})


def backward_sweep(grid: LqtGrid, starts: np.ndarray, length: int, keep: int,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Integrate Eqs. 12-13 backward on windows [starts_k, starts_k + length] (batched).

    Windows that would pass the last sample end there (terminal condition at t_n-1; the
    missing steps are identity steps). Returns (Wt [K, keep, m, m], gt [K, keep, m]) at the
    first ``keep`` samples of each window (scaled coordinates). What does not depend on the
    recursion (step coefficients, projected forcing) is per interval in ``grid`` and gathered
    up front; the loop over the ``length`` steps is a few batched [K, m, m] products and one
    batched solve.
    """
    starts = np.atleast_1d(np.asarray(starts, dtype=int))
    n, m = grid.n, grid.m
    if length < 1 or keep < 1 or keep > length + 1:
        raise ValueError('need 1 <= keep <= length + 1')
    ends = np.minimum(starts + length, n - 1)
    if np.any(starts < 0) or np.any(starts >= ends):
        raise ValueError('window starts must lie in [0, n - 2]')
    K = starts.size
    idx = starts[:, None] + np.arange(length)[None, :]                 # [K, L] intervals
    valid = (idx < ends[:, None])[..., None]
    idx = np.where(valid[..., 0], idx, 0)
    # identity steps beyond a window's end: lam_t = d = forcing = 0, sech = 1
    c = {k: np.where(valid, grid.coef[k][idx], 0.0) for k in ('lam_t', 'd', 'lin', 'quad')}
    c['sech'] = np.where(valid, grid.coef['sech'][idx], 1.0)
    wt = grid.wt_terminal[ends].copy()
    gt = grid.gt_terminal[ends].copy()
    w_keep = np.empty((K, keep, m, m))
    g_keep = np.empty((K, keep, m))
    if keep == length + 1:
        w_keep[:, length] = wt
        g_keep[:, length] = gt
    eye = np.eye(m)
    diag = np.arange(m)
    for j in range(length - 1, -1, -1):
        vj = grid.v[idx[:, j]]
        vtj = np.swapaxes(vj, 1, 2)
        d, se = c['d'][:, j], c['sech'][:, j]
        z0 = vtj @ wt @ vj
        gh0 = vtj @ gt[..., None]
        sol = np.linalg.solve(eye + z0 * d[:, None, :], np.concatenate([z0, gh0], axis=2))
        kk = _sym(sol[:, :, :m])
        ek = se[:, :, None] * kk
        z1 = ek * se[:, None, :]
        z1[:, diag, diag] += c['lam_t'][:, j]
        gh1 = se * sol[:, :, m] + c['lin'][:, j] - (ek @ c['quad'][:, j, :, None])[..., 0]
        wt = _sym(vj @ z1 @ vtj)
        gt = (vj @ gh1[..., None])[..., 0]
        if j < keep:
            w_keep[:, j] = wt
            g_keep[:, j] = gt
    return w_keep, g_keep


# ---------------------------------------------------------------------------- full solution
@dataclass(frozen=True)
class LqtSolution:
    """W [n, m, m], g [n, m] of Eqs. 12-13 on the grid t [n] (physical units)."""

    t: np.ndarray
    W: np.ndarray
    g: np.ndarray
    R: np.ndarray

    def control(self, f: np.ndarray) -> np.ndarray:
        """Eq. 14 at every sample: eta [n, m] for forces f [n, m]."""
        return lqt_control(self.W, self.g, f, self.R)


def lqt_control(W: np.ndarray, g: np.ndarray, f: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Eq. 14: eta = -R^-1 W f + R^-1 g (any leading axes; R [m, m] or its diagonal [m])."""
    rhs = g - np.einsum('...ij,...j->...i', W, f)
    R = np.asarray(R, dtype=float)
    if R.ndim == 1:
        return rhs / R
    return np.linalg.solve(R, rhs[..., None])[..., 0]


def solve_lqt(t: np.ndarray, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray, R: np.ndarray,
              P: np.ndarray | None = None, A: np.ndarray | None = None,
              B: np.ndarray | None = None) -> LqtSolution:
    """Eqs. 12-13 backward over the whole grid (the paper's full horizon).

    t [n] uniform; C [n, p, m] (or [p, m], constant); tau_ref [n, p]; Q [p, p]; R [m, m]
    (or diagonal [m]); P [p, p] (default 0). Optional constant A [m, m], B [m, k] give the
    general LQT (R then [k, k]): -Wdot = A'W + WA - W B R^-1 B' W + C'QC,
    -gdot = (A - B R^-1 B' W)' g + C'Q tau_ref (exact step by the matrix exponential).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    C = np.asarray(C, dtype=float)
    if C.ndim == 2:
        C = np.broadcast_to(C, (n, *C.shape))
    R_mat = np.diag(R) if np.ndim(R) == 1 else np.asarray(R, dtype=float)
    if A is None and B is None:
        grid = prepare_grid(t, C, tau_ref, Q, R, P)
        wt, gt = backward_sweep(grid, np.array([0]), n - 1, n)
        return LqtSolution(t=t, W=_sym(grid.unscale_w(wt[0])), g=grid.unscale_g(gt[0]),
                           R=R_mat)
    m = C.shape[2]
    A = np.zeros((m, m)) if A is None else np.asarray(A, dtype=float)
    B = np.eye(m) if B is None else np.asarray(B, dtype=float)
    W, g = _general_sweep(t, C, np.asarray(tau_ref, dtype=float), np.asarray(Q, dtype=float),
                          R_mat, P, A, B)
    return LqtSolution(t=t, W=W, g=g, R=R_mat)


def _general_sweep(t: np.ndarray, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                   R: np.ndarray, P: np.ndarray | None, A: np.ndarray, B: np.ndarray,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Exact-step sweep for general constant (A, B): Moebius map of expm(augmented Hamiltonian).

    Backward time s: d[x; lam]/ds = [[-A, S], [M, A']] [x; lam] + [0; -b(s)], S = B R^-1 B',
    lam = W x - g. With Phi, (pf, pl) the flow and the forced response of one step,
    W1 = (Phi21 + Phi22 W0)(Phi11 + Phi12 W0)^-1, g1 = (Phi22 - W1 Phi12) g0 + W1 pf - pl.
    M frozen at the interval mean, b linear in s (augmented states 1 and s).
    """
    h = _uniform_step(t)
    n, p, m = C.shape
    P = np.zeros((p, p)) if P is None else np.asarray(P, dtype=float)
    S = B @ np.linalg.solve(R, B.T)
    Ct = np.swapaxes(C, 1, 2)
    M = _sym(Ct @ Q @ C)
    b = np.einsum('nip,np->ni', Ct @ Q, tau_ref)
    W = np.empty((n, m, m))
    g = np.empty((n, m))
    W[-1] = _sym(C[-1].T @ P @ C[-1])
    g[-1] = C[-1].T @ P @ tau_ref[-1]
    big = np.zeros((2 * m + 2, 2 * m + 2))
    big[:m, :m] = -A
    big[:m, m:2 * m] = S
    big[m:2 * m, m:2 * m] = A.T
    big[2 * m + 1, 2 * m] = 1.0
    for i in range(n - 2, -1, -1):
        big[m:2 * m, :m] = 0.5 * (M[i] + M[i + 1])
        big[m:2 * m, 2 * m] = -b[i + 1]
        big[m:2 * m, 2 * m + 1] = -(b[i] - b[i + 1]) / h
        phi = expm(big * h)
        p11, p12 = phi[:m, :m], phi[:m, m:2 * m]
        p21, p22 = phi[m:2 * m, :m], phi[m:2 * m, m:2 * m]
        pf, pl = phi[:m, 2 * m], phi[m:2 * m, 2 * m]
        x = p11 + p12 @ W[i + 1]
        y = p21 + p22 @ W[i + 1]
        w1 = _sym(np.linalg.solve(x.T, y.T).T)
        W[i] = w1
        g[i] = (p22 - w1 @ p12) @ g[i + 1] + w1 @ pf - pl
    return W, g


# ---------------------------------------------------------------------------- forward loop
def closed_loop_coefficients(wt: np.ndarray, h: float) -> dict[str, np.ndarray]:
    """Exact-step data of ft_dot = -Wt ft + gt(t) on intervals, Wt frozen at the interval mean.

    wt [..., k+1, m, m] at the samples of k intervals. Returns u [..., k, m, m] (eigenvectors
    of the interval mean), decay = exp(-omega h), hphi1, hphi2 [..., k, m] for ``advance``.
    """
    omega, u = np.linalg.eigh(_sym(0.5 * (wt[..., 1:, :, :] + wt[..., :-1, :, :])))
    decay, hphi1, hphi2 = _decay_functions(omega, h)
    return {'u': u, 'decay': decay, 'hphi1': hphi1, 'hphi2': hphi2}


def closed_loop_advance(ft0: np.ndarray, gt0: np.ndarray, gt1: np.ndarray, u: np.ndarray,
                        decay: np.ndarray, hphi1: np.ndarray, hphi2: np.ndarray) -> np.ndarray:
    """One interval of ft_dot = -Wt ft + gt (Eq. 14 closed loop, scaled): ft at its end."""
    y0 = ft0 @ u
    c0 = gt0 @ u
    c1 = gt1 @ u
    return u @ (decay * y0 + hphi1 * c0 + hphi2 * (c1 - c0))


def simulate_linear(sol: LqtSolution, f0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed loop fdot = eta (Eq. 14) of the linear system (10) from f0: (f [n, m], eta [n, m]).

    Exact per interval (W frozen at the interval mean, g linear); no muscle model.
    """
    h = _uniform_step(sol.t)
    r_is, r_s = _inv_sqrt_spd(sol.R)
    wt = r_is @ sol.W @ r_is
    gt = sol.g @ r_is.T
    cl = closed_loop_coefficients(wt, h)
    n = sol.t.size
    ft = np.empty((n, wt.shape[-1]))
    ft[0] = r_s @ np.asarray(f0, dtype=float)
    for i in range(n - 1):
        ft[i + 1] = closed_loop_advance(ft[i], gt[i], gt[i + 1], cl['u'][i], cl['decay'][i],
                                        cl['hphi1'][i], cl['hphi2'][i])
    f = ft @ r_is.T
    return f, sol.control(f)


def tracking_cost(t: np.ndarray, f: np.ndarray, eta: np.ndarray, C: np.ndarray,
                  tau_ref: np.ndarray, Q: np.ndarray, R: np.ndarray,
                  P: np.ndarray | None = None) -> float:
    """Eq. 11 by the trapezoidal rule: f, eta [n, m]; C [n, p, m]; tau_ref [n, p]."""
    e = tau_ref - np.einsum('npm,nm->np', C, f)
    R = np.diag(R) if np.ndim(R) == 1 else np.asarray(R, dtype=float)
    run = np.einsum('np,pq,nq->n', e, Q, e) + np.einsum('nm,mk,nk->n', eta, R, eta)
    dt = np.diff(t)
    total = 0.5 * float(np.sum(0.5 * (run[1:] + run[:-1]) * dt))
    if P is not None:
        total += 0.5 * float(e[-1] @ P @ e[-1])
    return total


# ---------------------------------------------------------------------------- bounded LQT
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


def solve_bounded_lqt(h: float, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                      R: np.ndarray, phi: np.ndarray, psi: np.ndarray, x0: np.ndarray,
                      lo: tuple[np.ndarray, np.ndarray], hi: tuple[np.ndarray, np.ndarray],
                      P: np.ndarray | None = None, tol: float = 1e-9,
                      max_iterations: int = 80) -> BoundedLqtSolution:
    """Eq. 11 in discrete time with bounds on the state steps (a convex QP), interior point.

    Grid of n samples, step h; outputs f_i = phi_i x_i + psi_i (elementwise, [n, m]); cost
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
    la, lb = (np.broadcast_to(np.asarray(v, dtype=float), (n - 1, m)) for v in lo)
    ha, hb = (np.broadcast_to(np.asarray(v, dtype=float), (n - 1, m)) for v in hi)
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
    diag_idx = np.arange(m)

    def hess_vec(x: np.ndarray) -> np.ndarray:
        out = np.einsum('kij,kj->ki', T, x) + e_diag * x
        out[:-1] += e_off * x[1:]
        out[1:] += e_off * x[:-1]
        return out

    def prev(x: np.ndarray) -> np.ndarray:
        """x_i for the intervals i = 0..n-2 (x_0 the data; zero for directions)."""
        return np.vstack([np.zeros((1, m)), x[:-1]])

    lb0 = lb.copy()
    hb0 = hb.copy()
    lb0[0] += la[0] * x0
    hb0[0] += ha[0] * x0

    def constraints(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xp = prev(x)
        return x - la * xp - lb0, ha * xp + hb0 - x

    def at_z(z_lo: np.ndarray, z_hi: np.ndarray) -> np.ndarray:
        """A' z for c_lo = x_i+1 - la x_i - ..., c_hi = ha x_i + ... - x_i+1."""
        out = z_lo - z_hi
        out[:-1] += -la[1:] * z_lo[1:] + ha[1:] * z_hi[1:]
        return out

    def cost(x: np.ndarray) -> float:
        xf = np.vstack([x0, x])
        f = phi * xf + psi
        e = tau_ref - np.einsum('npm,nm->np', C, f)
        val = 0.5 * np.sum(w * np.einsum('np,pq,nq->n', e, Q, e))
        val += 0.5 * np.sum(k_eff * np.diff(f, axis=0) ** 2)
        if P is not None:
            val += 0.5 * float(e[-1] @ np.asarray(P, dtype=float) @ e[-1])
        return float(val)

    # strictly feasible start: the middle of the reachable interval at every step
    x = np.empty((n - 1, m))
    xi = x0
    for i in range(n - 1):
        xi = 0.5 * ((la[i] + ha[i]) * xi + lb[i] + hb[i])
        x[i] = xi
    sl = np.stack(constraints(x))                        # slacks [2, n-1, m] (lo, hi)
    z_scale = max(1.0, float(np.max(np.abs(hess_vec(x) + g_lin))))
    z = np.full_like(sl, z_scale)                        # multipliers
    n_con = sl.size
    converged = False
    g_norm = 1.0 + float(np.max(np.abs(g_lin)))
    pbtrf, pbtrs = get_lapack_funcs(('pbtrf', 'pbtrs'), (x,))
    layout = _BandedLayout(n - 1, m)
    iterations = 0
    while iterations < max_iterations:
        rd = hess_vec(x) + g_lin - at_z(z[0], z[1])
        gap = float(np.sum(sl * z))
        if np.max(np.abs(rd)) <= tol * g_norm and gap <= tol * (1.0 + abs(cost(x))):
            converged = True
            break
        iterations += 1
        mu = gap / n_con
        dd = z / sl
        # normal matrix H + A' diag(z/s) A: block tridiagonal with diagonal couplings
        blocks = T.copy()
        extra = dd[0] + dd[1]
        extra[:-1] += la[1:] ** 2 * dd[0, 1:] + ha[1:] ** 2 * dd[1, 1:]
        blocks[:, diag_idx, diag_idx] += e_diag + extra
        coupling = e_off - la[1:] * dd[0, 1:] - ha[1:] * dd[1, 1:]
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

        ops = (chol, pbtrs, rd, sl, z, la, ha, at_z, prev)
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
    s_lo, s_hi = constraints(x)
    return BoundedLqtSolution(x=xf, f=phi * xf + psi, slack_lo=s_lo, slack_hi=s_hi,
                              z_lo=z[0], z_hi=z[1], cost=cost(x), iterations=iterations,
                              converged=converged)


def _ip_direction(rc: np.ndarray, chol: np.ndarray, pbtrs: callable, rd: np.ndarray,
                  sl: np.ndarray, z: np.ndarray, la: np.ndarray, ha: np.ndarray,
                  at_z: callable, prev: callable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


# ---------------------------------------------------------------------------- discrete LQT
@dataclass(frozen=True)
class DiscreteLqt:
    """Discrete-time Eqs. 12-14 on a grid of n samples: V_i(x) = 1/2 x' S_i x - s_i' x + c.

    S [n, m, m] (the discrete W, in the coordinates x), s [n, m] (the discrete g); the optimal
    input of interval i is v_i = -K_i x_i + k_i (K [n-1, m, m], k [n-1, m]: the discrete
    Eq. 14).
    """

    S: np.ndarray
    s: np.ndarray
    K: np.ndarray
    k: np.ndarray

    def simulate(self, x0: np.ndarray, E: np.ndarray, free: np.ndarray,
                 c: np.ndarray) -> np.ndarray:
        """x [n, m] of the closed loop x_i+1 = E_i x_i + B_i (-K_i x_i + k_i) + c_i."""
        x = np.empty((self.S.shape[0], np.size(x0)))
        x[0] = x0
        for i in range(x.shape[0] - 1):
            v = self.k[i] - self.K[i] @ x[i]
            x[i + 1] = E[i] * x[i] + np.where(free[i], v, 0.0) + c[i]
        return x


def discrete_lqt(h: float, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 phi: np.ndarray, psi: np.ndarray, E: np.ndarray | None = None,
                 free: np.ndarray | None = None, c: np.ndarray | None = None,
                 P: np.ndarray | None = None) -> DiscreteLqt:
    """Backward Riccati/adjoint recursion of the discretised Eq. 11 of ``solve_bounded_lqt``
    for x_i+1 = E_i x_i + B_i v_i + c_i, B_i = diag(free_i), outputs f = phi x + psi.

    Free elements (``free`` True; E = 1, c = 0 there) move by their input v; the others follow
    a given diagonal affine map and carry no input (Stage 2: a muscle held at u = 0 or 1
    follows its own activation step). The cost is that of ``solve_bounded_lqt`` (trapezoid
    tracking, 1/2 h |(f_i+1 - f_i)/h|_R^2 effort, R diagonal [m]); a held element's effort
    becomes a state cost. With every element free and phi = 1, psi = 0 this is the discrete
    counterpart of Eqs. 12-14 for A = 0, B = I (x = f, v = h eta). The recursion is the exact
    minimiser of the discrete problem, so with the active set of ``solve_bounded_lqt`` it
    reproduces that solution (tested).
    """
    C = np.asarray(C, dtype=float)
    tau_ref = np.asarray(tau_ref, dtype=float)
    n, p, m = C.shape
    r = np.asarray(R, dtype=float)
    if r.ndim != 1:
        raise ValueError('discrete_lqt needs a diagonal R [m]')
    phi = np.asarray(phi, dtype=float)
    psi = np.asarray(psi, dtype=float)
    E = np.ones((n - 1, m)) if E is None else np.asarray(E, dtype=float)
    free = np.ones((n - 1, m), dtype=bool) if free is None else np.asarray(free, dtype=bool)
    c = np.zeros((n - 1, m)) if c is None else np.asarray(c, dtype=float)
    Q = np.asarray(Q, dtype=float)
    w = np.full(n, h)
    w[0] = w[-1] = 0.5 * h
    ctq = np.swapaxes(C, 1, 2) @ Q
    track = w[:, None, None] * (phi[:, :, None] * (ctq @ C) * phi[:, None, :])
    track_lin = w[:, None] * phi * np.einsum('nmp,np->nm', ctq, tau_ref - np.einsum(
        'npm,nm->np', C, psi))
    rh = r / h
    B = free.astype(float)
    # effort of interval i: 1/2 |G x_i + H v_i + d|^2_Rh, f_i+1 - f_i = G x + H v + d
    G = phi[1:] * E - phi[:-1]
    H = phi[1:] * B
    d = phi[1:] * c + np.diff(psi, axis=0)
    S_out = np.empty((n, m, m))
    s_out = np.empty((n, m))
    K_out = np.empty((n - 1, m, m))
    k_out = np.empty((n - 1, m))
    S = track[-1].copy()
    s = track_lin[-1].copy()
    if P is not None:
        cp = phi[-1][:, None] * (C[-1].T @ np.asarray(P, dtype=float))
        S += cp @ C[-1] * phi[-1][None, :]
        s += cp @ (tau_ref[-1] - C[-1] @ psi[-1])
    S_out[-1], s_out[-1] = S, s
    # everything but the recursion, vectorised over the intervals
    ee = E[:, :, None] * E[:, None, :]
    eb = E[:, :, None] * B[:, None, :]
    bb = B[:, :, None] * B[:, None, :]
    diag = np.arange(m)
    qxx0 = track[:-1].copy()
    qxx0[:, diag, diag] += G ** 2 * rh
    qvv_d = H ** 2 * rh
    # no input where held; a vanishing dF/da leaves v free: keep the solve regular
    qvv_d += np.where(free, 1e-12 * np.max(qvv_d, axis=1, keepdims=True), 1.0)
    qxv_d = G * H * rh
    lin_v = H * rh * d
    lin_x = track_lin[:-1] - G * rh * d
    posv = get_lapack_funcs('posv', (S,))
    rhs = np.empty((m, m + 1))
    for i in range(n - 2, -1, -1):
        sc = s - S @ c[i]
        qxx = qxx0[i] + ee[i] * S
        qxv = eb[i] * S
        qxv[diag, diag] += qxv_d[i]
        qvv = bb[i] * S
        qvv[diag, diag] += qvv_d[i]
        rhs[:, :m] = qxv.T
        rhs[:, m] = B[i] * sc - lin_v[i]
        _, sol, info = posv(qvv, rhs, lower=1)
        if info != 0:
            sol = np.linalg.solve(qvv, rhs)
        K_out[i], k_out[i] = sol[:, :m], sol[:, m]
        S = _sym(qxx - qxv @ sol[:, :m])
        s = lin_x[i] + E[i] * sc - qxv @ sol[:, m]
        S_out[i], s_out[i] = S, s
    return DiscreteLqt(S=S_out, s=s_out, K=K_out, k=k_out)
