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

With ``actuation='muscle'`` the three torques are not free: they are the nine muscles' torques
C(theta) F_MT(a, l_MT, v_MT) (Eq. 8b, 10b), with activations driven by excitations
0 <= u <= 1 through Eq. 8a (trapezoidal, like the skeleton), and the torque smoothness term
replaced by small excitation and excitation-rate terms. This is OpenSim Moco's muscle-driven
tracking problem posed on the raw observations. The prior it adds is the muscles' capacity:
torques that no activation pattern can make (the saturated end of a maximal push-off), and
torque shapes that activation dynamics cannot follow, are excluded, so the estimate is both
closer to the actual and one that Stage 2 can track. The initial guess of a and u is Stage 2
on the skeletal tracker's torques. About 5.4 s of CPU for the 0.25 s jump, of which 0.2 s builds
the NLP (its Lagrangian Hessian and constraint Jacobian are assembled from one node's:
``_lagrangian_hessian``, ``_constraint_jacobian``);
0.2 GB of memory (bench/bench_stage1.py).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import time

import casadi as ca
import numpy as np

from nmt_ros.model.contact import liftoff_time
from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Observations, SKTResult
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE

_QDD_SCALE = 100.0   # rad/s^2 or m/s^2 per unit of an acceleration variable
_TAU_SCALE = 100.0   # N m per unit of a torque variable


