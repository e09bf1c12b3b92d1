"""Stage 2's bounded QP: the home-made interior point against the QP solvers CasADi ships.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_stage2_qp.py [--repeat 3]
        [--stream-s 10] [--stream-full-s 1] [--stream-stride 10]
        [--solvers home,home_1e-9,hpipm,piqp,osqp,qpoases] [--sets 1,2,3,4,5]

(run by hand; about 15 minutes on this 2-core machine). The QP is the bounded LQT of Stage 2's
'plan' mode (``nmt_ros.tracking.stage2.bounded_qp``): Eq. 11 discretised on the internal grid
with every activation step between the exact steps at u = 0 and u = 1. Problem sets, from the
Stage-1 torques of the shipped reference jump (Stage 1 as ``nmt track`` runs it: optimal
tracking with muscle-made torques, 1080 Hz, up to lift-off + 10 ms):

  1. jump, full horizon: one QP (225 intervals x 9 muscles);
  2. jump, receding windows H = 100 ms, stride one sample: the QPs of ``nmt track
     --stage2-mode windowed``, recorded from the production run (each window from the state
     the previous one left);
  3. a stream: the jump's Stage-1 inputs played forward and backward (a palindrome; time
     reversal negates theta_dot) for ``--stream-full-s`` s, full horizon (one QP);
  4. the same stream for ``--stream-s`` s, windows H = 100 ms, stride ``--stream-stride``
     samples;
  5. the ``--stream-s`` stream, full horizon, home-made solver only (casadi.conic('hpipm')
     builds superlinearly in N: ~10 s at N = 1080; OSQP needs minutes per solve).

Every solver gets the same QPs. Solvers:

* home: ``bounded_qp.interior_point`` (primal-dual Mehrotra, block Cholesky of the
  block-tridiagonal normal matrix; compiled by numba), with Stage 2's tolerance (plan_tol,
  1e-7); home_<tol> (e.g. home_1e-9): the same at that tolerance.
* hpipm (``casadi.conic('hpipm')``): the same QP in HPIPM's OCP form - state x_k the
  activations, input u_k = x_k+1 - (step at u = 0) >= 0, general constraint u_k <= (step at
  u = 1) - (step at u = 0), stage costs Q_k, S_k, R_k; mode 'speed', residual tolerances
  ``--hpipm-tol`` (1e-8) on the objective scaled by 1 / (1 + max |g|) (``--hpipm-mode``
  'speed_abs', 'balance', 'robust' stop 1e-3 to 1e-1 in activation from the optimum on this
  problem, even at 1e-8; 'speed' at 1e-6 stops 2e-5 to 1e-4 from it, 15 % faster).
* piqp (``casadi.conic('piqp')``, sparse proximal interior point): the QP in the activations
  as OSQP gets it, eps_abs = eps_rel = ``--piqp-eps`` (1e-8).
* osqp (``casadi.conic('osqp')``): the QP in the activations x_1..x_n-1 (as the home-made
  solver sees it: block-tridiagonal H, 2 (n-1) m one-sided step constraints), eps_abs =
  eps_rel = ``--osqp-eps`` (1e-8), solution polishing on, cold start, at most 20000
  iterations; on the long stream it fails on some windows (p99 > 1 s), so it gets the first
  ``--osqp-windows`` windows of a set.
* qpoases (``casadi.conic('qpoases')``): the same sparse QP, dense active set. It needs
  ~1500 working-set changes (about a minute for one 100 ms window), so it gets the first
  window of each windowed set only (``--qpoases-windows``) and no full horizon; one cold
  solve (it hot-starts a repeated QP).

Timing: CPU (process) seconds per solve, from the QP record to the activations (the CasADi
solvers: nonzero assembly in numpy + the call through ``Function.buffer``, no Python DM
conversion; their C time from a separate pass with statistics), build time (``casadi.conic``
and the index maps, once per horizon length: the last windows of a recording are shorter)
apart. Each set is solved ``--repeat`` times, the solvers interleaved QP by QP (load changes on
the shared machine hit all alike); p50 / p99 are the median over repeats [min - max].

Accuracy per QP against the exact optimum (``exact_solution``: the KKT system of the active
set solved by sparse LU, the active set corrected until every inactive constraint holds and
every multiplier is >= 0 - no solver's stopping rule involved; how many QPs check out is
printed): max |da| (activation), max |df| / F0, objective (J - J_exact) / |J_exact|,
smallest constraint slack (negative: violated), and the active set Stage 2 derives from the
solution (steps within ``saturation_margin`` of a bound; the plan's discrete LQT depends on
nothing else): elements that differ from the production solver's ('home' at plan_tol) and
from the exact solution's. Last, what that accuracy changes in Stage 2's output: its windowed
muscle forces on the jump and the stream at plan_tol against ``--downstream-tol`` (1e-9).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import os
from pathlib import Path
import time
import warnings

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from nmt_ros.model.squat import rest_activations_for_posture
from nmt_ros.tracking.stage2 import NeuromuscularTracker, load_stage2_settings
from nmt_ros.tracking.stage2.bounded_qp import BoundedLqtQp, interior_point
from nmt_ros.tracking.stage2.forward_pass import initial_state

DEFAULT_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'
WINDOW_S = 0.1


# ---------------------------------------------------------------------------- problems
def stage1_inputs(bag: Path, tracker: NeuromuscularTracker) -> dict:
    """Stage 2's input as ``nmt track`` makes it: the Stage-1 motion up to lift-off + 10 ms."""
    from nmt_ros.io.trial_bag import read_observations
    from nmt_ros.study.pipeline import NMTSettings, run_nmt

    if not bag.exists():
        raise SystemExit(f'no bag at {bag}')
    model = tracker.model
    settings = NMTSettings(stage1='optimal_muscle')
    run = run_nmt(model, read_observations(bag), settings)
    skt = run.skt
    if not skt.ok:
        raise SystemExit(f'Stage 1 failed on {bag}: {skt.status}')
    t_stop = skt.liftoff_s + settings.stage2_margin_s
    keep = skt.t <= t_stop
    theta = [model.batch(model.joint_angles, x[keep])[0] for x in (skt.q, skt.qd, skt.qdd)]
    return {'t': skt.t[keep], 'tau': skt.tau[keep], 'theta': theta[0], 'theta_dot': theta[1],
            'theta_ddot': theta[2], 'a0': rest_activations_for_posture(model, skt.q[0], skt.x0)}


