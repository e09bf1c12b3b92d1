"""Riccati (Eq. 12), adjoint (Eq. 13) and control law (Eq. 14) against independent truths."""
from __future__ import annotations

import control
import numpy as np
import pytest
from scipy.linalg import solve_continuous_are, sqrtm
import stage2_oracles as oracles

from nmt_ros.tracking.stage2 import bounded_qp, lqt


def _jumper_problem() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C (3x9) of the model at the squat and the paper's Q, R (Appendix B)."""
    from nmt_ros.model.jumper import default_model

    model = default_model()
    C, = model.call(model.moment_arm_matrix, np.radians([25.0, -70.0, 80.0]))
    r = np.array([1, 1, 0.1, 1, 0.3, 1, 0.75, 1, 1])   # gmax ilpso hams bfsh rf vas gas sol ta
    R = 1000.0 * np.diag(r / model.p.muscles.f0 ** 2)
    return np.asarray(C), 1500.0 * np.eye(3), R


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_step_functions_series_and_closed_forms_agree():
    mu = np.array([0.0199, 0.0201, 0.5, 3.0])
    c = lqt._step_functions(mu, 1.0)
    x = mu
    np.testing.assert_allclose(c['d'], np.tanh(x) / x, rtol=1e-9)
    np.testing.assert_allclose(c['n'], (1 - 1 / np.cosh(x)) / x ** 2, rtol=1e-8)
    np.testing.assert_allclose(c['pb'], (x * np.tanh(x) - 1 + 1 / np.cosh(x)) / x ** 2,
                               rtol=1e-8)
    np.testing.assert_allclose(c['pd'], (np.tanh(x) / x - 1 / np.cosh(x)) / x ** 2, rtol=1e-7)


def test_constant_c_reaches_closed_form_steady_state():
    C, Q, R = _jumper_problem()
    M = C.T @ Q @ C
    rates = np.sqrt(np.abs(np.linalg.eigvals(np.linalg.solve(R, M))))
    assert rates.max() > 300          # the stiffness the integrator must cope with
    t = np.arange(0, 0.2 + 1e-12, 1 / 120)   # a coarse 120 Hz grid: exact steps stay stable
    tau = np.zeros((t.size, 3))
    sol = oracles.solve_lqt(t, C, tau, Q, R)
    r_h = np.sqrt(np.diag(R))
    S = r_h[:, None] * np.real(sqrtm(M / np.outer(r_h, r_h))) * r_h[None, :]
    assert _rel(sol.W[0], S) < 1e-6       # ~6e-8: sqrtm of the rank-3 matrix is the limit
    # the same closed form through the rank-3 factor G = Q^1/2 C R^-1/2 (no square root of a
    # singular matrix): sqrtm(G'G) = G' (G G')^-1/2 G
    G = np.sqrt(np.diag(Q))[:, None] * C / r_h[None, :]
    w, v = np.linalg.eigh(G @ G.T)
    S_exact = r_h[:, None] * (G.T @ (v / np.sqrt(w)) @ v.T @ G) * r_h[None, :]
    assert _rel(sol.W[0], S_exact) < 1e-11
    # symmetric, positive semi-definite everywhere; W(tf) = C'PC = 0
    assert np.max(np.abs(sol.W - np.swapaxes(sol.W, 1, 2))) == 0.0
    assert np.linalg.eigvalsh(sol.W).min() > -1e-9 * np.abs(S).max()
    assert np.all(sol.W[-1] == 0)


def test_general_ab_path_matches_care_and_control_lqr():
    rng = np.random.default_rng(3)
    m, k, p = 4, 2, 2
    A = rng.normal(size=(m, m))               # generally unstable
    B = rng.normal(size=(m, k))
    C = rng.normal(size=(p, m))               # observable (random)
    Q = np.diag([2.0, 0.5])
    R = np.diag([0.3, 1.2])
    t = np.linspace(0, 30, 301)      # slowest closed-loop mode 0.39 1/s: e^(-2*0.39*30) ~ 1e-10
    sol = oracles.solve_lqt(t, C, np.zeros((t.size, p)), Q, R, A=A, B=B)
    S_care = solve_continuous_are(A, B, C.T @ Q @ C, R)
    _, S_ctrl, _ = control.lqr(A, B, C.T @ Q @ C, R)
    assert _rel(sol.W[0], S_care) < 1e-9
    assert _rel(sol.W[0], np.asarray(S_ctrl)) < 1e-9


