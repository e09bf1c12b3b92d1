"""The LQT of Stage 2: Riccati (Eq. 12), adjoint (Eq. 13), feedback law (Eq. 14).

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
(mu = 0, unobservable) are handled by the series of the same functions. (The tests check this
sweep against the exact step of a general (A, B) by the matrix exponential of the augmented
Hamiltonian, ``test/lqt_oracles.py``.)

The forward closed loop fdot = R^-1 (g - W f) is likewise solved exactly per interval
(``closed_loop_coefficients``; exponential integrator, W frozen at the interval mean, g linear).
Any step is stable. Accuracy: second order where mu h is small; where mu h >> 1 the stiff modes
sit at the quasi-steady value of the frozen coefficients, which lags the time variation of C by
O(h) - so the Stage 2 tracker refines coarse inputs to <= 1 ms internally (``max_step``).

Discrete form (Stage 2's default 'plan' mode): ``discrete_lqt`` is the Riccati / adjoint /
feedback recursion (Eqs. 12-14 in discrete time) of Eq. 11 discretised on the grid as in
``bounded_qp.solve_bounded_lqt``, for given held elements (the bounded QP's active set);
without held elements it converges to the continuous solution at second order in h (tested).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

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


def with_force_term(C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray, P: np.ndarray | None,
                    k_force: np.ndarray | None,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Eq. 11 with a force term 1/2 int f' K_f f dt (K_f = diag(k_force) [m], 1/N^2 per s)
    written as extra tracked outputs, so that every solver of Eq. 11 (the Riccati sweeps,
    the discrete LQT, the bounded QP) takes it unchanged: y = [C f; f], y_ref = [tau_ref; 0],
    Q_y = blkdiag(Q, K_f), P_y = blkdiag(P, 0). Returns (C_y [n, p + m, m], y_ref [n, p + m],
    Q_y, P_y); the arguments themselves when k_force is None or zero.

    Why: Eq. 11 weighs the tracking error and the force RATES only, so the forces' null
    space (co-contraction: C f = 0) is not observed and keeps whatever the start and the
    bounds left in it - on a long stream it drifts (Stage 2 on the routine: 22 % F0 RMS in
    quiet stance). A force term lets it decay to the least-force distribution without
    touching the tracked torques (``data/stage2.yaml``, ``k_f``, for the measurement).
    """
    if k_force is None or not np.any(k_force):
        return C, tau_ref, Q, P
    C = np.asarray(C, dtype=float)
    n, p, m = C.shape
    k_force = np.broadcast_to(np.asarray(k_force, dtype=float), (m,))
    C_y = np.concatenate([C, np.broadcast_to(np.eye(m), (n, m, m))], axis=1)
    y_ref = np.concatenate([np.asarray(tau_ref, dtype=float).reshape(n, p), np.zeros((n, m))],
                           axis=1)
    Q_y = np.zeros((p + m, p + m))
    Q_y[:p, :p] = Q
    Q_y[p:, p:] = np.diag(k_force)
    P_y = None
    if P is not None:
        P_y = np.zeros((p + m, p + m))
        P_y[:p, :p] = P
    return C_y, y_ref, Q_y, P_y


def symmetric(a: np.ndarray) -> np.ndarray:
    """(a + a')/2 over the last two axes."""
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def inv_sqrt_spd(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R^-1/2 and R^1/2 of a symmetric positive-definite R (or a diagonal given as [m])."""
    r = np.asarray(r, dtype=float)
    if r.ndim == 1:
        if np.any(r <= 0):
            raise ValueError('R must be positive definite')
        return np.diag(1 / np.sqrt(r)), np.diag(np.sqrt(r))
    w, u = np.linalg.eigh(symmetric(r))
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
    v: np.ndarray | None       # [n-1, m, m]  eigenvectors of the interval-mean m_tilde
    coef: dict[str, np.ndarray]  # [n-1, m]: _step_functions + projected forcing
    # (v None and coef empty: prepared without the sweep data, ``prepare_grid(sweeps=False)``)

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


def uniform_step(t: np.ndarray, h: float | None = None) -> float:
    """The step h [s] of a uniform increasing grid t [n] (clear error otherwise).

    Without ``h`` the step is the mean of the grid's differences (it carries their rounding,
    so it depends on which samples t holds); with ``h`` (the nominal step, e.g. 1 / rate) t
    is checked against it and h itself is returned: a stream built in pieces then uses one
    step whatever its pieces.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError('t must be a 1-D grid of at least 2 samples')
    dt = np.diff(t)
    step = float(dt.mean()) if h is None else float(h)
    if step <= 0 or np.max(np.abs(dt - step)) > 1e-4 * step:   # (stamps in ns: ~1e-6 h)
        raise ValueError('t must be uniform and increasing'
                         + ('' if h is None else f' with step {h} s'))
    return step