@dataclass(frozen=True)
class OptimalTrackingSettings:
    """Noise model (the weights) and numerics of the tracking optimisation."""

    # Channel weights 1/SD: the observation specification's noise (METHOD.md 1.3).
    angle_sd_deg: tuple[float, ...] = OBSERVATION_NOISE.angle_sd_deg   # foot..HAT
    angle_bias_allowance: float = 1.0          # SD multiplier (sqrt 2: a bias as large again)
    force_sd_bw: float = OBSERVATION_NOISE.force_sd_bw
    moment_lever_m: float = OBSERVATION_NOISE.moment_lever_m   # moment SD = force SD x lever
    # Moment bias b(t) = sum c_k (t/T)^k, k = 1..n: 7 terms follow both a one-lobe and a
    # three-harmonic bias (tested on both shapes; 3 terms leave the hip 2 % worse).
    moment_bias_terms: int = 7
    torque_rate_weight: float = 1e-3
    # 'torque': the three joint torques are free (the paper's Stage 1 model);
    # 'muscle': they are the nine muscles' torques, C(theta) F(a, l, v), with activations
    # driven by excitations u in [0, 1] (Eq. 8): only torques the muscles can make.
    actuation: str = 'torque'
    excitation_weight: float = 1e-2            # muscle actuation: sum u^2 dt / T
    # muscle actuation: sum (du/dt)^2 dt / T x s^2. 1e-2 rather than 1e-4: 20-40 % less knee
    # and hip torque error under the paper's noise (seeds 0-11, both bias shapes), for a
    # smoothing bias of 0.35 % of peak on noise-free data.
    excitation_rate_weight: float = 1e-2
    liftoff_force_bw: float = OBSERVATION_NOISE.force_sd_bw   # the plate's noise (contact.py)
    tol: float = 1e-6
    # The fit ends this long after the guess's lift-off (None: the whole record; also when
    # the guess has no lift-off). Flight adds little (the body is ballistic) but the NLP's
    # size and solve time grow with the record (muscles: about 20 ms of CPU per sample).
    flight_s: float | None = 0.05
    max_intervals: int = 1080     # longer fits are refused (bounds the solve: ~25 s at 1 s)
    # IPOPT's initial barrier: None = 1e-3 for muscle actuation (its guess, Stage 2 on the
    # tracker's torques, is close: a small barrier keeps IPOPT near it) and IPOPT's 0.1 for
    # torque actuation (1e-3 took 520 iterations on one noise seed, 0.1 converges).
    mu_init: float | None = None
    max_iter: int = 500        # typical: 30-60 iterations (tested over 30 noise realisations)


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
    cb = ca.MX.sym('c_bias', st.moment_bias_terms)
    w = ca.MX.sym('wrench_obs', n + 1, 3)
    ang = ca.MX.sym('angles_obs', n_a, 4)
    x0 = ca.MX.sym('anchors', 2)
    qdd = _QDD_SCALE * qdd_v
    x = ca.SX.sym('x', 12)
    acc = ca.SX.sym('acc', 6)
    xa = ca.SX.sym('x0', 2)
    scale = ca.DM([1 / 100.0] * 4 + [1 / bw] * 2)
    muscle = st.actuation == 'muscle'
    if muscle:
        nm = model.p.muscles.f0.size
        act = ca.MX.sym('a', nm, n + 1)
        exc = ca.MX.sym('u', nm, n + 1)
        aa, uu = ca.SX.sym('a', nm), ca.SX.sym('u', nm)
        tau_m, _ = model.muscle_torques(x[:6], x[6:], aa)
        node = ca.Function('ocp_node', [x, acc, aa, uu, xa], [
            scale * model.dynamics_residual(x[:6], x[6:], acc, tau_m, xa),
            model.contact_outputs(x[:6], x[6:], xa), model.activation_dynamics(uu, aa)],
            {'cse': True})   # common subexpressions: half the instructions, build and solve
        residual, s_model, adot = node.map(n + 1, 'serial')(
            ca.vertcat(q, qd), qdd, act, exc, ca.repmat(x0, 1, n + 1))
    else:
        tau_v = ca.MX.sym('tau', 3, n + 1)
        uu = ca.SX.sym('u', 3)
        node = ca.Function('ocp_node', [x, acc, uu, xa], [
            scale * model.dynamics_residual(x[:6], x[6:], acc, uu, xa),
            model.contact_outputs(x[:6], x[6:], xa)], {'cse': True})
        residual, s_model = node.map(n + 1, 'serial')(ca.vertcat(q, qd), qdd,
                                                     _TAU_SCALE * tau_v, ca.repmat(x0, 1, n + 1))
        adot = None

    def assemble(residual: ca.MX, adot: ca.MX | None) -> ca.MX:
        # (Order and layout relied on by _lagrangian_hessian and _constraint_jacobian; their
        # tests compare with CasADi's derivatives of the whole NLP.)
        extra = [] if adot is None else [
            ca.vec(act[:, 1:] - act[:, :-1] - h / 2 * (adot[:, 1:] + adot[:, :-1]))]
        return ca.vertcat(
            ca.vec(q[:, 1:] - q[:, :-1] - h / 2 * (qd[:, 1:] + qd[:, :-1])),   # trapezoidal
            ca.vec(qd[:, 1:] - qd[:, :-1] - h / 2 * (qdd[:, 1:] + qdd[:, :-1])),
            ca.vec(residual), qd[:, 0], qdd_v[:, 0], *extra)                 # Eq. 1; at rest

    constraints = assemble(residual, adot)
    linear_part = assemble(ca.MX.zeros(residual.shape),
                           None if adot is None else ca.MX.zeros(adot.shape))
    t_grid = np.arange(n + 1) * h
    basis = np.column_stack([(t_grid / t_grid[-1]) ** (k + 1)
                             for k in range(st.moment_bias_terms)])
    sig_s = np.array([st.force_sd_bw * bw] * 2 + [st.force_sd_bw * bw * st.moment_lever_m])
    s_fit = s_model.T + ca.horzcat(ca.DM.zeros(n + 1, 2), ca.DM(basis) @ cb)
    cost_fit = ca.sumsqr((s_fit - w) / ca.repmat(ca.DM(sig_s).T, n + 1, 1))
    sig_a = np.radians(st.angle_sd_deg) * st.angle_bias_allowance
    cost_quad = ca.sumsqr((q[0:4, list(idx)].T - ang) / ca.repmat(ca.DM(sig_a).T, n_a, 1))
    if muscle:
        t_total = n * h
        cost_quad += st.excitation_weight * h / t_total * ca.sumsqr(exc)
        cost_quad += (st.excitation_rate_weight / (h * t_total)
                      * ca.sumsqr(exc[:, 1:] - exc[:, :-1]))
        drive = [act, exc]
    else:
        cost_quad += st.torque_rate_weight * n * ca.sumsqr(tau_v[:, 1:] - tau_v[:, :-1]) / h
        drive = [tau_v]
    z = ca.vertcat(ca.vec(q), ca.vec(qd), ca.vec(qdd_v), *[ca.vec(d) for d in drive], cb)
    p = ca.vertcat(ca.vec(w), ca.vec(ang), x0)
    rows = [6, 6, 6] + [d.shape[0] for d in drive]
    hess = _lagrangian_hessian(node, muscle, n, h, z, p, cost_quad, sig_s, basis, rows)
    jac = _constraint_jacobian(node, muscle, n, h, z, p, constraints, linear_part, rows)
    if hess.size1_in(3) != constraints.numel():
        raise AssertionError('the Hessian assembly does not match the constraints')
    solver = ca.nlpsol('stage1_tracking', 'ipopt',
                       {'x': z, 'p': p, 'f': cost_fit + cost_quad, 'g': constraints},
                       {'expand': False, 'hess_lag': hess, 'jac_g': jac,
                        'print_time': False, 'show_eval_warnings': False,
                        'ipopt': {'print_level': 0, 'tol': st.tol, 'max_iter': st.max_iter,
                                  'linear_solver': 'mumps', 'sb': 'yes',
                                  'mu_init': st.mu_init if st.mu_init is not None
                                  else (1e-3 if muscle else 0.1)}})
    _SOLVERS[key] = (solver, basis)
    return _SOLVERS[key]