def test_general_path_equals_fast_path_for_a0_b_identity():
    """The two implementations of the same exact step agree on a time-varying problem."""
    rng = np.random.default_rng(5)
    C0, Q, R = _jumper_problem()
    t = np.linspace(0, 0.05, 51)
    C = C0[None] * (1 + 0.3 * np.sin(40 * t))[:, None, None] + 0.004 * rng.normal(size=(1, 3, 9))
    tau = np.stack([100 * np.sin(30 * t), 50 * np.cos(20 * t), 80 * t], axis=1)
    P = 0.01 * np.eye(3)
    fast = oracles.solve_lqt(t, C, tau, Q, R, P=P)
    general = oracles.solve_lqt(t, C, tau, Q, R, P=P, A=np.zeros((9, 9)), B=np.eye(9))
    assert _rel(fast.W, general.W) < 1e-8
    assert _rel(fast.g, general.g) < 1e-8


def test_scalar_constant_coefficients_tanh_solution():
    q, r, c, tf = 3.0, 0.2, 1.7, 1.0
    t = np.linspace(0, tf, 11)                       # coarse: the step is exact
    sol = oracles.solve_lqt(t, np.full((t.size, 1, 1), c), np.zeros((t.size, 1)), [[q]], [r])
    exact = np.sqrt(q * r) * c * np.tanh(c * np.sqrt(q / r) * (tf - t))
    np.testing.assert_allclose(sol.W[:, 0, 0], exact, rtol=1e-12, atol=1e-14)


def _manufactured(t: np.ndarray, tf: float) -> dict[str, np.ndarray | float]:
    """Time-varying scalar problem with a known solution w(t), g(t).

    Choose w = 2 (1 + 0.5 sin 3t), r = 0.1, q = 1; Eq. 12 then fixes c(t)^2 = (w^2/r - wdot)/q
    and P = w(tf)/c(tf)^2. Choose g = w (1 + 0.3 (t - tf)^2) (gdot/g = wdot/w at tf, so g(tf)
    = c P tau(tf) holds); Eq. 13 fixes tau = ((w/r) g - gdot)/(c q).
    """
    q, r = 1.0, 0.1
    w = 2 * (1 + 0.5 * np.sin(3 * t))
    wd = 3 * np.cos(3 * t)
    c = np.sqrt((w ** 2 / r - wd) / q)
    shape = 1 + 0.3 * (t - tf) ** 2
    g = w * shape
    gd = wd * shape + w * 0.6 * (t - tf)
    tau = ((w / r) * g - gd) / (c * q)
    return {'q': q, 'r': r, 'w': w, 'c': c, 'g': g, 'tau': tau, 'P': w[-1] / c[-1] ** 2}


@pytest.mark.parametrize('n', [4001, 8001])
def test_scalar_time_varying_manufactured_solution(n):
    tf = 2.0
    t = np.linspace(0, tf, n)
    ms = _manufactured(t, tf)
    sol = oracles.solve_lqt(t, ms['c'][:, None, None], ms['tau'][:, None], [[ms['q']]],
                            [ms['r']], P=[[ms['P']]])
    assert _rel(sol.W[:, 0, 0], ms['w']) < 1e-6
    assert _rel(sol.g[:, 0], ms['g']) < 1e-6


def test_scalar_time_varying_is_second_order():
    tf = 2.0
    errs = []
    for n in (101, 201, 401):
        t = np.linspace(0, tf, n)
        ms = _manufactured(t, tf)
        sol = oracles.solve_lqt(t, ms['c'][:, None, None], ms['tau'][:, None], [[ms['q']]],
                                [ms['r']], P=[[ms['P']]])
        errs.append(np.abs(sol.g[:, 0] - ms['g']).max())
    order = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(order > 1.8), order


def test_adjoint_constant_reference_reaches_r_weighted_optimum():
    """Infinite-horizon optimum of fdot = eta, e = tau - C f, constant tau and C.

    The forces settle where C f = tau with the R-weighted minimum change from f0:
    f_inf = f0 + R^-1 C' (C R^-1 C')^-1 (tau - C f0); there eta = 0, so g = W f_inf.
    """
    C, Q, R = _jumper_problem()
    tau = np.array([-60.0, 120.0, -150.0])
    f0 = np.full(9, 300.0)
    t = np.arange(0, 0.3 + 1e-12, 1e-3)
    sol = oracles.solve_lqt(t, C, np.tile(tau, (t.size, 1)), Q, R)
    f, eta = oracles.simulate_linear(sol, f0)
    ri = np.linalg.inv(R)
    f_inf = f0 + ri @ C.T @ np.linalg.solve(C @ ri @ C.T, tau - C @ f0)
    mid = t.size // 2                     # far from both ends (rates > 400 1/s)
    assert _rel(f[mid], f_inf) < 1e-6
    assert _rel(sol.g[mid], sol.W[mid] @ f_inf) < 1e-6
    assert np.abs(eta[mid]).max() < 1e-6 * np.abs(f_inf).max()


