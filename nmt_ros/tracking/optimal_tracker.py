"""Stage 1 by optimal tracking (beyond the paper): joint torques that make the model fit all the
observations at once, over the whole trial.

The paper's skeletal motion tracker (``skeletal_tracker``) balances its seven outputs
instant by instant. Here the same model, driven by the same three joint torques, is fitted to
the raw observations over the whole recording by direct collocation (the machinery of the
reference jump's optimisation, OpenSim Moco's "tracking" problem):

    minimise  sum_k |(theta(t_k) - theta_obs,k) / sigma_theta|^2             (120 Hz samples)
            + sum_j |(s(t_j) + [0, 0, b(t_j)] - s_obs,j) / sigma_s|^2       (1080 Hz samples)
            + w_rate N sum_i |(tau_i+1 - tau_i) / 100 N m|^2 / h              (torque smoothness)
    subject to Eq. 1 (implicit, trapezoidal, one interval per force sample), rest at t = 0,

with the moment bias b(t) a low-order polynomial vanishing at t = 0. The fit weighs each
channel by its noise (with a bias allowance on the angles) instead of filtering each channel
on its own, so the ground forces inform the whole-body accelerations the angles cannot resolve
after a 10 Hz filter. The result is again a dynamically consistent motion of the model (the
collocation solution) with its torques. Offline only: about 1 s of CPU for the 0.25 s jump.
The skeletal tracker's result is the initial guess.
"""
from __future__ import annotations

from dataclasses import dataclass
import time

import casadi as ca
import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.study.trial import Observations
from nmt_ros.tracking.skeletal_tracker import SKTResult, liftoff_time

_QDD_SCALE = 100.0   # rad/s^2 or m/s^2 per unit of an acceleration variable
_TAU_SCALE = 100.0   # N m per unit of a torque variable


@dataclass(frozen=True)
class OptimalTrackingSettings:
    """Noise model (the weights) and numerics of the tracking optimisation."""

    angle_sd_deg: tuple[float, ...] = (5.0, 3.0, 2.0, 1.0)   # foot..HAT
    angle_bias_allowance: float = 1.0          # SD multiplier (sqrt 2: a bias as large again)
    force_sd_bw: float = 0.02
    moment_lever_m: float = 0.17               # moment SD = force SD x this lever
    # Moment bias b(t) = sum c_k (t/T)^k, k = 1..n: 7 terms follow both a one-lobe and a
    # three-harmonic bias (tested on both shapes; 3 terms leave the hip 2 % worse).
    moment_bias_terms: int = 7
    torque_rate_weight: float = 1e-3
    liftoff_force_bw: float = 0.02
    tol: float = 1e-6
    max_iter: int = 2000


_SOLVERS: dict[tuple, tuple] = {}


def _build(model: JumperModel, n: int, h: float, idx: np.ndarray,
           st: OptimalTrackingSettings) -> tuple:
    """The NLP for n intervals of h seconds and angle samples at grid indices ``idx``.

    Observations and contact anchors are parameters, so trials of the same length share it.
    """
    key = (id(model), n, round(h, 12), idx.tobytes(), st)
    if key in _SOLVERS:
        return _SOLVERS[key]
    bw = model.p.body_weight
    n_a = idx.size
    q = ca.MX.sym('q', 6, n + 1)
    qd = ca.MX.sym('qd', 6, n + 1)
    qdd_v = ca.MX.sym('qdd', 6, n + 1)
    tau_v = ca.MX.sym('tau', 3, n + 1)
    cb = ca.MX.sym('c_bias', st.moment_bias_terms)
    w = ca.MX.sym('wrench_obs', n + 1, 3)
    ang = ca.MX.sym('angles_obs', n_a, 4)
    x0 = ca.MX.sym('anchors', 2)
    qdd, tau = _QDD_SCALE * qdd_v, _TAU_SCALE * tau_v

    x = ca.SX.sym('x', 12)
    a = ca.SX.sym('a', 6)
    u = ca.SX.sym('u', 3)
    xa = ca.SX.sym('x0', 2)
    scale = ca.DM([1 / 100.0] * 4 + [1 / bw] * 2)
    node = ca.Function('ocp_node', [x, a, u, xa], [
        scale * model.dynamics_residual(x[:6], x[6:], a, u, xa),
        model.contact_outputs(x[:6], x[6:], xa)])
    residual, s_model = node.map(n + 1, 'serial')(ca.vertcat(q, qd), qdd, tau,
                                                 ca.repmat(x0, 1, n + 1))
    constraints = ca.vertcat(
        ca.vec(q[:, 1:] - q[:, :-1] - h / 2 * (qd[:, 1:] + qd[:, :-1])),   # trapezoidal
        ca.vec(qd[:, 1:] - qd[:, :-1] - h / 2 * (qdd[:, 1:] + qdd[:, :-1])),
        ca.vec(residual), qd[:, 0], qdd_v[:, 0])                             # Eq. 1; at rest
    t_grid = np.arange(n + 1) * h
    basis = np.column_stack([(t_grid / t_grid[-1]) ** (k + 1)
                             for k in range(st.moment_bias_terms)])
    sig_s = np.array([st.force_sd_bw * bw] * 2 + [st.force_sd_bw * bw * st.moment_lever_m])
    s_fit = s_model.T + ca.horzcat(ca.DM.zeros(n + 1, 2), ca.DM(basis) @ cb)
    cost = ca.sumsqr((s_fit - w) / ca.repmat(ca.DM(sig_s).T, n + 1, 1))
    sig_a = np.radians(st.angle_sd_deg) * st.angle_bias_allowance
    cost += ca.sumsqr((q[0:4, list(idx)].T - ang) / ca.repmat(ca.DM(sig_a).T, n_a, 1))
    cost += st.torque_rate_weight * n * ca.sumsqr(tau_v[:, 1:] - tau_v[:, :-1]) / h
    z = ca.vertcat(ca.vec(q), ca.vec(qd), ca.vec(qdd_v), ca.vec(tau_v), cb)
    p = ca.vertcat(ca.vec(w), ca.vec(ang), x0)
    solver = ca.nlpsol('stage1_tracking', 'ipopt',
                       {'x': z, 'p': p, 'f': cost, 'g': constraints},
                       {'expand': True, 'print_time': False, 'show_eval_warnings': False,
                        'ipopt': {'print_level': 0, 'tol': st.tol, 'max_iter': st.max_iter,
                                  'linear_solver': 'mumps', 'sb': 'yes'}})
    _SOLVERS[key] = (solver, basis)
    return _SOLVERS[key]