def palindrome(inputs: dict, seconds: float) -> dict:
    """The inputs forward, then backward in time (theta_dot negated), ... until ``seconds``."""
    fwd = [inputs['tau'], inputs['theta'], inputs['theta_dot'], inputs['theta_ddot']]
    bwd = [inputs['tau'][::-1], inputs['theta'][::-1], -inputs['theta_dot'][::-1],
           inputs['theta_ddot'][::-1]]
    h = float(inputs['t'][1] - inputs['t'][0])
    n = int(round(seconds / h)) + 1
    parts, total, k = [[x] for x in fwd], fwd[0].shape[0], 0
    while total < n:
        seg = bwd if k % 2 == 0 else fwd
        for p, x in zip(parts, seg):
            p.append(x[1:])
        total += seg[0].shape[0] - 1
        k += 1
    tau, theta, theta_dot, theta_ddot = (np.concatenate(p)[:n] for p in parts)
    return {'t': inputs['t'][0] + h * np.arange(n), 'tau': tau, 'theta': theta,
            'theta_dot': theta_dot, 'theta_ddot': theta_ddot, 'a0': inputs['a0']}


def record_problems(tracker: NeuromuscularTracker, inputs: dict, windowed: bool,
                    stride_samples: int = 1) -> list[BoundedLqtQp]:
    """The QPs of a Stage-2 run in production order (windows: planned from the state the
    previous window left, with the home-made solver, as ``track(mode='windowed')``)."""
    ref = tracker.reference(inputs['t'], inputs['tau'], inputs['theta'], inputs['theta_dot'],
                            inputs['theta_ddot'])
    state = initial_state(ref, inputs['a0'])
    if not windowed:
        return [tracker.planner.bounded_qp(ref, state.a, 0, ref.end)]
    length, stride = tracker.window_samples(ref, WINDOW_S, stride_samples * ref.grid.h)
    problems = []
    for start in range(0, ref.n - 1, stride):
        stop = min(start + length, ref.end)
        problems.append(tracker.planner.bounded_qp(ref, state.a, start, stop))
        state, _ = tracker.apply(tracker.plan_window(ref, state, length, stride), state)
    return problems


# ---------------------------------------------------------------------------- solvers
class HomeSolver:
    """``bounded_qp.interior_point`` with Stage 2's settings."""

    name = 'home'

    def __init__(self, tol: float, max_iterations: int) -> None:
        self.tol, self.max_iterations = tol, max_iterations

    def build(self, qp: BoundedLqtQp) -> float:
        return 0.0

    def solve(self, qp: BoundedLqtQp) -> np.ndarray:
        return interior_point(qp, self.tol, self.max_iterations).x[1:]

    def solve_with_stats(self, qp: BoundedLqtQp) -> tuple[np.ndarray, int, bool, float]:
        c0 = time.process_time()
        sol = interior_point(qp, self.tol, self.max_iterations)
        return sol.x[1:], sol.iterations, sol.converged, time.process_time() - c0