def test_tracking_cost_of_a_known_trajectory():
    """Eq. 11 for f linear in t (eta constant), one muscle, constant c: closed form."""
    t = np.linspace(0, 2, 2001)
    c, q, r, p, tau, f0, rate = 0.5, 3.0, 0.2, 7.0, 4.0, 1.0, 2.0
    f = (f0 + rate * t)[:, None]
    eta = np.full_like(f, rate)
    J = oracles.tracking_cost(t, f, eta, np.full((t.size, 1, 1), c),
                              np.full((t.size, 1), tau), [[q]], [r], P=[[p]])
    e0, e1 = tau - c * f0, tau - c * (f0 + rate * 2)
    exact = 0.5 * p * e1 ** 2 + 0.5 * (q * (e0 ** 2 + e0 * e1 + e1 ** 2) / 3 * 2
                                       + r * rate ** 2 * 2)
    assert J == pytest.approx(exact, rel=1e-6)


def test_lqt_control_matches_explicit_formula():
    rng = np.random.default_rng(0)
    W = rng.normal(size=(5, 4, 4))
    g = rng.normal(size=(5, 4))
    f = rng.normal(size=(5, 4))
    r = np.array([0.5, 2.0, 1.0, 3.0])
    expected = np.stack([np.linalg.solve(np.diag(r), g[i] - W[i] @ f[i]) for i in range(5)])
    np.testing.assert_allclose(lqt.lqt_control(W, g, f, r), expected, rtol=1e-12)
    np.testing.assert_allclose(lqt.lqt_control(W, g, f, np.diag(r)), expected, rtol=1e-12)


# ---------------------------------------------------------------------------- bounded / discrete
def _bounded_problem(n: int = 41, seed: int = 2) -> dict:
    """Small Stage-2-like problem: 4 'muscles', 2 joints, activation-like step bounds."""
    rng = np.random.default_rng(seed)
    h = 0.004
    t = np.arange(n) * h
    m, p = 4, 2
    C = (rng.normal(scale=0.04, size=(p, m))[None]
         * (1 + 0.3 * np.sin(20 * t))[:, None, None])
    phi = 1000 * (1 + 0.2 * np.cos(15 * t))[:, None] * rng.uniform(0.5, 1.5, m)[None]
    psi = 20 * rng.uniform(size=(1, m)) * (1 + t[:, None])
    tau = np.stack([40 * np.sin(25 * t), 30 * np.cos(18 * t) - 10], axis=1)
    tau_act, tau_deact = 0.01, 0.04
    lo = (np.full(m, np.exp(-h / tau_deact)), np.zeros(m))          # u = 0
    hi = (np.full(m, np.exp(-h / tau_act)), np.full(m, 1 - np.exp(-h / tau_act)))   # u = 1
    return {'h': h, 't': t, 'C': C, 'phi': phi, 'psi': psi, 'tau': tau, 'Q': 1500 * np.eye(p),
            'R': 1000 * rng.uniform(0.1, 1, m) / 1000 ** 2, 'x0': np.full(m, 0.1),
            'lo': lo, 'hi': hi}


def _discrete_cost(pr: dict, x: np.ndarray) -> float:
    f = pr['phi'] * x + pr['psi']
    e = pr['tau'] - np.einsum('npm,nm->np', pr['C'], f)
    w = np.full(x.shape[0], pr['h'])
    w[0] = w[-1] = 0.5 * pr['h']
    return float(0.5 * np.sum(w * np.einsum('np,pq,nq->n', e, pr['Q'], e))
                 + 0.5 * np.sum(pr['R'] / pr['h'] * np.diff(f, axis=0) ** 2))