def track_optimal(model: JumperModel, obs: Observations, guess: SKTResult,
                  settings: OptimalTrackingSettings = OptimalTrackingSettings(),
                  ) -> SKTResult:
    """Fit the model to ``obs`` (one collocation interval per force-plate sample).

    ``guess``: the skeletal tracker's result on the same observations (initial guess, contact
    anchors and the static initial state's neighbourhood). Returns an ``SKTResult`` on the
    force-plate instants; ``status`` is 'ok' or the solver's failure.
    """
    c0 = time.process_time()
    st = settings
    bw = model.p.body_weight
    t_w = np.asarray(obs.t_wrench, dtype=float)
    n = t_w.size - 1
    h = float(np.mean(np.diff(t_w)))
    x0 = np.asarray(guess.x0, dtype=float)
    idx = np.rint((obs.t_angles - t_w[0]) / h).astype(int)
    keep = (idx >= 0) & (idx <= n)
    solver, basis = _build(model, n, h, idx[keep], st)
    z0 = np.concatenate([_on_grid(guess.q, n).ravel(), _on_grid(guess.qd, n).ravel(),
                         (_on_grid(guess.qdd, n) / _QDD_SCALE).ravel(),
                         (_on_grid(guess.tau, n) / _TAU_SCALE).ravel(),
                         np.zeros(st.moment_bias_terms)])
    p = np.concatenate([obs.wrench[:n + 1].ravel(order='F'),
                        obs.angles[keep].ravel(order='F'), x0])
    sol = solver(x0=z0, p=p, lbg=0.0, ubg=0.0)
    stats = solver.stats()
    zz = np.asarray(sol['x']).ravel()
    blocks = np.split(zz[:21 * (n + 1)], np.cumsum([6, 6, 6, 3])[:-1] * (n + 1))
    Q, QD, QDD, TAU = (b.reshape(n + 1, -1) for b in blocks)
    QDD, TAU = QDD * _QDD_SCALE, TAU * _TAU_SCALE
    s, = model.batch(model.contact_outputs, Q, QD, x0)
    ok = bool(stats['success'])
    res = SKTResult(t=t_w - t_w[0], q=Q, qd=QD, qdd=QDD, tau=TAU, s=s,
                    bias=basis @ zz[21 * (n + 1):], residual=np.zeros((n + 1, 7)), x0=x0,
                    status='ok' if ok else 'solver: ' + str(stats['return_status']),
                    events=[] if ok else [{'t': 0.0, 'reason': str(stats['return_status'])}],
                    cpu_s=time.process_time() - c0)
    res.liftoff_s = liftoff_time(res.t, s[:, 1], st.liftoff_force_bw * bw)
    return res


def _on_grid(values: np.ndarray, n: int) -> np.ndarray:
    """The guess's first n + 1 samples [n + 1, k], the last one held if it is shorter.

    Raveled row by row this is CasADi's column-major ``vec`` of the [k, n + 1] variables.
    """
    out = np.empty((n + 1, values.shape[1]))
    k = min(values.shape[0], n + 1)
    out[:k] = values[:k]
    out[k:] = values[k - 1]
    return out
