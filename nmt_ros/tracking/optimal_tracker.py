"""Stage 1 by optimal tracking (beyond the paper): joint torques that make the model fit all the
observations at once, over the whole trial.

The paper's skeletal motion tracker (``skeletal_tracker``) balances its seven outputs
instant by instant. Here the same model, driven by the same three joint torques, is fitted to
the raw observations over the whole recording by direct collocation (the machinery of the
reference jump's optimisation, OpenSim Moco's "tracking" problem):

    minimise  sum_k |(theta(t_k) - theta_obs,k) / sigma_theta|^2             (120 Hz samples)
            + sum_j |(s(t_j) + [0, 0, b(t_j)] - s_obs,j) / sigma_s|^2       (1080 Hz samples)
            + w_rate N sum_i |(tau_i+1 - tau_i) / 100 N m|^2 / h              (torque smoothness)
    subject to Eq. 1 (implicit, trapezoidal, one interval per force sample), and at t = 0
    the initial guess's rates and accelerations (rest after a static start; a trial that
    starts in flight starts moving),

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
the NLP (the transcription of ``collocation``: its Lagrangian Hessian and constraint Jacobian
are assembled from one node's); 0.2 GB of memory (bench/bench_stage1.py).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import time

import casadi as ca
import numpy as np

from nmt_ros.model.contact import liftoff_time
from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Observations, SKTResult
from nmt_ros.tracking.collocation import (
    QDD_SCALE,
    TAU_SCALE,
    Block,
    Defect,
    Fixed,
    LeastSquares,
    Path,
    Transcription,
    dynamics_residual,
    solvers,
)
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE


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
    # typical: 30-60 iterations (tested over 30 noise realisations). From a tracker that lost
    # control it can take many more: the reference jump at 3x the paper's noise (seed 9,
    # test_optimal_tracker) exceeded 500 on one machine (rounding) and converged within
    # 2000 in 51 s to 1.0 / 4.3 / 2.7 % of peak, as it had within 500 on another
    max_iter: int = 2000


@dataclass(frozen=True)
class TrackingNLP:
    """The transcription of one trial shape, its IPOPT solver and the moment-bias basis."""

    transcription: Transcription
    solver: ca.Function
    basis: np.ndarray        # [n + 1, moment_bias_terms]: b(t_k) = basis[k] @ c


def tracking_nlp(model: JumperModel, n: int, h: float, idx: np.ndarray,
                 st: OptimalTrackingSettings, at_rest: bool = True) -> TrackingNLP:
    """The NLP for n intervals of h seconds and angle samples at grid indices ``idx``.

    Observations and contact anchors are parameters, so trials of the same shape share it
    (``collocation.solvers``, a bounded cache). ``at_rest``: rates and accelerations are
    zero at t = 0 (constraints); otherwise the caller bounds them (``track_optimal``).
    """
    key = ('optimal_tracking', n, round(h, 12), idx.tobytes(), st, at_rest)
    return solvers.get(model, key, lambda: _build(model, n, h, idx, st, at_rest))


def _build(model: JumperModel, n: int, h: float, idx: np.ndarray,
           st: OptimalTrackingSettings, at_rest: bool = True) -> TrackingNLP:
    bw = model.p.body_weight
    muscle = st.actuation == 'muscle'
    nm = model.p.muscles.f0.size
    nb = st.moment_bias_terms
    t_grid = np.arange(n + 1) * h
    basis = np.column_stack([(t_grid / t_grid[-1]) ** (k + 1) for k in range(nb)])
    sig_s = np.array([st.force_sd_bw * bw] * 2 + [st.force_sd_bw * bw * st.moment_lever_m])
    sig_a = np.radians(st.angle_sd_deg) * st.angle_bias_allowance

    def node(v: dict[str, ca.SX]) -> dict[str, ca.SX]:
        q, qd = v['q'], v['qd']
        tau = model.muscle_torques(q, qd, v['a'])[0] if muscle else v['tau']
        out = {'residual': dynamics_residual(model, q, qd, v['qdd'], tau, v['x0']),
               's': model.contact_outputs(q, qd, v['x0'])}
        if muscle:
            out['adot'] = model.activation_dynamics(v['u'], v['a'])
        return out

    def wrench_fit(v: dict[str, ca.SX | ca.MX]) -> ca.SX | ca.MX:
        """(s + [0, 0, b(t)] - s_obs) / sigma_s, one column per node."""
        bias = ca.mtimes(v['basis'].T, v['c_bias']).T          # the moment bias b(t) [N m]
        cols = bias.size2()
        return ((v['s'] + ca.vertcat(ca.DM.zeros(2, cols), bias) - v['wrench'])
                / ca.repmat(ca.DM(sig_s), 1, cols))

    def quadratic(var: dict[str, ca.MX], par: dict[str, ca.MX]) -> ca.MX:
        n_a = idx.size
        cost = ca.sumsqr((var['q'][0:4, list(idx)].T - par['angles'])
                         / ca.repmat(ca.DM(sig_a).T, n_a, 1))
        if muscle:
            t_total = n * h
            exc = var['u']
            cost += st.excitation_weight * h / t_total * ca.sumsqr(exc)
            cost += (st.excitation_rate_weight / (h * t_total)
                     * ca.sumsqr(exc[:, 1:] - exc[:, :-1]))
        else:
            tau_v = var['tau']
            cost += st.torque_rate_weight * n * ca.sumsqr(tau_v[:, 1:] - tau_v[:, :-1]) / h
        return cost

    drive = ([Block('a', nm), Block('u', nm)] if muscle
             else [Block('tau', 3, scale=TAU_SCALE)])
    tr = Transcription(
        n, h, [Block('q', 6), Block('qd', 6), Block('qdd', 6, scale=QDD_SCALE), *drive],
        node,
        [Defect('q', 'qd'), Defect('qd', 'qdd'), Path('residual'),        # Eq. 1, trapezoidal
         *([Fixed('qd', 0), Fixed('qdd', 0)] if at_rest else []),          # at rest at t = 0
         *([Defect('a', 'adot')] if muscle else [])],
        costs=[LeastSquares(wrench_fit)], global_blocks=[Block('c_bias', nb)],
        node_parameters=[Block('wrench', 3)],
        global_parameters=[Block('angles', idx.size, 4), Block('x0', 2)],
        node_constants={'basis': basis}, quadratic_cost=quadratic)
    solver = tr.solver('stage1_tracking', {
        'expand': False, 'print_time': False, 'show_eval_warnings': False,
        'ipopt': {'print_level': 0, 'tol': st.tol, 'max_iter': st.max_iter,
                  'linear_solver': 'mumps', 'sb': 'yes',
                  'mu_init': st.mu_init if st.mu_init is not None
                  else (1e-3 if muscle else 0.1)}})
    return TrackingNLP(tr, solver, basis)


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
    at_rest = not np.any(guess.qd[0])        # a static start (else: moving at t = 0)
    nlp = tracking_nlp(model, n, h, idx[keep], st, at_rest)
    tr = nlp.transcription
    guess_values = {'q': _on_grid(guess.q, n), 'qd': _on_grid(guess.qd, n),
                    'qdd': _on_grid(guess.qdd, n)}
    if st.actuation == 'muscle':
        a_guess, u_guess = _muscle_guess(model, guess)
        guess_values.update(a=_on_grid(a_guess, n), u=_on_grid(u_guess, n))
        lbx, ubx = tr.bounds({'a': 0.0, 'u': 0.0}, {'a': 1.0, 'u': 1.0})
    else:
        guess_values['tau'] = _on_grid(guess.tau, n)
        lbx, ubx = tr.bounds()
    if not at_rest:      # the guess's rates and accelerations at t = 0, held by the bounds
        for name, value, scale in (('qd', guess.qd[0], 1.0), ('qdd', guess.qdd[0], QDD_SCALE)):
            i = tr.index(name)[0]
            lbx[i] = ubx[i] = np.asarray(value, dtype=float) / scale
    p = tr.pack_parameters({'wrench': obs.wrench[:n + 1], 'angles': obs.angles[keep],
                            'x0': x0})
    sol = tr.solve(nlp.solver, tr.pack(guess_values), p, lbx, ubx)
    vals = tr.unpack(sol.z)
    Q, QD, QDD = vals['q'], vals['qd'], vals['qdd']
    muscles = None
    if st.actuation == 'muscle':
        A, U = vals['a'], vals['u']
        TAU, F = model.batch(model.muscle_torques, Q, QD, A)
        muscles = {'a': A, 'u': U, 'f': F}
    else:
        TAU = vals['tau']
    s, = model.batch(model.contact_outputs, Q, QD, x0)
    ok = sol.success
    res = SKTResult(t=t_w - t_w[0], q=Q, qd=QD, qdd=QDD, tau=TAU, s=s,
                    bias=nlp.basis @ vals['c_bias'].ravel(), residual=np.zeros((n + 1, 7)),
                    x0=x0, status='ok' if ok else 'solver: ' + sol.status,
                    events=[] if ok else [{'t': 0.0, 'reason': sol.status}],
                    cpu_s=time.process_time() - c0, muscles=muscles)
    res.liftoff_s = liftoff_time(res.t, s[:, 1], st.liftoff_force_bw * bw)
    return res


def _muscle_guess(model: JumperModel, guess: SKTResult) -> tuple[np.ndarray, np.ndarray]:
    """Activations and excitations [n, 9] that make the guess's torques: Stage 2 on them
    (up to the guess's lift-off + 10 ms), from the activations that hold its first posture."""
    from nmt_ros.tracking.stage2 import NeuromuscularTracker

    t_stop = guess.liftoff_s if np.isfinite(guess.liftoff_s) else guess.t[-1]
    stage2 = NeuromuscularTracker(model).track_motion(guess.t, guess.q, guess.qd, guess.qdd,
                                                      guess.tau, guess.x0, t_stop + 0.01)
    return stage2.a, stage2.u


def _on_grid(values: np.ndarray, n: int) -> np.ndarray:
    """The guess's first n + 1 samples [n + 1, k], the last one held if it is shorter."""
    out = np.empty((n + 1, values.shape[1]))
    k = min(values.shape[0], n + 1)
    out[:k] = values[:k]
    out[k:] = values[k - 1]
    return out