def prepare_grid(t: np.ndarray, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray,
                 R: np.ndarray, P: np.ndarray | None = None, h: float | None = None,
                 sweeps: bool = True) -> LqtGrid:
    """Precompute the scaled problem and the exact-step coefficients of every interval.

    t [n] uniform (s); C [n, p, m]; tau_ref [n, p]; Q [p, p]; R [m, m] SPD (or its diagonal
    [m]); P [p, p] terminal weight (default 0); h [s] the nominal step (default: from t,
    ``uniform_step``). Vectorised over samples (batched eigh). ``sweeps`` False leaves out
    what only ``backward_sweep`` uses (the eigen-decompositions and step coefficients of the
    intervals; Stage 2's 'plan' mode never sweeps).
    """
    h = uniform_step(t, h)
    C = np.asarray(C, dtype=float)
    tau_ref = np.asarray(tau_ref, dtype=float)
    n, p, m = C.shape
    if tau_ref.shape != (n, p) or np.shape(t) != (n,):
        raise ValueError(f'shapes: t {np.shape(t)}, C {C.shape}, tau_ref {tau_ref.shape}')
    Q = np.asarray(Q, dtype=float)
    P = np.zeros((p, p)) if P is None else np.asarray(P, dtype=float)
    r_is, r_s = inv_sqrt_spd(R)
    ct = C @ r_is                                          # [n, p, m]  C R^-1/2
    ctt = np.swapaxes(ct, 1, 2)
    m_tilde = symmetric(ctt @ Q @ ct)
    b_tilde = np.einsum('nip,np->ni', ctt @ Q, tau_ref)
    wt_terminal = symmetric(ctt @ P @ ct)
    gt_terminal = np.einsum('nip,np->ni', ctt @ P, tau_ref)
    if not sweeps:
        return LqtGrid(t=np.asarray(t, dtype=float), h=h, r_inv_sqrt=r_is, r_sqrt=r_s,
                       m_tilde=m_tilde, b_tilde=b_tilde, wt_terminal=wt_terminal,
                       gt_terminal=gt_terminal, v=None, coef={})
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
    if (first.v is None) != (second.v is None):
        raise ValueError('grids must both hold the sweep data or both not')
    return LqtGrid(h=first.h, r_inv_sqrt=first.r_inv_sqrt, r_sqrt=first.r_sqrt,
                   v=None if first.v is None else np.concatenate([first.v, second.v]),
                   coef={k: np.concatenate([first.coef[k], second.coef[k]]) for k in first.coef},
                   **joined)