def _node_index(rows: list[int], n: int, nz: int, nb: int) -> np.ndarray:
    """[n + 1, sum(rows) + nb]: the global index in z of each node's local variables (the
    blocks of ``rows``, each stored node by node, then the nb bias coefficients)."""
    big_n = n + 1
    offsets = np.cumsum([0] + [r * big_n for r in rows])[:-1]
    local = np.concatenate([off + r * np.arange(big_n)[:, None] + np.arange(r)[None, :]
                            for off, r in zip(offsets, rows)], axis=1)
    return np.hstack([local, np.repeat(nz - nb + np.arange(nb)[None, :], big_n, 0)])


def _node_variables(xz: ca.MX, rows: list[int], n: int, nb: int) -> tuple[ca.MX, ca.MX]:
    """(the nodes' local variables [sum(rows), n + 1], the bias coefficients [nb]) of z."""
    big_n = n + 1
    cuts = list(np.cumsum([0] + [r * big_n for r in rows])) + [xz.numel()]
    blocks = ca.vertsplit(xz, cuts)
    return (ca.vertcat(*[ca.reshape(b, r, big_n) for b, r in zip(blocks[:-1], rows)]),
            blocks[-1])


def _gather(rows_out: np.ndarray, cols_out: np.ndarray, source: np.ndarray,
            coef: np.ndarray, shape: tuple[int, int], n_in: int) -> tuple[ca.Sparsity, ca.DM]:
    """Sparsity of the sum of entries (rows_out, cols_out) and the constant matrix that
    sums source values (with coefficients) into its nonzeros (column-major order)."""
    keys = cols_out * shape[0] + rows_out
    uniq = np.unique(keys)
    sp = ca.Sparsity.triplet(shape[0], shape[1], (uniq % shape[0]).tolist(),
                             (uniq // shape[0]).tolist())
    gather = ca.DM.triplet(np.searchsorted(uniq, keys).tolist(), source.tolist(),
                           ca.DM(coef.tolist()), uniq.size, n_in)
    return sp, gather


def _constraint_jacobian(node: ca.Function, muscle: bool, n: int, h: float, z: ca.MX,
                         p: ca.MX, constraints: ca.MX, linear_part: ca.MX,
                         rows: list[int]) -> ca.Function:
    """IPOPT's constraint Jacobian, assembled like ``_lagrangian_hessian``: the residual of
    Eq. 1 and the activation rates each involve one node; the rest of g is linear."""
    big_n, nz = n + 1, z.numel()
    nb = nz - int(sum(r * big_n for r in rows))
    ny = int(sum(rows))
    n_g = constraints.numel()
    y, x0s = ca.SX.sym('y', ny), ca.SX.sym('x0', 2)
    qk, qdk, qddk = y[0:6], y[6:12], _QDD_SCALE * y[12:18]
    if muscle:
        nm = rows[3]
        res, _, adot = node(ca.vertcat(qk, qdk), qddk, y[18:18 + nm], y[18 + nm:], x0s)
        v = ca.vertcat(res, adot)
    else:
        res, _ = node(ca.vertcat(qk, qdk), qddk, _TAU_SCALE * y[18:21], x0s)
        v = res
    jk = ca.jacobian(v, y)
    r_loc, c_loc = (np.asarray(a) for a in jk.sparsity().get_triplet())
    jk_fn = ca.Function('node_jacobian', [y, x0s], [ca.vertcat(*jk.nonzeros())],
                        {'cse': True})
    lin = ca.Function('linear_jacobian', [z], [ca.jacobian(linear_part, z)])(np.zeros(nz))
    r_l, c_l = (np.asarray(a) for a in lin.sparsity().get_triplet())
    local = _node_index(rows, n, nz, nb)
    m = r_loc.size
    res_off, rate_off = 12 * n, 12 * n + 6 * big_n + 12
    out_r, out_c, src, coef = [], [], [], []
    k = np.arange(big_n)[:, None]
    src_all = k * m + np.arange(m)[None, :]                                   # [N, m]
    cols = local[:, c_loc]
    is_res = np.broadcast_to(r_loc < 6, (big_n, m))
    out_r.append((res_off + 6 * k + r_loc[None, :])[is_res])
    out_c.append(cols[is_res])
    src.append(src_all[is_res])
    coef.append(np.ones(int(is_res.sum())))
    if muscle:
        i = r_loc - 6
        for shift, ok in ((-1, k >= 1), (0, k <= n - 1)):       # rows k - 1 and k of trapA
            sel = ~is_res & np.broadcast_to(ok, (big_n, m))
            out_r.append((rate_off + nm * (k + shift) + i[None, :])[sel])
            out_c.append(cols[sel])
            src.append(src_all[sel])
            coef.append(np.full(int(sel.sum()), -h / 2))
    n_node = m * big_n
    out_r.append(r_l)
    out_c.append(c_l)
    src.append(n_node + np.arange(r_l.size))
    coef.append(np.ones(r_l.size))
    sp, gather = _gather(*(np.concatenate(a) for a in (out_r, out_c, src, coef)),
                         (n_g, nz), n_node + r_l.size)
    xz, xp = ca.MX.sym('x', nz), ca.MX.sym('p', p.numel())
    y_all, _ = _node_variables(xz, rows, n, nb)
    nodes = jk_fn.map(big_n, 'serial')(y_all, ca.repmat(xp[-2:], 1, big_n))
    values = ca.mtimes(gather, ca.vertcat(ca.vec(nodes), ca.DM(lin.nonzeros())))
    g = ca.Function('g', [z, p], [constraints])(xz, xp)
    return ca.Function('nlp_jac_g', [xz, xp], [g, ca.MX(sp, values)], ['x', 'p'],
                       ['g', 'jac_g_x'])


def _lagrangian_hessian(node: ca.Function, muscle: bool, n: int, h: float, z: ca.MX,
                        p: ca.MX, cost_quad: ca.MX, sig_s: np.ndarray, basis: np.ndarray,
                        rows: list[int]) -> ca.Function:
    """IPOPT's Hessian of the Lagrangian (upper triangle), assembled from one node's.

    The NLP is separable: every nonlinear term (the dynamics residual, the model's wrench in
    the fit, the activation rates of the trapezoidal rule) involves one node's variables and
    the moment-bias coefficients; the rest of the cost is quadratic (a constant Hessian). So
    the Hessian of one node's Lagrangian is built once (SX, common subexpressions removed),
    mapped over the nodes, and summed into place by a constant sparse matrix: the same
    values as differentiating the whole NLP (tested), without building it node by node
    (muscle actuation: 10 s and 1.1 GB less per trial length).

    ``rows``: the variable blocks of ``z`` before the bias coefficients, each [rows x n + 1]
    stored node by node (q, qd, qdd, then the drive: torques, or activations and excitations).
    """
    big_n = n + 1
    nb = basis.shape[1]
    ny = int(sum(rows))
    nz = z.numel()
    # One node's Lagrangian: sigma * (wrench fit) + lambda_res' residual - h/2 mu' adot.
    y = ca.SX.sym('y', ny)
    cbs = ca.SX.sym('cb', nb)
    wk = ca.SX.sym('w', 3)
    bk = ca.SX.sym('b', nb)
    x0s = ca.SX.sym('x0', 2)
    sigma = ca.SX.sym('sigma')
    lres = ca.SX.sym('lres', 6)
    qk, qdk, qddk = y[0:6], y[6:12], _QDD_SCALE * y[12:18]
    if muscle:
        nm = rows[3]
        mu = ca.SX.sym('mu', nm)
        res, s, adot = node(ca.vertcat(qk, qdk), qddk, y[18:18 + nm], y[18 + nm:], x0s)
        extra_l = -h / 2 * ca.dot(mu, adot)
        extra_in = [mu]
    else:
        res, s = node(ca.vertcat(qk, qdk), qddk, _TAU_SCALE * y[18:21], x0s)
        extra_l, extra_in = 0, []
    fit = (s + ca.vertcat(0, 0, ca.dot(bk, cbs)) - wk) / ca.DM(sig_s)
    lag = sigma * ca.sumsqr(fit) + ca.dot(lres, res) + extra_l
    hk, _ = ca.hessian(lag, ca.vertcat(y, cbs))
    r_loc, c_loc = (np.asarray(v) for v in hk.sparsity().get_triplet())
    hk_fn = ca.Function('node_hessian', [y, cbs, wk, bk, x0s, sigma, lres, *extra_in],
                        [ca.vertcat(*hk.nonzeros())], {'cse': True})
    # The constant Hessian of the quadratic part of the cost.
    zs, ps = ca.SX.sym('z', nz), ca.SX.sym('p', p.numel())
    quad = ca.Function('quad', [z, p], [cost_quad]).expand()
    hc = ca.hessian(quad(zs, ps), zs)[0]
    hc = ca.evalf(ca.substitute(hc, ca.vertcat(zs, ps), ca.DM.zeros(nz + p.numel())))
    r_c, c_c = (np.asarray(v) for v in hc.sparsity().get_triplet())
    local = _node_index(rows, n, nz, nb)
    rr = np.concatenate([local[:, r_loc].ravel(), r_c])
    cc = np.concatenate([local[:, c_loc].ravel(), c_c])
    upper = np.flatnonzero(rr <= cc)                  # IPOPT takes the upper triangle
    n_in = r_loc.size * big_n + r_c.size
    sp, gather = _gather(rr[upper], cc[upper], upper, np.ones(upper.size), (nz, nz), n_in)
    # The Hessian function of IPOPT's interface: (x, p, lam_f, lam_g) -> triu(H).
    xz, xp, lf = ca.MX.sym('x', nz), ca.MX.sym('p', p.numel()), ca.MX.sym('lam_f')
    n_g = 12 * n + 6 * big_n + 12 + (rows[3] * n if muscle else 0)
    lg = ca.MX.sym('lam_g', n_g)
    y_all, cb_all = _node_variables(xz, rows, n, nb)
    w_all = ca.reshape(xp[:3 * big_n], big_n, 3).T
    x0_all = ca.repmat(xp[-2:], 1, big_n)
    lres_all = ca.reshape(lg[12 * n:12 * n + 6 * big_n], 6, big_n)
    args = [y_all, ca.repmat(cb_all, 1, big_n), w_all, ca.DM(basis.T), x0_all,
            ca.repmat(lf, 1, big_n), lres_all]
    if muscle:
        lam_a = ca.reshape(lg[12 * n + 6 * big_n + 12:], rows[3], n)
        zero = ca.MX.zeros(rows[3], 1)
        args.append(ca.horzcat(zero, lam_a) + ca.horzcat(lam_a, zero))
    nodes = hk_fn.map(big_n, 'serial')(*args)
    values = ca.mtimes(gather, ca.vertcat(ca.vec(nodes), lf * ca.DM(hc.nonzeros())))
    return ca.Function('nlp_hess_l', [xz, xp, lf, lg], [ca.MX(sp, values)],
                       ['x', 'p', 'lam_f', 'lam_g'], ['hess_gamma_x_x'])


def fit_window(obs: Observations, t_end: float) -> Observations:
    """The observations up to ``t_end`` [s] (both streams; the whole record if shorter)."""
    w = np.asarray(obs.t_wrench) <= t_end + 1e-9
    a = np.asarray(obs.t_angles) <= t_end + 1e-9
    return replace(obs, t_wrench=obs.t_wrench[w], wrench=obs.wrench[w],
                   t_angles=obs.t_angles[a], angles=obs.angles[a])


def collocation_grid(obs: Observations) -> tuple[int, float, np.ndarray, np.ndarray]:
    """(n intervals, h [s], grid index of each angle sample, mask of those on the grid):
    one interval per force-plate sample."""
    t_w = np.asarray(obs.t_wrench, dtype=float)
    n = t_w.size - 1
    h = float(np.mean(np.diff(t_w)))
    idx = np.rint((np.asarray(obs.t_angles, dtype=float) - t_w[0]) / h).astype(int)
    return n, h, idx, (idx >= 0) & (idx <= n)


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
    if st.flight_s is not None and np.isfinite(guess.liftoff_s):
        obs = fit_window(obs, float(guess.liftoff_s) + st.flight_s)
    t_w = np.asarray(obs.t_wrench, dtype=float)
    n, h, idx, keep = collocation_grid(obs)
    if n > st.max_intervals:
        reason = (f'{n} force samples ({n * h:.2f} s) exceed max_intervals '
                  f'= {st.max_intervals}; trim the record to the movement')
        return replace(guess, status=reason, events=[{'t': 0.0, 'reason': reason}],
                       cpu_s=time.process_time() - c0)
    x0 = np.asarray(guess.x0, dtype=float)
    solver, basis = _build(model, n, h, idx[keep], st)
    kin0 = [_on_grid(guess.q, n).ravel(), _on_grid(guess.qd, n).ravel(),
            (_on_grid(guess.qdd, n) / _QDD_SCALE).ravel()]
    n_kin = 18 * (n + 1)
    lbx = np.full(n_kin, -np.inf)
    ubx = np.full(n_kin, np.inf)
    if st.actuation == 'muscle':
        nm = model.p.muscles.f0.size
        drive0 = [_on_grid(x, n).ravel() for x in _muscle_guess(model, guess)]
        lbx = np.concatenate([lbx, np.zeros(2 * nm * (n + 1))])
        ubx = np.concatenate([ubx, np.ones(2 * nm * (n + 1))])
    else:
        drive0 = [(_on_grid(guess.tau, n) / _TAU_SCALE).ravel()]
        lbx = np.concatenate([lbx, np.full(3 * (n + 1), -np.inf)])
        ubx = np.concatenate([ubx, np.full(3 * (n + 1), np.inf)])
    z0 = np.concatenate(kin0 + drive0 + [np.zeros(st.moment_bias_terms)])
    lbx = np.concatenate([lbx, np.full(st.moment_bias_terms, -np.inf)])
    ubx = np.concatenate([ubx, np.full(st.moment_bias_terms, np.inf)])
    p = np.concatenate([obs.wrench[:n + 1].ravel(order='F'),
                        obs.angles[keep].ravel(order='F'), x0])
    sol = solver(x0=z0, p=p, lbg=0.0, ubg=0.0, lbx=lbx, ubx=ubx)
    stats = solver.stats()
    zz = np.asarray(sol['x']).ravel()
    Q, QD, QDD = (b.reshape(n + 1, -1) for b in np.split(zz[:n_kin], 3))
    QDD = QDD * _QDD_SCALE
    drive = zz[n_kin:-st.moment_bias_terms]
    muscles = None
    if st.actuation == 'muscle':
        A, U = (b.reshape(n + 1, -1) for b in np.split(drive, 2))
        TAU, F = model.batch(model.muscle_torques, Q, QD, A)
        muscles = {'a': A, 'u': U, 'f': F}
    else:
        TAU = drive.reshape(n + 1, -1) * _TAU_SCALE
    s, = model.batch(model.contact_outputs, Q, QD, x0)
    ok = bool(stats['success'])
    res = SKTResult(t=t_w - t_w[0], q=Q, qd=QD, qdd=QDD, tau=TAU, s=s,
                    bias=basis @ zz[-st.moment_bias_terms:], residual=np.zeros((n + 1, 7)), x0=x0,
                    status='ok' if ok else 'solver: ' + str(stats['return_status']),
                    events=[] if ok else [{'t': 0.0, 'reason': str(stats['return_status'])}],
                    cpu_s=time.process_time() - c0, muscles=muscles)
    res.liftoff_s = liftoff_time(res.t, s[:, 1], st.liftoff_force_bw * bw)
    return res


def _muscle_guess(model: JumperModel, guess: SKTResult) -> tuple[np.ndarray, np.ndarray]:
    """Activations and excitations [n, 9] that make the guess's torques: Stage 2 on them
    (up to the guess's lift-off + 10 ms), from the activations that hold its first posture."""
    from nmt_ros.tracking.neuromuscular_tracker import NeuromuscularTracker

    t_stop = guess.liftoff_s if np.isfinite(guess.liftoff_s) else guess.t[-1]
    stage2 = NeuromuscularTracker(model).track_motion(guess.t, guess.q, guess.qd, guess.qdd,
                                                      guess.tau, guess.x0, t_stop + 0.01)
    return stage2.a, stage2.u


def _on_grid(values: np.ndarray, n: int) -> np.ndarray:
    """The guess's first n + 1 samples [n + 1, k], the last one held if it is shorter.

    Raveled row by row this is CasADi's column-major ``vec`` of the [k, n + 1] variables.
    """
    out = np.empty((n + 1, values.shape[1]))
    k = min(values.shape[0], n + 1)
    out[:k] = values[:k]
    out[k:] = values[k - 1]
    return out
