"""Stage 1 by optimal tracking with muscle-made joint torques (beyond the paper).

Checked against independent truth: the synthetic ground truth (torques, jump), a forward
simulation of the estimate's own excitations (physics, not the collocation), and Stage 2's
ability to reproduce the torques within the muscles' capacity.
"""
import dataclasses

import numpy as np
import pytest

from nmt_ros.model.simulation import held, simulate_excitations
from nmt_ros.study.metrics import jump_from
from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.tracking.conditioning import condition
from nmt_ros.tracking.optimal_tracker import OptimalTrackingSettings, track_optimal
from nmt_ros.tracking.streaming import track_stage1

MUSCLE = OptimalTrackingSettings(actuation='muscle')


def contact_pct(t, est, truth, ref):
    """RMS over the contact phase, % of each column's peak in the truth."""
    m = t <= truth.liftoff_s
    idx = np.rint(t[m] * 1080).astype(int)
    peak = np.abs(ref[truth.t <= truth.liftoff_s]).max(axis=0)
    return 100 * np.sqrt(np.mean((est[m] - ref[idx]) ** 2, axis=0)) / peak


def stage1(model, obs):
    skt = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    assert skt.ok
    return track_optimal(model, obs, skt, MUSCLE)


@pytest.fixture(scope='module')
def shipped(model, obs):
    return stage1(model, obs)


def actual_jump(model, truth):
    return jump_from(model, truth.t, truth.q, truth.qd, truth.liftoff_s)['jump_height_m']


def test_recovers_the_truth_from_clean_observations(model, truth, obs):
    """Noise- and bias-free samples of the actual jump: torques within 0.5 % of peak, angles
    within 0.1 deg at every sample and the jump within 0.3 %. What remains is the
    excitation-rate prior's smoothing of the optimised (near bang-bang) excitations: torques
    0.07 / 0.35 / 0.36 %, angles 0.08 deg at worst, jump -0.21 % measured at the default weight
    (0.02 / 0.07 / 0.06 %, under 0.05 deg, -0.08 % at a 100x smaller one, which tracks noisy data
    20-40 % worse)."""
    clean = dataclasses.replace(
        obs, angles=truth.q[np.rint(obs.t_angles * 1080).astype(int), :4],
        wrench=truth.s[np.rint(obs.t_wrench * 1080).astype(int)])
    res = stage1(model, clean)
    assert res.ok, res.status
    assert (contact_pct(res.t, res.tau, truth, truth.tau) < 0.5).all()
    m = res.t <= truth.liftoff_s
    idx = np.rint(res.t[m] * 1080).astype(int)
    assert np.degrees(np.abs(res.q[m, :4] - truth.q[idx, :4])).max() < 0.1
    jump = jump_from(model, res.t, res.q, res.qd, res.liftoff_s)['jump_height_m']
    assert abs(jump / actual_jump(model, truth) - 1) < 0.003


def test_shipped_trial_torques_and_forces(model, truth, shipped):
    """Noisy, biased shipped trial: torques within 3 % of peak on every joint (the paper's
    tracker: 4 / 12 / 22 %), ground forces within 2 % of body weight, moment bias removed."""
    assert shipped.ok, shipped.status
    assert (contact_pct(shipped.t, shipped.tau, truth, truth.tau) < 3.0).all()
    s_pct = contact_pct(shipped.t, shipped.s, truth, truth.s)
    bw = model.p.body_weight
    peak_s = np.abs(truth.s[truth.t <= truth.liftoff_s]).max(axis=0)
    assert (s_pct[:2] * peak_s[:2] / 100 < 0.021 * bw).all()
    assert abs(shipped.liftoff_s - truth.liftoff_s) < 0.002