def test_bounded_lqt_satisfies_the_kkt_conditions():
    """Convex QP: stationarity, dual feasibility, complementarity and primal feasibility are
    sufficient; the gradient is taken from the cost itself by central differences (exact for a
    quadratic up to rounding)."""
    pr = _bounded_problem()
    sol = bounded_qp.solve_bounded_lqt(pr['h'], pr['C'], pr['tau'], pr['Q'], pr['R'],
                                       pr['phi'], pr['psi'], pr['x0'], pr['lo'], pr['hi'],
                                       tol=1e-10)
    assert sol.converged and sol.cost == pytest.approx(_discrete_cost(pr, sol.x), rel=1e-12)
    n, m = sol.x.shape
    (la, lb), (ha, hb) = pr['lo'], pr['hi']
    grad = np.zeros((n - 1, m))
    step = 1e-3
    for i in range(1, n):
        for j in range(m):
            xp, xm = sol.x.copy(), sol.x.copy()
            xp[i, j] += step
            xm[i, j] -= step
            grad[i - 1, j] = (_discrete_cost(pr, xp) - _discrete_cost(pr, xm)) / (2 * step)
    # A' z: c_lo = x_i+1 - la x_i - lb, c_hi = ha x_i + hb - x_i+1 (interval i = 0..n-2)
    at_z = sol.z_lo - sol.z_hi
    at_z[:-1] += -la * sol.z_lo[1:] + ha * sol.z_hi[1:]
    scale = np.abs(grad).max()
    assert np.abs(grad - at_z).max() < 1e-6 * scale
    assert min(sol.z_lo.min(), sol.z_hi.min()) >= 0
    assert min(sol.slack_lo.min(), sol.slack_hi.min()) > -1e-12
    np.testing.assert_allclose(sol.slack_lo, sol.x[1:] - la * sol.x[:-1] - lb, atol=1e-12)
    np.testing.assert_allclose(sol.slack_hi, ha * sol.x[:-1] + hb - sol.x[1:], atol=1e-12)
    assert max(np.max(sol.z_lo * sol.slack_lo), np.max(sol.z_hi * sol.slack_hi)) < 1e-8 * scale
    # the bounds bind somewhere (else the test would not test them)
    pos = sol.position()
    assert np.any(pos > 1 - 1e-6) and np.any(pos < 1e-6)


def test_discrete_lqt_equals_the_bounded_lqt_without_and_with_active_bounds():
    pr = _bounded_problem()
    args = (pr['h'], pr['C'], pr['tau'], pr['Q'], pr['R'], pr['phi'], pr['psi'])
    m = pr['x0'].size
    # without active bounds: the bounded solution is the plain discrete LQT (all free)
    loose = ((np.ones(m), -1e3 * np.ones(m)), (np.ones(m), 1e3 * np.ones(m)))
    sol = bounded_qp.solve_bounded_lqt(*args, pr['x0'], *loose, tol=1e-12)
    dl = lqt.discrete_lqt(*args)
    n = pr['t'].size
    free = np.ones((n - 1, m), dtype=bool)
    x = oracles.simulate_discrete(dl, pr['x0'], np.ones((n - 1, m)), free,
                                  np.zeros((n - 1, m)))
    np.testing.assert_allclose(x, sol.x, atol=1e-7)
    # with them: the discrete LQT over the active set reproduces the bounded solution
    sol = bounded_qp.solve_bounded_lqt(*args, pr['x0'], pr['lo'], pr['hi'], tol=1e-12)
    pos = sol.position()
    high, low = pos > 1 - 1e-6, pos < 1e-6
    (la, lb), (ha, hb) = pr['lo'], pr['hi']
    E = np.where(high, ha, np.where(low, la, 1.0))
    c = np.where(high, hb, np.where(low, lb, 0.0))
    free = ~(high | low)
    dl = lqt.discrete_lqt(*args, E=E, free=free, c=c)
    x = oracles.simulate_discrete(dl, pr['x0'], E, free, c)
    np.testing.assert_allclose(x, sol.x, atol=1e-6)
    assert np.all(np.linalg.eigvalsh(dl.S).min(axis=1) > -1e-9 * np.abs(dl.S).max())


