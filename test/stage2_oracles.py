"""Test-only oracles and fixtures of Stage 2 (not used by the package).

* ``solve_lqt``: Eqs. 12-13 over a whole grid, by the package's exact-step sweep (A = 0,
  B = I) or, for a general constant (A, B), by the matrix exponential of the augmented
  Hamiltonian (``_general_sweep``, an independent path the fast sweep is checked against);
  ``simulate_linear`` its closed loop on the linear system (10); ``tracking_cost`` Eq. 11 by
  the trapezoidal rule; ``simulate_discrete`` the closed loop of a discrete LQT.
* ``synthetic_reference``: a squat-jump-like motion with known muscle forces (its own fine
  RK4 of the activation ODE).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from nmt_ros.model.jumper import JumperModel, default_model
from nmt_ros.tracking.stage2.activation import ActivationLaw
from nmt_ros.tracking.stage2.lqt import (
    DiscreteLqt,
    backward_sweep,
    closed_loop_coefficients,
    inv_sqrt_spd,
    lqt_control,
    prepare_grid,
    symmetric,
    uniform_step,
)


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
        return LqtSolution(t=t, W=symmetric(grid.unscale_w(wt[0])), g=grid.unscale_g(gt[0]),
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
    h = uniform_step(t)
    n, p, m = C.shape
    P = np.zeros((p, p)) if P is None else np.asarray(P, dtype=float)
    S = B @ np.linalg.solve(R, B.T)
    Ct = np.swapaxes(C, 1, 2)
    M = symmetric(Ct @ Q @ C)
    b = np.einsum('nip,np->ni', Ct @ Q, tau_ref)
    W = np.empty((n, m, m))
    g = np.empty((n, m))
    W[-1] = symmetric(C[-1].T @ P @ C[-1])
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
        w1 = symmetric(np.linalg.solve(x.T, y.T).T)
        W[i] = w1
        g[i] = (p22 - w1 @ p12) @ g[i + 1] + w1 @ pf - pl
    return W, g


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
    h = uniform_step(sol.t)
    r_is, r_s = inv_sqrt_spd(sol.R)
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


def simulate_discrete(dl: DiscreteLqt, x0: np.ndarray, E: np.ndarray, free: np.ndarray,
                      c: np.ndarray) -> np.ndarray:
    """x [n, m] of the closed loop x_i+1 = E_i x_i + B_i (-K_i x_i + k_i) + c_i."""
    x = np.empty((dl.S.shape[0], np.size(x0)))
    x[0] = x0
    for i in range(x.shape[0] - 1):
        v = dl.k[i] - dl.K[i] @ x[i]
        x[i + 1] = E[i] * x[i] + np.where(free[i], v, 0.0) + c[i]
    return x


# ---------------------------------------------------------------------------- synthetic truth
@dataclass(frozen=True)
class SyntheticReference:
    """A squat-jump-like motion with known muscle forces: tau_ref = C(theta) f_true."""

    t: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    theta_ddot: np.ndarray
    tau_ref: np.ndarray
    u_true: np.ndarray
    a_true: np.ndarray
    f_true: np.ndarray


def synthetic_reference(model: JumperModel | None = None, dt: float = 1e-3,
                        duration: float = 0.25,
                        start_deg: tuple[float, float, float] = (25.0, -70.0, 80.0),
                        end_deg: tuple[float, float, float] = (-30.0, 0.0, 0.0),
                        ) -> SyntheticReference:
    """Known-truth Stage-2 input (tests, benchmarks).

    Joint angles (ankle, knee, hip) move from a squat to extension with a minimum-jerk profile;
    smooth excitations (extensors on proximal-to-distal, flexors low) drive the model's
    activation ODE (fine RK4); f_true = F(a_true, l_MT, v_MT), tau_ref = C f_true.
    """
    model = model if model is not None else default_model()
    t = np.arange(0.0, duration + 0.5 * dt, dt)
    s = t / duration
    pos = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
    vel = (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4) / duration
    acc = (60 * s - 180 * s ** 2 + 120 * s ** 3) / duration ** 2
    span = np.radians(np.subtract(end_deg, start_deg))
    theta = np.radians(start_deg) + pos[:, None] * span
    theta_dot = vel[:, None] * span
    theta_ddot = acc[:, None] * span
    # excitations: base level + smooth rise at a muscle-specific onset
    #               gmax  ilpso hams  bfsh  rf    vas   gas   sol   ta
    base = np.array([0.08, 0.03, 0.08, 0.03, 0.05, 0.10, 0.08, 0.10, 0.03])
    peak = np.array([0.60, 0.06, 0.45, 0.06, 0.25, 0.65, 0.50, 0.60, 0.06])
    onset = np.array([0.00, 0.10, 0.01, 0.10, 0.05, 0.03, 0.09, 0.08, 0.10]) * duration / 0.25
    rise = 0.04 * duration / 0.25

    def excitation(time: float | np.ndarray) -> np.ndarray:
        x = np.clip((np.asarray(time)[..., None] - onset) / rise, 0.0, 1.0)
        return base + (peak - base) * x * x * (3 - 2 * x)

    law = ActivationLaw.from_model(model)
    u_true = excitation(t)

    def adot(a: np.ndarray, time: float) -> np.ndarray:
        drift, gain = law.affine(a)
        return drift + gain * excitation(time)

    a = np.empty_like(u_true)
    a[0] = -(law.d0 + law.g0 * base) / (law.d1 + law.g1 * base)   # steady state of u(0)
    sub = 10
    hh = dt / sub
    for i in range(t.size - 1):
        x = a[i]
        for j in range(sub):
            tt = t[i] + j * hh
            k1 = adot(x, tt)
            k2 = adot(x + 0.5 * hh * k1, tt + 0.5 * hh)
            k3 = adot(x + 0.5 * hh * k2, tt + 0.5 * hh)
            k4 = adot(x + hh * k3, tt + hh)
            x = x + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        a[i + 1] = x
    l_mt, = model.batch(model.musculotendon_lengths, theta)
    v_mt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    f_true, = model.batch(model.muscle_force, a, l_mt, v_mt)
    C, = model.batch(model.moment_arm_matrix, theta)
    tau_ref = np.einsum('npm,nm->np', C.reshape(t.size, 3, 9), f_true)
    return SyntheticReference(t=t, theta=theta, theta_dot=theta_dot, theta_ddot=theta_ddot,
                              tau_ref=tau_ref, u_true=u_true, a_true=a, f_true=f_true)