def tail_grid(grid: LqtGrid, k: int) -> LqtGrid:
    """The grid without its first k samples (and intervals)."""
    per_sample = ('t', 'm_tilde', 'b_tilde', 'wt_terminal', 'gt_terminal')
    return LqtGrid(h=grid.h, r_inv_sqrt=grid.r_inv_sqrt, r_sqrt=grid.r_sqrt,
                   v=None if grid.v is None else grid.v[k:],
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
    if grid.v is None:
        raise ValueError('the grid was prepared without the sweep data (sweeps=False)')
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
        kk = symmetric(sol[:, :, :m])
        ek = se[:, :, None] * kk
        z1 = ek * se[:, None, :]
        z1[:, diag, diag] += c['lam_t'][:, j]
        gh1 = se * sol[:, :, m] + c['lin'][:, j] - (ek @ c['quad'][:, j, :, None])[..., 0]
        wt = symmetric(vj @ z1 @ vtj)
        gt = (vj @ gh1[..., None])[..., 0]
        if j < keep:
            w_keep[:, j] = wt
            g_keep[:, j] = gt
    return w_keep, g_keep


def lqt_control(W: np.ndarray, g: np.ndarray, f: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Eq. 14: eta = -R^-1 W f + R^-1 g (any leading axes; R [m, m] or its diagonal [m])."""
    rhs = g - np.einsum('...ij,...j->...i', W, f)
    R = np.asarray(R, dtype=float)
    if R.ndim == 1:
        return rhs / R
    return np.linalg.solve(R, rhs[..., None])[..., 0]


# ---------------------------------------------------------------------------- forward loop
def closed_loop_coefficients(wt: np.ndarray, h: float) -> dict[str, np.ndarray]:
    """Exact-step data of ft_dot = -Wt ft + gt(t) on intervals, Wt frozen at the interval mean.

    wt [..., k+1, m, m] at the samples of k intervals. Returns u [..., k, m, m] (eigenvectors
    of the interval mean), decay = exp(-omega h), hphi1, hphi2 [..., k, m]: over interval i,
    ft_i+1 = u (decay u' ft_i + hphi1 u' gt_i + hphi2 u' (gt_i+1 - gt_i)).
    """
    omega, u = np.linalg.eigh(symmetric(0.5 * (wt[..., 1:, :, :] + wt[..., :-1, :, :])))
    decay, hphi1, hphi2 = _decay_functions(omega, h)
    return {'u': u, 'decay': decay, 'hphi1': hphi1, 'hphi2': hphi2}


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


def discrete_lqt(h: float, C: np.ndarray, tau_ref: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 phi: np.ndarray, psi: np.ndarray, E: np.ndarray | None = None,
                 free: np.ndarray | None = None, c: np.ndarray | None = None,
                 P: np.ndarray | None = None) -> DiscreteLqt:
    """Backward Riccati/adjoint recursion of the discretised Eq. 11 (step h [s]) of
    ``bounded_qp.solve_bounded_lqt`` for x_i+1 = E_i x_i + B_i v_i + c_i, B_i = diag(free_i),
    outputs f = phi x + psi.

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
    _riccati_recursion(S, s, np.ascontiguousarray(c), qxx0, ee, eb, bb, qxv_d, qvv_d, lin_v,
                       lin_x, B, np.ascontiguousarray(E), S_out, s_out, K_out, k_out)
    return DiscreteLqt(S=S_out, s=s_out, K=K_out, k=k_out)


@numba.njit(cache=True)
def _riccati_recursion(S: np.ndarray, s: np.ndarray, c: np.ndarray, qxx0: np.ndarray,
                       ee: np.ndarray, eb: np.ndarray, bb: np.ndarray, qxv_d: np.ndarray,
                       qvv_d: np.ndarray, lin_v: np.ndarray, lin_x: np.ndarray, B: np.ndarray,
                       E: np.ndarray, S_out: np.ndarray, s_out: np.ndarray, K_out: np.ndarray,
                       k_out: np.ndarray) -> None:
    """The backward recursion of ``discrete_lqt`` (compiled: m = 9 and one small solve per
    step, numpy's per-call overhead was ~90 % of it), from S, s at the last sample; fills
    S_out, s_out [n] and K_out, k_out [n-1] (the last sample's rows already set)."""
    n1, m = c.shape
    qvv = np.empty((m, m))
    rhs = np.empty((m, m + 1))
    sol = np.empty((m, m + 1))
    L = np.empty((m, m))
    qxx = np.empty((m, m))
    qxv = np.empty((m, m))
    sc = np.empty(m)
    for i in range(n1 - 1, -1, -1):
        for r in range(m):
            acc = s[r]
            for k in range(m):
                acc -= S[r, k] * c[i, k]
            sc[r] = acc
        for r in range(m):
            for k in range(m):
                qxx[r, k] = qxx0[i, r, k] + ee[i, r, k] * S[r, k]
                qxv[r, k] = eb[i, r, k] * S[r, k]
                qvv[r, k] = bb[i, r, k] * S[r, k]
            qxv[r, r] += qxv_d[i, r]
            qvv[r, r] += qvv_d[i, r]
        for r in range(m):
            for k in range(m):
                rhs[r, k] = qxv[k, r]
            rhs[r, m] = B[i, r] * sc[r] - lin_v[i, r]
        # Cholesky of qvv (symmetric positive definite; else a general solve)
        pd = True
        for col in range(m):
            d = qvv[col, col]
            for k in range(col):
                d -= L[col, k] * L[col, k]
            if not d > 0.0:
                pd = False
                break
            d = np.sqrt(d)
            L[col, col] = d
            for r in range(col + 1, m):
                acc = qvv[r, col]
                for k in range(col):
                    acc -= L[r, k] * L[col, k]
                L[r, col] = acc / d
        if pd:
            for j in range(m + 1):
                for r in range(m):
                    acc = rhs[r, j]
                    for k in range(r):
                        acc -= L[r, k] * sol[k, j]
                    sol[r, j] = acc / L[r, r]
                for r in range(m - 1, -1, -1):
                    acc = sol[r, j]
                    for k in range(r + 1, m):
                        acc -= L[k, r] * sol[k, j]
                    sol[r, j] = acc / L[r, r]
        else:
            sol[:, :] = np.linalg.solve(qvv, rhs)
        for r in range(m):
            for k in range(m):
                K_out[i, r, k] = sol[r, k]
            k_out[i, r] = sol[r, m]
        for r in range(m):
            for k in range(m):
                acc = qxx[r, k]
                for j in range(m):
                    acc -= qxv[r, j] * sol[j, k]
                S_out[i, r, k] = acc
            acc = lin_x[i, r] + E[i, r] * sc[r]
            for j in range(m):
                acc -= qxv[r, j] * sol[j, m]
            s_out[i, r] = acc
        for r in range(m):
            for k in range(m):
                S[r, k] = 0.5 * (S_out[i, r, k] + S_out[i, k, r])
        for r in range(m):
            for k in range(m):
                S_out[i, r, k] = S[r, k]
            s[r] = s_out[i, r]