def test_discrete_lqt_tends_to_the_continuous_lqt():
    """phi = 1, psi = 0, no bounds: the discrete Eqs. 12-14 converge to the continuous ones."""
    C0, Q, R = _jumper_problem()
    r = np.diag(R)
    errs = []
    for n in (101, 201, 401):
        t = np.linspace(0, 0.2, n)
        C = C0[None] * (1 + 0.3 * np.sin(20 * t))[:, None, None]
        tau = np.stack([100 * np.sin(30 * t), 50 * np.cos(20 * t), -80 - 200 * t], axis=1)
        f0 = np.full(9, 300.0)
        cont = oracles.simulate_linear(oracles.solve_lqt(t, C, tau, Q, r), f0)[0]
        dl = lqt.discrete_lqt(t[1] - t[0], C, tau, Q, r, np.ones((n, 9)), np.zeros((n, 9)))
        ones = np.ones((n - 1, 9))
        disc = oracles.simulate_discrete(dl, f0, ones, ones > 0, 0 * ones)
        errs.append(np.abs(disc - cont).max())
    order = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(order > 1.8), (errs, order)          # second order in h


def test_force_term_is_the_dense_minimiser_and_forgets_the_start_co_contraction():
    """Eq. 11 + 1/2 int f' K_f f dt through ``with_force_term`` (extra tracked outputs) and
    the discrete LQT equals the minimiser of the same discrete cost written out densely
    (numpy, no Riccati): trapezoid-weighted tracking and force terms, rate effort
    1/2 h |(f_i+1 - f_i) / h|_R^2, f_0 given. Two starts that differ only by co-contraction
    (a force pattern in the null space of C): the paper's Eq. 11 carries the difference to
    the end, the force term forgets it; both track the torques alike."""
    C0, Q, R = _jumper_problem()
    from nmt_ros.model.jumper import default_model

    f0_peak = default_model().p.muscles.f0
    r = np.diag(R)
    n, m, h = 121, 9, 0.005                               # 0.6 s
    t = np.arange(n) * h
    C = C0[None] * (1 + 0.2 * np.sin(15 * t))[:, None, None]   # null space of C0 kept
    tau = np.stack([60 + 40 * np.sin(10 * t), -30 * np.cos(8 * t), -50 - 100 * t], axis=1)
    null = np.linalg.svd(C0)[2][-1]                       # C0 null = 0
    base = np.linalg.lstsq(C0, tau[0], rcond=None)[0]
    k_force = 1e5 / f0_peak ** 2

    def dense(kf: np.ndarray, f_start: np.ndarray) -> np.ndarray:
        w = np.full(n, h)
        w[0] = w[-1] = 0.5 * h
        N = (n - 1) * m
        H, g = np.zeros((N, N)), np.zeros(N)
        for i in range(1, n):                             # tracking and force terms
            s = slice((i - 1) * m, i * m)
            H[s, s] += w[i] * (C[i].T @ Q @ C[i] + np.diag(kf))
            g[s] += w[i] * C[i].T @ Q @ tau[i]
        D = np.eye(N) - np.eye(N, k=-m)                   # rows: f_i+1 - f_i, i = 0..n-2
        d0 = np.zeros(N)
        d0[:m] = -f_start
        Rh = np.kron(np.eye(n - 1), np.diag(r / h))
        H += D.T @ Rh @ D
        g -= D.T @ Rh @ d0
        return np.vstack([f_start, np.linalg.solve(H, g).reshape(n - 1, m)])

    ones = np.ones((n - 1, m))
    ends = {}
    for name, kf in (('paper', None), ('force', k_force)):
        C_y, y_ref, Q_y, _ = lqt.with_force_term(C, tau, Q, None, kf)
        dl = lqt.discrete_lqt(h, C_y, y_ref, Q_y, r, np.ones((n, m)), np.zeros((n, m)))
        runs = []
        for sign in (1.0, -1.0):
            start = base + sign * 1000.0 * null
            f = oracles.simulate_discrete(dl, start, ones, ones > 0, 0 * ones)
            np.testing.assert_allclose(f, dense(np.zeros(m) if kf is None else kf, start),
                                       rtol=0, atol=1e-6 * np.abs(f).max())
            err = np.einsum('npm,nm->np', C, f)[20:] - tau[20:]
            assert np.sqrt(np.mean(err ** 2)) < 0.02 * np.abs(tau).max()
            runs.append(f)
        ends[name] = float(np.abs((runs[0] - runs[1])[-1] @ null))
    assert ends['paper'] > 0.9 * 2000.0, ends             # the start's difference kept
    assert ends['force'] < 0.05 * ends['paper'], ends     # ... and forgotten
    # zero weight: the arguments unchanged
    assert lqt.with_force_term(C, tau, Q, None, np.zeros(m))[0] is C