def _csc(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int],
         ) -> tuple[ca.Sparsity, np.ndarray]:
    """CasADi sparsity of the pattern (rows, cols) and the permutation of values into it."""
    order = sp.csc_matrix((np.arange(1, rows.size + 1, dtype=float), (rows, cols)), shape=shape)
    order.sort_indices()
    sparsity = ca.Sparsity(shape[0], shape[1], order.indptr.tolist(), order.indices.tolist())
    return sparsity, order.data.astype(int) - 1


class _ConicSolver:
    """A ``casadi.conic`` behind ``Function.buffer`` (inputs: dense nonzero vectors)."""

    plugin = ''
    scaled = False        # objective divided by 1 + max |g| (HPIPM's tolerances are absolute)

    def __init__(self, options: dict) -> None:
        self.options = options
        self.cache: dict[tuple[int, int], dict] = {}

    # subclasses: pattern(N, m) -> dict(h_rows, h_cols, a_rows, a_cols, nv, na);
    # data(qp) -> (h values, g, a values, lba, uba, lbx, ubx) in pattern order; unpack(z, m)
    def build(self, qp: BoundedLqtQp) -> float:
        key = qp.shape
        if key in self.cache:
            return 0.0
        c0 = time.perf_counter()
        pat = self.pattern(*key)
        hs, hp = _csc(pat['h_rows'], pat['h_cols'], (pat['nv'], pat['nv']))
        asp, ap = _csc(pat['a_rows'], pat['a_cols'], (pat['na'], pat['nv']))
        solver = ca.conic('qp', self.plugin, {'h': hs, 'a': asp},
                          {**self.options, 'error_on_fail': False})
        sym = {k: ca.MX.sym(k, n) for k, n in (('h', hs.nnz()), ('g', pat['nv']),
                                               ('a', asp.nnz()), ('lba', pat['na']),
                                               ('uba', pat['na']), ('lbx', pat['nv']),
                                               ('ubx', pat['nv']))}
        out = solver(h=ca.MX(hs, sym['h']), g=sym['g'], a=ca.MX(asp, sym['a']),
                     lba=sym['lba'], uba=sym['uba'], lbx=sym['lbx'], ubx=sym['ubx'])
        # every output bound: the HPIPM interface writes its multipliers unconditionally
        names = ('x', 'cost', 'lam_a', 'lam_x')
        wrapped = ca.Function('wrapped', list(sym.values()), [out[k] for k in names])
        buf, evaluate = wrapped.buffer()
        res = [np.zeros(wrapped.nnz_out(i)) for i in range(len(names))]
        for i, r in enumerate(res):
            buf.set_res(i, memoryview(r))
        self.cache[key] = {'solver': solver, 'hs': hs, 'asp': asp, 'hp': hp, 'ap': ap,
                           'buffer': buf, 'eval': evaluate, 'x': res[0], 'res': res,
                           'pattern': pat}
        return time.perf_counter() - c0

    def _inputs(self, qp: BoundedLqtQp) -> tuple[dict, list[np.ndarray]]:
        entry = self.cache[qp.shape]
        hv, g, av, lba, uba, lbx, ubx = self.data(qp, entry['pattern'])
        scale = 1.0 + float(np.max(np.abs(qp.g_lin))) if self.scaled else 1.0
        args = [np.ascontiguousarray(hv[entry['hp']] / scale), np.ascontiguousarray(g / scale),
                np.ascontiguousarray(av[entry['ap']]), lba, uba, lbx, ubx]
        return entry, args

    def solve(self, qp: BoundedLqtQp) -> np.ndarray:
        entry, args = self._inputs(qp)
        for i, a in enumerate(args):
            entry['buffer'].set_arg(i, memoryview(a))
        entry['eval']()
        return self.unpack(entry['x'], qp.shape)

    def solve_with_stats(self, qp: BoundedLqtQp) -> tuple[np.ndarray, int, bool, float]:
        entry, (hv, g, av, lba, uba, lbx, ubx) = self._inputs(qp)
        out = entry['solver'](h=ca.DM(entry['hs'], hv), g=g, a=ca.DM(entry['asp'], av),
                              lba=lba, uba=uba, lbx=lbx, ubx=ubx)   # (a pass with stats)
        stats = entry['solver'].stats()
        z = np.asarray(out['x']).ravel()
        # OSQP and PIQP report neither iterations nor their own time through CasADi
        timed = stats.get('n_call_solver', 0) > 0
        return (self.unpack(z, qp.shape), int(stats.get('iter_count', -1)),
                bool(stats.get('success', False)),
                float(stats['t_proc_solver']) if timed else np.nan)