def test_excitations_are_bounded_and_reproduce_the_motion(model, truth, shipped):
    """The estimate is a motion the muscles make: excitations and activations in [0, 1], and
    a forward simulation of its excitations (RK4, independent of the collocation) follows it
    open loop through the whole push-off: angles within 0.5 deg (the trapezoidal rule's error
    at 1080 Hz, grown by the unstable open loop: 0.37 deg measured), lift-off within 2 ms (two
    sample periods: the simulation's zero-force instant against the estimate's 2 % BW one),
    jump within 0.3 %."""
    mus = shipped.muscles
    for key in ('a', 'u'):
        assert mus[key].min() >= -1e-9 and mus[key].max() <= 1 + 1e-9
    x_init = np.concatenate([shipped.q[0], shipped.qd[0], mus['a'][0]])
    sim = simulate_excitations(model, x_init, shipped.x0, held(shipped.t, mus['u']),
                               shipped.liftoff_s + 0.01, method='rk4', rate_hz=1080.0)
    k = np.searchsorted(shipped.t, sim.t[sim.t <= shipped.liftoff_s] - 1e-9)
    assert np.degrees(np.abs(sim.x[:k.size, :4] - shipped.q[k, :4])).max() < 0.5
    assert abs(sim.liftoff_s - shipped.liftoff_s) < 0.002
    j_sim = jump_from(model, sim.t, sim.x[:, :6], sim.x[:, 6:12], sim.liftoff_s)
    j_est = jump_from(model, shipped.t, shipped.q, shipped.qd, shipped.liftoff_s)
    assert abs(j_sim['jump_height_m'] / j_est['jump_height_m'] - 1) < 0.003


def test_stage2_tracks_the_muscle_made_torques(model, truth, shipped):
    """Torques the muscles can make are ones Stage 2 can track: under 3 % of each joint's peak
    (issue 5's target; on free-torque Stage-1 estimates the ankle misses it)."""
    from nmt_ros.tracking.stage2 import NeuromuscularTracker

    s2 = NeuromuscularTracker(model).track_motion(shipped.t, shipped.q, shipped.qd,
                                                  shipped.qdd, shipped.tau, shipped.x0,
                                                  shipped.liftoff_s + 0.01)
    assert (100 * s2.rms_error_relative < 3.0).all(), s2.rms_error_relative


def test_other_noise_realisation(model, truth):
    """A noise seed the defaults were not tuned on: torques within 5 % of peak."""
    obs, _ = make_observations(truth, ObservationSettings(seed=17),
                               body_weight=model.p.body_weight)
    res = stage1(model, obs)
    assert res.ok, res.status
    assert (contact_pct(res.t, res.tau, truth, truth.tau) < 5.0).all()


def test_harsher_bias_still_beats_the_papers_tracker(model, truth):
    """Three-harmonic biases (harsher than the paper's one-lobe): on this seed the paper's
    tracker is off by 6 / 19 / 13 % of peak; the muscle-made estimate is better on every
    joint (measured 1.6 / 6.7 / 5.2 %)."""
    obs, _ = make_observations(truth, ObservationSettings(seed=17, bias_shape='harmonic'),
                               body_weight=model.p.body_weight)
    skt = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    res = track_optimal(model, obs, skt, MUSCLE)
    assert res.ok, res.status
    e_opt = contact_pct(res.t, res.tau, truth, truth.tau)
    e_skt = contact_pct(skt.t, skt.tau, truth, truth.tau)
    assert (e_opt < e_skt).all(), (e_opt, e_skt)


def test_runs_after_the_skeletal_tracker_loses_control(model, truth):
    """Three times the paper's noise (seed 9): the paper's tracker diverges near lift-off;
    optimal tracking from its partial result still estimates the torques (within 6 % of peak,
    measured 1.0 / 4.3 / 2.7 %), the NMT runs, and the tracker's loss is reported."""
    from nmt_ros.study.pipeline import NMTSettings, run_nmt

    obs, _ = make_observations(truth, ObservationSettings(seed=9, noise_scale=3.0),
                               body_weight=model.p.body_weight)
    run = run_nmt(model, obs, NMTSettings(stage1='optimal_muscle'))
    assert run.ok and run.skt.muscles is not None
    assert any('skeletal tracker' in e['reason'] for e in run.skt.events)
    assert (contact_pct(run.skt.t, run.skt.tau, truth, truth.tau) < 6.0).all()


def test_failed_optimal_tracking_falls_back_to_the_tracker(model, obs, monkeypatch):
    """If the optimisation fails, Stage 1 is the tracker's result and the failure is
    reported (not a crash, not a silent substitution)."""
    from nmt_ros.study.pipeline import NMTSettings, run_nmt
    from nmt_ros.tracking import optimal_tracker

    def failing(model, obs, guess, settings):
        return dataclasses.replace(guess, status='solver: Maximum_Iterations_Exceeded')

    monkeypatch.setattr(optimal_tracker, 'track_optimal', failing)
    run = run_nmt(model, obs, NMTSettings(stage1='optimal_muscle'))
    assert run.ok and run.skt.muscles is None
    assert any('optimal tracking: solver' in e['reason'] for e in run.skt.events)

    def raising(model, obs, guess, settings):
        raise RuntimeError('Error in Function::call for solver')

    monkeypatch.setattr(optimal_tracker, 'track_optimal', raising)
    run = run_nmt(model, obs, NMTSettings(stage1='optimal_muscle'))
    assert run.ok and run.skt.muscles is None
    assert any('optimal tracking: error: RuntimeError' in e['reason'] for e in run.skt.events)


def test_a_record_too_long_is_refused_with_a_reason(model, obs):
    """The NLP grows with the record: beyond ``max_intervals`` it is not built, and the
    status says why (the fit window ends ``flight_s`` after the guess's lift-off)."""
    skt = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    res = track_optimal(model, obs, skt, OptimalTrackingSettings(actuation='muscle',
                                                                 max_intervals=100))
    assert not res.ok and 'exceed max_intervals = 100' in res.status
    assert res.events and res.events[0]['reason'] == res.status


@pytest.mark.parametrize('actuation', ['muscle', 'torque'])
def test_assembled_hessian_equals_the_nlps_own(model, actuation):
    """The Lagrangian Hessian assembled from one node's (what IPOPT gets) equals CasADi's
    differentiation of the whole NLP, at a random point with random multipliers."""
    import casadi as ca

    from nmt_ros.tracking.optimal_tracker import tracking_nlp

    n = 12
    idx = np.array([0, 4, 8, 12])
    solver = tracking_nlp(model, n, 1 / 1080, idx,
                          OptimalTrackingSettings(actuation=actuation)).solver
    nlp = solver.oracle()
    x, p = ca.MX.sym('x', nlp.size1_in(0)), ca.MX.sym('p', nlp.size1_in(1))
    lam_f, lam_g = ca.MX.sym('lam_f'), ca.MX.sym('lam_g', nlp.size1_out(1))
    f, g = nlp(x, p)
    reference = ca.Function('h', [x, p, lam_f, lam_g],
                            [ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])])
    rng = np.random.default_rng(4)
    xv = 0.1 * rng.normal(size=x.numel())
    xv[:6 * (n + 1)] += np.tile([0.0, -0.4, 0.8, -0.6, 0.0, 0.0], n + 1)   # a squat
    pv = rng.normal(size=p.numel())
    pv[-2:] = [-0.03, 0.14]
    args = [xv, pv, 0.7, rng.normal(size=lam_g.numel())]
    ours = solver.get_function('nlp_hess_l')(*args)
    ref = reference(*args)
    scale = float(np.abs(np.asarray(ref)).max())
    assert float(np.abs(np.asarray(ours - ref)).max()) < 1e-10 * scale


@pytest.mark.parametrize('actuation', ['muscle', 'torque'])
def test_assembled_jacobian_equals_the_nlps_own(model, actuation):
    """The constraint Jacobian assembled from one node's (what IPOPT gets) equals CasADi's
    differentiation of the whole NLP, and so do the constraint values, at a random point."""
    import casadi as ca

    from nmt_ros.tracking.optimal_tracker import tracking_nlp

    n = 12
    solver = tracking_nlp(model, n, 1 / 1080, np.array([0, 4, 8, 12]),
                          OptimalTrackingSettings(actuation=actuation)).solver
    nlp = solver.oracle()
    x, p = ca.MX.sym('x', nlp.size1_in(0)), ca.MX.sym('p', nlp.size1_in(1))
    _, g = nlp(x, p)
    reference = ca.Function('j', [x, p], [g, ca.jacobian(g, x)])
    rng = np.random.default_rng(5)
    xv = 0.1 * rng.normal(size=x.numel())
    xv[:6 * (n + 1)] += np.tile([0.0, -0.4, 0.8, -0.6, 0.0, 0.0], n + 1)
    pv = rng.normal(size=p.numel())
    pv[-2:] = [-0.03, 0.14]
    g_ours, j_ours = solver.get_function('nlp_jac_g')(xv, pv)
    g_ref, j_ref = reference(xv, pv)
    assert float(np.abs(np.asarray(g_ours - g_ref)).max()) == 0.0
    scale = float(np.abs(np.asarray(j_ref)).max())
    assert float(np.abs(np.asarray(j_ours - j_ref)).max()) < 1e-12 * scale