def _block_pattern(offsets_r: np.ndarray, offsets_c: np.ndarray, m: int,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of dense m x m blocks at the given offsets (row-major per block)."""
    r, c = np.meshgrid(np.arange(m), np.arange(m), indexing='ij')
    return ((offsets_r[:, None, None] + r[None]).ravel(),
            (offsets_c[:, None, None] + c[None]).ravel())


class CondensedConic(_ConicSolver):
    """The QP in x_1..x_n-1, as ``interior_point`` sees it (OSQP, qpOASES)."""

    def __init__(self, plugin: str, options: dict) -> None:
        super().__init__(options)
        self.plugin = self.name = plugin

    def pattern(self, N: int, m: int) -> dict:
        blocks = np.arange(N) * m
        hr, hc = _block_pattern(blocks, blocks, m)
        k = (np.arange(N - 1)[:, None] * m + np.arange(m)[None]).ravel()
        idx = np.arange(N * m)
        return {'h_rows': np.concatenate([hr, k, k + m]),
                'h_cols': np.concatenate([hc, k + m, k]),
                'a_rows': np.concatenate([idx, idx[m:], N * m + idx, N * m + idx[m:]]),
                'a_cols': np.concatenate([idx, idx[:-m], idx, idx[:-m]]),
                'nv': N * m, 'na': 2 * N * m}

    def data(self, qp: BoundedLqtQp, pat: dict) -> tuple[np.ndarray, ...]:
        N, m = qp.shape
        blocks = qp.T.copy()
        d = np.arange(m)
        blocks[:, d, d] += qp.e_diag
        hv = np.concatenate([blocks.ravel(), qp.e_off.ravel(), qp.e_off.ravel()])
        av = np.concatenate([np.ones(N * m), -qp.la[1:].ravel(), np.ones(N * m),
                             -qp.ha[1:].ravel()])
        # x_i+1 - la x_i >= lb0; x_i+1 - ha x_i <= hb0
        lba = np.concatenate([qp.lb0.ravel(), np.full(N * m, -np.inf)])
        uba = np.concatenate([np.full(N * m, np.inf), qp.hb0.ravel()])
        return (hv, qp.g_lin.ravel(), av, lba, uba, np.full(N * m, -np.inf),
                np.full(N * m, np.inf))

    @staticmethod
    def unpack(z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        return np.asarray(z).reshape(shape).copy()


class OcpConic(_ConicSolver):
    """The QP in HPIPM's OCP form: [x_0 u_0 x_1 u_1 ... x_N], x_k+1 = la_k x_k + lb_k + u_k,
    0 <= u_k, u_k - (ha_k - la_k) x_k <= hb_k - lb_k; x_0 fixed by its bounds."""

    plugin = name = 'hpipm'
    scaled = True

    def pattern(self, N: int, m: int) -> dict:
        xo = np.arange(N + 1) * 2 * m                  # x_k
        uo = xo[:-1] + m                               # u_k
        ro = np.arange(N) * 2 * m                      # gap rows, then general rows
        d = np.arange(m)
        qr, qc = _block_pattern(xo, xo, m)
        diag = [(uo[:, None] + d).ravel(), (xo[:-1, None] + d).ravel()]
        return {'h_rows': np.concatenate([qr, diag[0], diag[0], diag[1]]),
                'h_cols': np.concatenate([qc, diag[0], diag[1], diag[0]]),
                'a_rows': np.concatenate([(ro[:, None] + d).ravel()] * 3
                                         + [(ro[:, None] + m + d).ravel()] * 2),
                'a_cols': np.concatenate([diag[1], diag[0], (xo[1:, None] + d).ravel(),
                                          diag[1], diag[0]]),
                'nv': (2 * N + 1) * m, 'na': 2 * N * m, 'xo': xo, 'uo': uo}

    def __init__(self, options: dict) -> None:
        super().__init__(options)
        self.base_options = options

    def build(self, qp: BoundedLqtQp) -> float:
        N, m = qp.shape             # HPIPM's stage structure, given (no detection)
        self.options = {**self.base_options, 'N': N, 'nx': [m] * (N + 1),
                        'nu': [m] * N + [0], 'ng': [m] * N + [0]}
        return super().build(qp)

    def data(self, qp: BoundedLqtQp, pat: dict) -> tuple[np.ndarray, ...]:
        N, m = qp.shape
        phi, psi, C, ke = qp.phi, qp.psi, qp.C, qp.k_eff
        ctq = np.swapaxes(C, 1, 2) @ qp.Q
        track = qp.w[:, None, None] * (phi[:, :, None] * (ctq @ C) * phi[:, None, :])
        track_lin = -qp.w[:, None] * phi * np.einsum(
            'nmp,np->nm', ctq, qp.tau_ref - np.einsum('npm,nm->np', C, psi))
        if qp.P is not None:
            cp = phi[-1][:, None] * (C[-1].T @ np.asarray(qp.P, dtype=float))
            track[-1] += cp @ C[-1] * phi[-1][None, :]
            track_lin[-1] -= cp @ (qp.tau_ref[-1] - C[-1] @ psi[-1])
        track[0] = 0.0                                 # x_0 is data
        track_lin[0] = 0.0
        # effort of interval k: f_k+1 - f_k = a_k x_k + b_k u_k + c_k (elementwise)
        a = phi[1:] * qp.la - phi[:-1]
        b = phi[1:]
        c = phi[1:] * qp.lb + np.diff(psi, axis=0)
        d = np.arange(m)
        track[:-1, d, d] += ke * a ** 2
        track_lin[:-1] += ke * a * c
        s = ke * a * b
        hv = np.concatenate([track.ravel(), (ke * b ** 2).ravel(), s.ravel(), s.ravel()])
        g = np.zeros(pat['nv'])
        g[(pat['xo'][:, None] + d).ravel()] = track_lin.ravel()
        g[(pat['uo'][:, None] + d).ravel()] = (ke * b * c).ravel()
        av = np.concatenate([qp.la.ravel(), np.ones(N * m), -np.ones(N * m),
                             -(qp.ha - qp.la).ravel(), np.ones(N * m)])
        lba = np.empty((N, 2, m))
        uba = np.empty((N, 2, m))
        lba[:, 0] = uba[:, 0] = -qp.lb
        lba[:, 1] = -2.0
        uba[:, 1] = qp.hb - qp.lb
        # bounds: x_0 fixed, u_k >= 0; the rest are never active (HPIPM bounds every variable)
        lbx = np.full(pat['nv'], -1.0)
        ubx = np.full(pat['nv'], 2.0)
        lbx[:m] = ubx[:m] = qp.x0
        lbx[(pat['uo'][:, None] + d).ravel()] = 0.0
        return hv, g, av, lba.ravel(), uba.ravel(), lbx, ubx

    def unpack(self, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        N, m = shape
        z = np.asarray(z).ravel()
        return z[:(2 * N + 1) * m].reshape(-1, m)[2::2].copy()


def make_solvers(names: list[str], tracker: NeuromuscularTracker, hpipm_tol: float = 1e-8,
                 osqp_eps: float = 1e-8, piqp_eps: float = 1e-8,
                 hpipm_mode: str = 'speed') -> dict:
    """The solvers ``names`` (see the module docstring), Stage 2's settings from tracker."""
    st = tracker.settings
    tol = hpipm_tol
    factory = {
        'home': lambda: HomeSolver(st.plan_tol, st.plan_max_iterations),
        'hpipm': lambda: OcpConic({'hpipm': {'mode': hpipm_mode, 'iter_max': 100,
                                             'res_g_max': tol, 'res_b_max': tol,
                                             'res_d_max': tol, 'res_m_max': tol}}),
        'piqp': lambda: CondensedConic('piqp', {'piqp': {'eps_abs': piqp_eps,
                                                         'eps_rel': piqp_eps}}),
        'osqp': lambda: CondensedConic('osqp', {'osqp': {
            'eps_abs': osqp_eps, 'eps_rel': osqp_eps, 'max_iter': 20000, 'polish': True,
            'verbose': False}}),
        'qpoases': lambda: CondensedConic('qpoases', {'printLevel': 'none', 'CPUtime': 300.0,
                                                      'nWSR': 1000000}),
    }
    for name in names:
        if name.startswith('home_'):
            home_tol = float(name.removeprefix('home_'))
            factory[name] = lambda t=home_tol: HomeSolver(t, st.plan_max_iterations)
    unknown = set(names) - set(factory)
    if unknown:
        raise SystemExit(f'unknown solvers {sorted(unknown)}; choose from {sorted(factory)}')
    return {n: factory[n]() for n in names}


# ---------------------------------------------------------------------------- measurement
@dataclass
class SetResult:
    label: str
    solver: str
    n_qp: int
    build_s: float = 0.0
    builds: int = 0
    p50: list = field(default_factory=list)      # per repeat, s
    p99: list = field(default_factory=list)
    inner_p50: float = np.nan
    iterations: list = field(default_factory=list)
    failures: int = 0
    da_exact: float = 0.0          # max |a - a_exact|
    df_exact: float = 0.0          # max |f - f_exact| / F0
    dj_exact: float = 0.0          # (J - J_exact) / J_exact, largest in magnitude
    slack_min: float = np.inf
    pattern_diff: int = 0          # active-set elements that differ from the home-made plan's
    pattern_diff_exact: int = 0    # ... from the exact solution's
    elements: int = 0              # active-set elements compared (steps x muscles)


def _pattern(qp: BoundedLqtQp, x: np.ndarray, margin: float) -> np.ndarray:
    lo, hi = qp.constraints(x)
    width = lo + hi
    pos = np.clip(lo / np.where(width > 0, width, 1.0), 0.0, 1.0)
    return np.where(pos >= 1 - margin, 1, np.where(pos <= margin, -1, 0))


def exact_solution(qp: BoundedLqtQp) -> tuple[np.ndarray, bool]:
    """The QP's optimum to rounding, independent of any solver's stopping rule: the KKT system
    of an active set solved directly (sparse LU), the active set corrected until the point
    checks out (inactive constraints hold to 1e-12, multipliers >= -1e-9 of the largest:
    then it is the optimum of this convex QP; a primal-dual active-set iteration), starting
    from the active set of a tight interior-point solution (multiplier above slack; tol
    1e-10, else 1e-9, else 1e-8 - closer, z/s overflows). Returns (x [N, m], checked)."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        for tol in (1e-10, 1e-9, 1e-8):
            ip = interior_point(qp, tol, 200)
            if ip.converged and np.all(np.isfinite(ip.x)):
                break
        else:
            raise RuntimeError('the interior point did not converge at tol 1e-8')
    N, m = qp.shape
    nv = N * m
    condensed = CondensedConic('exact', {})
    pat = condensed.pattern(N, m)
    hv, g, av, lba, uba, _, _ = condensed.data(qp, pat)
    H = sp.csc_matrix((hv, (pat['h_rows'], pat['h_cols'])), shape=(nv, nv))
    A = sp.csr_matrix((av, (pat['a_rows'], pat['a_cols'])), shape=(2 * nv, nv))
    bound = np.concatenate([lba[:nv], uba[nv:]])     # lower rows: lb0; upper rows: hb0
    sign = np.repeat([1.0, -1.0], nv)                # slack = sign (A x - bound) >= 0
    active = np.concatenate([(ip.z_lo > ip.slack_lo).ravel(), (ip.z_hi > ip.slack_hi).ravel()])
    for _ in range(20):
        B = A[active]
        kkt = sp.bmat([[H, B.T], [B, None]], format='csc')
        sol = spla.spsolve(kkt, np.concatenate([-g, bound[active]]))
        x = sol[:nv]
        z = np.zeros(2 * nv)
        z[active] = -sign[active] * sol[nv:]         # H x + g = A' (sign z)
        violated = ~active & (sign * (A @ x - bound) < -1e-12)
        negative = active & (z < -1e-9 * np.abs(z).max())
        if not violated.any() and not negative.any():
            return x.reshape(N, m), True
        active = (active | violated) & ~negative
    return x.reshape(N, m), False


def run_set(label: str, problems: list[BoundedLqtQp], solvers: dict, repeat: int,
            f0: np.ndarray, margin: float, production: HomeSolver,
            limits: dict[str, int]) -> list[SetResult]:
    """Accuracy and iterations from one pass per solver; then ``repeat`` timing passes with
    the solvers interleaved QP by QP (a load change on the shared machine hits all alike).
    f0 [m] peak forces (N); margin: Stage 2's saturation margin; production: the solver
    Stage 2 runs (its active sets are the reference of 'diffs vs home'); ``limits``: at most
    this many windows for a solver (the first ones)."""
    exact, checked = zip(*(exact_solution(qp) for qp in problems))
    print(f'  {label}: exact solutions (KKT of the active set) checked optimal on '
          f'{sum(checked)} of {len(problems)} QPs', flush=True)
    home = [production.solve(qp) for qp in problems]
    results: dict[str, SetResult] = {}
    for name, solver in solvers.items():
        count = len(problems)
        if name == 'qpoases' and count == 1:
            print(f'  {label}: qpoases skipped (dense active set, > 300 s)')
            continue
        count = min(count, limits.get(name, count))
        res = SetResult(label=label, solver=name, n_qp=count)
        inner, total = [], []
        for j, qp in enumerate(problems[:count]):
            b = solver.build(qp)
            res.build_s += b
            res.builds += b > 0
            c0 = time.process_time()
            x, its, ok, t_in = solver.solve_with_stats(qp)
            total.append(time.process_time() - c0)
            res.iterations.append(its)
            res.failures += not ok
            inner.append(t_in)
            dx = x - exact[j]
            res.da_exact = max(res.da_exact, float(np.abs(dx).max()))
            res.df_exact = max(res.df_exact, float(np.max(np.abs(qp.phi[1:] * dx) / f0)))
            j_exact = qp.cost(exact[j])
            res.dj_exact = max(res.dj_exact, (qp.cost(x) - j_exact) / abs(j_exact), key=abs)
            res.slack_min = min(res.slack_min, *(float(c.min()) for c in qp.constraints(x)))
            pattern = _pattern(qp, x, margin)
            res.pattern_diff += int(np.sum(pattern != _pattern(qp, home[j], margin)))
            res.pattern_diff_exact += int(np.sum(pattern != _pattern(qp, exact[j], margin)))
            res.elements += pattern.size
        res.inner_p50 = float(np.median(inner))    # NaN: not reported
        if name == 'qpoases':     # it hot-starts a repeated QP: one cold solve only
            res.p50, res.p99 = [float(np.percentile(total, 50))], [float(np.percentile(total, 99))]
        results[name] = res
        print(f'  {label}: {name} checked', flush=True)
    timed = [n for n in results if n != 'qpoases']
    for _ in range(repeat):
        times: dict[str, list[float]] = {n: [] for n in timed}
        for j, qp in enumerate(problems):
            for name in timed:
                if j >= results[name].n_qp:
                    continue
                c0 = time.process_time()
                solvers[name].solve(qp)
                times[name].append(time.process_time() - c0)
        for name in timed:
            results[name].p50.append(float(np.percentile(times[name], 50)))
            results[name].p99.append(float(np.percentile(times[name], 99)))
    return list(results.values())


def downstream(inputs: dict, stride_samples: int, tol: float) -> float:
    """Stage 2's windowed muscle forces (H = 100 ms, stride in samples) at the production
    plan_tol against the same at ``tol``: max |df| / F0 (what the QP's accuracy changes in
    Stage 2's output)."""
    forces = []
    for settings in (load_stage2_settings(), load_stage2_settings(plan_tol=tol)):
        tracker = NeuromuscularTracker(settings=settings)
        h = float(inputs['t'][1] - inputs['t'][0])
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            run = tracker.track(inputs['t'], inputs['tau'], inputs['theta'],
                                inputs['theta_dot'], inputs['theta_ddot'], inputs['a0'],
                                mode='windowed', window_length=WINDOW_S,
                                window_stride=stride_samples * h)
        forces.append(run.f)
    return float(np.max(np.abs(forces[0] - forces[1]) / tracker.f0))


def _spread(values: list[float]) -> str:
    v = 1e3 * np.asarray(values)
    return f'{np.median(v):.2f} [{v.min():.2f}-{v.max():.2f}]'


def print_table(results: list[SetResult]) -> None:
    print('| problem set | solver | QPs | build s (builds) | CPU ms/solve p50 [range] | '
          'p99 [range] | solver time p50 ms (one pass) | iterations mean/max | failed | '
          'max abs da vs exact | max abs df/F0 vs exact | max rel dJ vs exact | min slack | '
          'active-set diffs vs home / exact (of) |')
    print('|---|---|---|---|---|---|---|---|---|---|---|---|---|---|')
    for r in results:
        its = np.asarray(r.iterations)
        its_s = f'{its.mean():.1f}/{its.max()}' if its.min() >= 0 else 'n/a'
        inner = ('-' if r.solver.startswith('home') else 'n/a' if np.isnan(r.inner_p50)
                 else f'{1e3 * r.inner_p50:.2f}')
        print(f'| {r.label} | {r.solver} | {r.n_qp} | {r.build_s:.2f} ({r.builds}) | '
              f'{_spread(r.p50)} | {_spread(r.p99)} | {inner} | {its_s} | {r.failures} | '
              f'{r.da_exact:.1e} | {r.df_exact:.1e} | {r.dj_exact:+.1e} | '
              f'{r.slack_min:.0e} | {r.pattern_diff} / {r.pattern_diff_exact} '
              f'({r.elements}) |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', type=Path, default=DEFAULT_BAG)
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--stream-s', type=float, default=10.0,
                    help='long stream for the windows (set 4) and the home-only full horizon '
                         '(set 5), s')
    ap.add_argument('--stream-full-s', type=float, default=1.0,
                    help='stream length of the full horizon all solvers get (set 3), s')
    ap.add_argument('--stream-stride', type=int, default=10,
                    help='window stride on the long stream, samples')
    ap.add_argument('--solvers', default='home,home_1e-9,hpipm,piqp,osqp,qpoases')
    ap.add_argument('--qpoases-windows', type=int, default=1)
    ap.add_argument('--osqp-windows', type=int, default=216,
                    help='OSQP gets the first this many windows of a set (p99 > 1 s)')
    ap.add_argument('--sets', default='1,2,3,4,5')
    ap.add_argument('--hpipm-tol', type=float, default=1e-8,
                    help='HPIPM residual tolerances (objective scaled to |g| ~ 1)')
    ap.add_argument('--hpipm-mode', default='speed',
                    choices=('speed', 'speed_abs', 'balance', 'robust'))
    ap.add_argument('--osqp-eps', type=float, default=1e-8, help='OSQP eps_abs = eps_rel')
    ap.add_argument('--piqp-eps', type=float, default=1e-8, help='PIQP eps_abs = eps_rel')
    ap.add_argument('--downstream-tol', type=float, default=1e-9,
                    help="Stage 2's windowed forces at plan_tol vs this tolerance (0: skip)")
    args = ap.parse_args()
    tracker = NeuromuscularTracker()
    names = args.solvers.split(',')
    make_solvers(names, tracker)                         # unknown names fail here, not later
    production = HomeSolver(tracker.settings.plan_tol, tracker.settings.plan_max_iterations)
    print(f'machine: {os.cpu_count()} cores, load average at start '
          f'{" ".join(f"{x:.1f}" for x in os.getloadavg())}', flush=True)
    c0 = time.process_time()
    jump = stage1_inputs(args.bag, tracker)
    print(f'Stage 1 (optimal tracking, muscles): {time.process_time() - c0:.1f} s CPU; '
          f'{jump["t"].size} samples at {1 / (jump["t"][1] - jump["t"][0]):.0f} Hz',
          flush=True)
    stream = palindrome(jump, args.stream_s)
    short_stream = palindrome(jump, args.stream_full_s)
    sets = {
        '1': ('jump, full horizon', lambda: record_problems(tracker, jump, False)),
        '2': ('jump, windows 100 ms, stride 1', lambda: record_problems(tracker, jump, True)),
        '3': (f'stream {args.stream_full_s:g} s, full horizon',
              lambda: record_problems(tracker, short_stream, False)),
        '4': (f'stream {args.stream_s:g} s, windows 100 ms, stride {args.stream_stride}',
              lambda: record_problems(tracker, stream, True, args.stream_stride)),
        '5': (f'stream {args.stream_s:g} s, full horizon',
              lambda: record_problems(tracker, stream, False)),
    }
    # casadi.conic('hpipm') builds in ~N^2.4 (27 s at N = 1080, 140 s at 2160): set 5 would take
    # hours; OSQP needs minutes per solve there. Set 5 shows the home-made solver's O(N).
    only = {'5': ['home']}
    results = []
    for key in args.sets.split(','):
        label, make = sets[key]
        problems = make()
        shape = problems[0].shape
        print(f'{label}: {len(problems)} QPs, first {shape[0]} intervals x {shape[1]} '
              'muscles', flush=True)
        # fresh solvers per set: builds counted per set, no hot start from the previous set
        chosen = make_solvers([n for n in names if n in only.get(key, names)], tracker,
                              args.hpipm_tol, args.osqp_eps, args.piqp_eps,
                              args.hpipm_mode)
        done = run_set(label, problems, chosen, args.repeat, tracker.f0,
                       tracker.settings.saturation_margin, production,
                       {'qpoases': args.qpoases_windows, 'osqp': args.osqp_windows})
        print_table(done)
        results += done
    if args.downstream_tol > 0:
        for label, inputs, stride in (('jump', jump, 1), (f'stream {args.stream_s:g} s', stream,
                                                          args.stream_stride)):
            print(f'Stage 2 windowed on the {label} (stride {stride}): forces at plan_tol '
                  f'{tracker.settings.plan_tol:g} vs {args.downstream_tol:g}: max |df|/F0 '
                  f'{downstream(inputs, stride, args.downstream_tol):.1e}', flush=True)
    print(f'\nload average at the end {" ".join(f"{x:.1f}" for x in os.getloadavg())}\n')
    print_table(results)


if __name__ == '__main__':
    main()
