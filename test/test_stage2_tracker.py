"""Stage 2 (neuromuscular tracker) on references whose truth is known."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
import stage2_oracles as oracles

from nmt_ros.model.jumper import default_model
from nmt_ros.model.squat import rest_activations
from nmt_ros.tracking.stage2 import NeuromuscularTracker, Stage2Result, load_stage2_settings
from nmt_ros.tracking.stage2.activation import ActivationLaw, eq9_excitation
from nmt_ros.tracking.stage2.references import refine_samples

JUMP_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'


@pytest.fixture(scope='module')
def tracker() -> NeuromuscularTracker:
    return NeuromuscularTracker()


@pytest.fixture(scope='module')
def clip_tracker(tracker) -> NeuromuscularTracker:
    """The paper's Stage 2: unconstrained LQT, excitations clipped to [0, 1], Eq. 11 without
    the force term."""
    return NeuromuscularTracker(tracker.model, load_stage2_settings(saturation='clip', k_f=0.0))


@pytest.fixture(scope='module')
def synth() -> oracles.SyntheticReference:
    return oracles.synthetic_reference(dt=1e-3)


@pytest.fixture(scope='module')
def full(tracker, synth) -> Stage2Result:
    s = synth
    return tracker.track(s.t, s.tau_ref, s.theta, s.theta_dot, s.theta_ddot, s.a_true[0])


def _inputs(s: oracles.SyntheticReference) -> tuple[np.ndarray, ...]:
    return s.t, s.tau_ref, s.theta, s.theta_dot, s.theta_ddot


# ---------------------------------------------------------------------------- settings, pieces
def test_settings_weights_mapped_by_name(tracker):
    st = load_stage2_settings()
    # the paper's kQ and P; kR 100, not the paper's 1000 (stage2.yaml: a project choice)
    assert (st.k_q, st.k_r, st.k_p) == (1500.0, 100.0, 0.0)
    assert st.saturation == 'plan' and tracker.constrained
    with pytest.raises(ValueError):
        load_stage2_settings(saturation='ignore')
    assert 'Appendix B' in st.source
    names = tracker.names
    assert names == ('gmax', 'ilpso', 'hams', 'bfsh', 'rf', 'vas', 'gas', 'sol', 'ta')
    f0 = default_model().p.muscles.f0
    # the paper's list order: gmax, ilpso, hams, rf, vas, bfsh, gas, sol, ta
    paper = dict(zip(('gmax', 'ilpso', 'hams', 'rf', 'vas', 'bfsh', 'gas', 'sol', 'ta'),
                     (1, 1, 0.1, 0.3, 1, 1, 0.75, 1, 1)))
    expected = np.array([100.0 * paper[n] / f0[i] ** 2 for i, n in enumerate(names)])
    np.testing.assert_allclose(tracker.R, expected, rtol=1e-15)
    np.testing.assert_array_equal(tracker.Q, 1500.0 * np.eye(3))
    np.testing.assert_array_equal(tracker.P, np.zeros((3, 3)))
    assert load_stage2_settings(k_q=10.0).k_q == 10.0


def test_activation_step_is_the_models_ode():
    model = default_model()
    law = ActivationLaw.from_model(model)
    a0 = np.linspace(0.01, 0.99, 9)
    u = np.linspace(1.0, 0.0, 9)
    h = 0.02
    sol = solve_ivp(lambda _t, a: model.call(model.activation_dynamics, u, a)[0], (0, h), a0,
                    rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(law.step(a0, u, h)[0], sol.y[:, -1], rtol=1e-9, atol=1e-12)
    target = law.step(a0, 0.3 + 0.4 * u, h)[0]
    u_back, a1, sat = law.solve_step(a0, target, h)
    np.testing.assert_allclose(u_back, 0.3 + 0.4 * u, atol=1e-10)
    assert not sat.any()


def test_refinement_is_exact_for_quintics():
    t = np.linspace(0, 0.1, 6)
    c = np.array([[0.3, -1.0, 0.5], [2.0, 1.0, -3.0], [-5.0, 4.0, 1.0],
                  [30.0, -10.0, 5.0], [-100.0, 50.0, 20.0], [400.0, -300.0, 100.0]])

    def poly(x, d):
        out = np.zeros((x.size, 3))
        for k in range(d, 6):
            fac = np.prod(np.arange(k - d + 1, k + 1)) if d else 1.0
            out += fac * x[:, None] ** (k - d) * c[k]
        return out

    tau = np.stack([t, 2 * t, -t], axis=1)
    tf, tau_f, th, thd, thdd = refine_samples(t, tau, poly(t, 0), poly(t, 1), poly(t, 2), 4)
    assert tf.size == 21
    np.testing.assert_allclose(tf, np.linspace(0, 0.1, 21), atol=1e-15)
    np.testing.assert_allclose(th, poly(tf, 0), atol=1e-12)
    np.testing.assert_allclose(thd, poly(tf, 1), atol=1e-10)
    np.testing.assert_allclose(thdd, poly(tf, 2), atol=1e-8)
    np.testing.assert_allclose(tau_f, np.stack([tf, 2 * tf, -tf], axis=1), atol=1e-15)


def test_eq9_excitation_realises_the_requested_force_rate(tracker):
    """Eq. 9's u, put through the model's activation ODE, gives dF/dt = eta."""
    model = tracker.model
    rng = np.random.default_rng(1)
    theta0 = np.radians([10.0, -40.0, 50.0])
    thd, thdd = np.array([-3.0, 5.0, -4.0]), np.array([20.0, -30.0, 10.0])
    a0 = rng.uniform(0.2, 0.8, 9)
    eta = rng.uniform(-2000, 2000, 9)
    ref = tracker.reference(np.array([0.0]), np.zeros((1, 3)), theta0[None], thd[None],
                            thdd[None], substeps=1)
    drift, gain = tracker.activation.affine(a0)
    dfdl = ref.dfdl_0[0] + a0 * (ref.dfdl_1[0] - ref.dfdl_0[0])
    dfdv = ref.dfdv_0[0] + a0 * (ref.dfdv_1[0] - ref.dfdv_0[0])
    u = eq9_excitation(eta, ref.phi[0], dfdl, dfdv, drift, gain, ref.v_mt[0], ref.vdot_mt[0])

    def force(dt: float) -> np.ndarray:
        th = theta0 + thd * dt + 0.5 * thdd * dt ** 2
        a = a0 + dt * model.call(model.activation_dynamics, u, a0)[0]
        l_mt = model.call(model.musculotendon_lengths, th)[0]
        v_mt = model.call(model.musculotendon_velocities, th, thd + thdd * dt)[0]
        return model.call(model.muscle_force, a, l_mt, v_mt)[0]

    dt = 1e-6
    fdot = (force(dt) - force(-dt)) / (2 * dt)
    np.testing.assert_allclose(fdot, eta, rtol=1e-5, atol=1e-3)


# ---------------------------------------------------------------------------- full horizon
def test_full_horizon_tracks_the_torques(full, synth):
    assert full.f.shape == (synth.t.size, 9) and full.tau_muscle.shape == (synth.t.size, 3)
    assert np.all(full.rms_error_relative < 0.03), full.rms_error_relative
    assert np.all((full.u >= 0) & (full.u <= 1)) and np.all((full.a >= 0) & (full.a <= 1))
    np.testing.assert_allclose(full.tau_muscle, np.einsum('npm,nm->np',
                                                          _c_matrix(synth), full.f))
    assert set(full.cpu_s) == {'prepare', 'plan', 'riccati', 'forward'}


def _c_matrix(s: oracles.SyntheticReference) -> np.ndarray:
    model = default_model()
    C, = model.batch(model.moment_arm_matrix, s.theta)
    return C.reshape(-1, 3, 9)


def test_w_symmetric_positive_semidefinite(full, clip_tracker, synth):
    paper = clip_tracker.track(*_inputs(synth), synth.a_true[0])
    for W in (full.W, paper.W):
        assert np.max(np.abs(W - np.swapaxes(W, 1, 2))) <= 1e-12 * np.abs(W).max()
        eig = np.linalg.eigvalsh(W)
        assert eig.min() >= -1e-9 * eig.max()


def test_coarse_input_grid_is_refined_and_agrees(tracker, full):
    """120 Hz input: substeps keep the result close to the 1 kHz one."""
    s = oracles.synthetic_reference(dt=1 / 120)
    res = tracker.track(*_inputs(s), s.a_true[0])
    assert res.substeps == 9 and res.t.size == s.t.size
    assert np.all(res.rms_error_relative < 0.03)
    f_fine = np.array([np.interp(res.t, full.t, full.f[:, j]) for j in range(9)]).T
    rms = np.sqrt(np.mean((res.f - f_fine) ** 2, axis=0)) / tracker.f0
    assert rms.max() < 0.02, rms


# ---------------------------------------------------------------------------- windows
def test_windowed_matches_full_horizon(tracker, synth, full):
    res = tracker.track(*_inputs(synth), synth.a_true[0], mode='windowed', window_length=0.1)
    rms = np.sqrt(np.mean((res.f - full.f) ** 2, axis=0)) / tracker.f0
    assert rms.max() < 0.02, rms
    assert np.all(res.rms_error_relative < 0.03)
    assert res.latency_s == pytest.approx(0.1 + 1e-3)
    eig = np.linalg.eigvalsh(res.W)
    assert eig.min() >= -1e-9 * eig.max()


@pytest.mark.parametrize('dt', [1e-3, 1 / 120])
@pytest.mark.parametrize('saturation', ['plan', 'clip'])
def test_streaming_equals_batch_windowed(tracker, clip_tracker, dt, saturation):
    """``push`` fed uneven chunks of samples == the batch windowed mode (also with substeps)."""
    tracker = tracker if saturation == 'plan' else clip_tracker
    synth = oracles.synthetic_reference(dt=dt)
    kw = dict(window_length=0.03, window_stride=0.002)
    batch = tracker.track(*_inputs(synth), synth.a_true[0], mode='windowed', **kw)
    stream = tracker.start_stream(synth.a_true[0], dt=dt)
    steps = []
    n = synth.t.size
    for lo in range(0, n, 7):
        hi = min(n, lo + 7)
        stream, new = tracker.push(stream, *(x[lo:hi] for x in _inputs(synth)),
                                   final=hi == n, **kw)
        steps += new
        # nothing is output before its window's reference has arrived (window k covers
        # [t_k, t_k + stride) and needs samples up to t_k + H)
        if new and hi < n:
            h = dt / batch.substeps
            assert new[-1].t[-1] <= (synth.t[hi - 1] - batch.window_length
                                     + batch.window_stride - h + 1e-9)
    f = np.vstack([np.concatenate([s.f for s in steps]), stream.muscle.f])
    u = np.concatenate([s.u for s in steps])
    sub = batch.substeps
    assert stream.reference.n <= 0.035 / (dt / sub) + 2          # a window's worth is kept
    np.testing.assert_allclose(f[::sub], batch.f, rtol=0, atol=1e-9 * tracker.f0.max())
    np.testing.assert_allclose(u[::sub], batch.u[:-1], atol=1e-12)


# ---------------------------------------------------------------------------- saturation
def _collapse(synth: oracles.SyntheticReference) -> np.ndarray:
    """The extensor torques collapse in 3 ms: faster than deactivation allows (tau 60 ms)."""
    drop = np.clip((synth.t - 0.12) / 0.003, 0.0, 1.0)
    return synth.tau_ref * (1 - 0.9 * drop)[:, None]


def test_saturation_is_reported_paper_mode(clip_tracker, synth):
    """'clip' (the paper): the LQT does not know the bounds; Eq. 9 is clipped and reported."""
    s = synth
    base = clip_tracker.track(*_inputs(s), s.a_true[0]).saturation
    tau = _collapse(synth)
    res = clip_tracker.track(s.t, tau, s.theta, s.theta_dot, s.theta_ddot, s.a_true[0])
    rep = res.saturation
    assert rep.any and res.saturation_mode == 'clip' and not rep.fraction_planned.any()
    ext = [clip_tracker.names.index(n) for n in ('gmax', 'vas', 'sol')]
    assert np.all(rep.fraction_low[ext] > base.fraction_low[ext])
    assert rep.shortfall_integral.sum() > 3 * base.shortfall_integral.sum()
    after = (synth.t > 0.121) & (synth.t < 0.13)
    assert np.all(res.u[after][:, ext] == 0.0)               # saturated, never below 0
    assert np.all(res.u_demand[after][:, ext].min(axis=0) < 0)   # Eq. 9 asked for u < 0
    # the feedback acts on the actual forces: tracking recovers once the muscles caught up
    late = synth.t > 0.2
    err = np.abs(res.tracking_error[late]).max(axis=0) / np.abs(tau).max(axis=0)
    assert np.all(err < 0.1), err
    assert set(rep.summary()) == set(clip_tracker.names)


def test_saturation_is_planned(tracker, clip_tracker, synth):
    """'plan': the bounds are in the problem - the extensors switch off (u = 0) before the
    collapse, as the plan foresaw, and the torque error is far smaller than the paper's."""
    s = synth
    tau = _collapse(synth)
    res = tracker.track(s.t, tau, s.theta, s.theta_dot, s.theta_ddot, s.a_true[0])
    paper = clip_tracker.track(s.t, tau, s.theta, s.theta_dot, s.theta_ddot, s.a_true[0])
    ext = [tracker.names.index(n) for n in ('gmax', 'vas', 'sol')]
    rep = res.saturation
    assert res.saturation_mode == 'plan' and rep.fraction_planned[ext].min() > 0
    late = synth.t > 0.05

    def switch_off(r: Stage2Result) -> np.ndarray:
        return synth.t[late][np.argmax(r.u[late][:, ext] == 0.0, axis=0)]

    assert np.all(switch_off(res) < switch_off(paper))       # deactivation starts earlier
    assert np.all(switch_off(res) < 0.12)
    window = (synth.t > 0.1) & (synth.t < 0.2)
    err = np.sqrt(np.mean(res.tracking_error[window] ** 2, axis=0))
    err_paper = np.sqrt(np.mean(paper.tracking_error[window] ** 2, axis=0))
    assert np.all(err < 0.6 * err_paper), (err, err_paper)
    assert np.all((res.u >= 0) & (res.u <= 1))
    assert rep.shortfall_integral.sum() < 0.05 * paper.saturation.shortfall_integral.sum()


# ---------------------------------------------------------------------------- optimality
def test_lqt_solution_is_optimal_on_the_linear_system(tracker, synth):
    """No perturbation of eta lowers J (Eq. 11) of fdot = eta, tau = C f.

    J is evaluated exactly for piecewise-constant eta on a 0.25 ms grid; that projection of the
    continuous optimum leaves an O(h^2) first-order term (ratio to the second-order term ~0.4
    at 0.1 % amplitude here, ~2 on a 1 ms grid), so the amplitudes tested are >= 0.2 %.
    """
    ref = tracker.reference(*_inputs(synth), substeps=4)
    t, C, tau = ref.t, ref.C, ref.tau_ref
    sol = oracles.solve_lqt(t, C, tau, tracker.Q, tracker.R)
    f_opt, _ = oracles.simulate_linear(sol, synth.f_true[0])
    h = t[1] - t[0]
    eta = np.diff(f_opt, axis=0) / h                        # piecewise-constant optimum

    def cost(eta_pc: np.ndarray) -> float:
        f = synth.f_true[0] + np.vstack([np.zeros(9), np.cumsum(eta_pc, axis=0) * h])
        e = tau - np.einsum('npm,nm->np', C, f)
        qe = np.einsum('np,pq,nq->n', e, tracker.Q, e)
        cross = np.einsum('np,pq,nq->n', e[:-1], tracker.Q, e[1:])
        track = np.sum(qe[:-1] + qe[1:] + cross) * h / 3    # exact for linear e
        return 0.5 * (track + np.sum(eta_pc ** 2 * tracker.R) * h)

    j0 = cost(eta)
    rng = np.random.default_rng(7)
    tt = t[:-1, None]
    scale = np.abs(eta).max(axis=0)
    for _ in range(6):
        freq = rng.uniform(5, 60, 9)
        phase = rng.uniform(0, 2 * np.pi, 9)
        for amp in (0.05, 0.01, 0.002):
            d_eta = amp * scale * np.sin(2 * np.pi * freq * tt + phase)
            assert cost(eta + d_eta) > j0
            assert cost(eta - d_eta) > j0


# ---------------------------------------------------------------------------- reference jump
@pytest.fixture(scope='module')
def jump(tracker) -> dict:
    """The shipped reference jump: its true joint torques and kinematics as Stage-2 input.

    theta_ddot from the model's own dynamics at the true state (not finite differences).
    """
    from nmt_ros.io.trial_bag import read_truth

    tr = read_truth(JUMP_BAG)
    model = tracker.model
    theta, = model.batch(model.joint_angles, tr.q)
    x = np.hstack([tr.q, tr.qd, tr.a])
    xdot, = model.batch(model.musculoskeletal_ode, x, tr.u, np.tile(tr.x0, (tr.t.size, 1)))
    # joint angles are linear in q: theta = J q
    J = np.column_stack([model.call(model.joint_angles, e)[0] for e in np.eye(6)])
    with open(JUMP_BAG / 'reference.json') as fh:
        actual = json.load(fh)['actual']
    return {'truth': tr, 'inputs': (tr.t, tr.tau, theta, tr.qd @ J.T, xdot[:, 6:12] @ J.T),
            'contact': tr.t <= tr.liftoff_s, 'height_m': actual['jump_height_m']}


@pytest.fixture(scope='module')
def jump_full(tracker, jump) -> Stage2Result:
    return tracker.track(*jump['inputs'], jump['truth'].a[0])


def _contact_rms_relative(res: Stage2Result, contact: np.ndarray) -> np.ndarray:
    err = res.tracking_error[contact]
    return np.sqrt(np.mean(err ** 2, axis=0)) / np.abs(res.tau_ref[contact]).max(axis=0)


def test_reference_jump_full_horizon_tracks_true_torques(tracker, clip_tracker, jump,
                                                         jump_full):
    """Max-height jump (prime movers at u = 1 much of the push-off): < 1 % of each joint's
    peak over the contact phase (measured 0.2 / 0.7 / 0.3 % at kR 100; the paper's kR 1000
    leaves the knee at 1.7 %); the paper's clipped LQT misses that by far."""
    res, tr, contact = jump_full, jump['truth'], jump['contact']
    rel = _contact_rms_relative(res, contact)
    assert np.all(rel < 0.01), rel
    assert np.all((res.u >= 0) & (res.u <= 1)) and np.all((res.a >= 0) & (res.a <= 1))
    rep = res.saturation
    for name in ('gmax', 'hams', 'vas', 'sol'):            # saturated, and planned so
        j = tracker.names.index(name)
        assert rep.fraction_high[j] > 0.3 and rep.fraction_planned[j] > 0.3
    assert rep.shortfall_integral.max() < 1.0               # nothing the plan did not foresee
    assert len(res.plan_iterations) == 1 and res.plan_iterations[0] < 40 and res.plan_converged
    # forces: the effort criterion shares the load differently from the jump's optimiser
    # (RF, GAS), but every muscle stays within 8 % F0 of the truth
    d = np.sqrt(np.mean((res.f - tr.f)[contact] ** 2, axis=0)) / tracker.f0
    assert d.max() < 0.08, d
    paper = clip_tracker.track(*jump['inputs'], tr.a[0])
    assert _contact_rms_relative(paper, contact).max() > 0.1


def test_reference_jump_windowed_matches_full_horizon(tracker, jump, jump_full):
    """The default window (H <= 100 ms, stride one sample) within 2 % F0 of the full horizon."""
    H = tracker.settings.window_length
    assert H <= 0.1
    res = tracker.track(*jump['inputs'], jump['truth'].a[0], mode='windowed')
    d = np.sqrt(np.mean((res.f - jump_full.f) ** 2, axis=0)) / tracker.f0
    assert d.max() < 0.02, d
    assert np.all(_contact_rms_relative(res, jump['contact']) < 0.03)
    assert res.window_length == pytest.approx(H, abs=1e-3)
    assert len(res.plan_iterations) == res.t.size - 1


def test_reference_jump_nmt_height(tracker, jump, jump_full):
    """The skeleton driven by the Stage-2 excitations jumps within 1 % of the actual height
    (measured -0.54 % at kR 100; the paper's kR 1000 undertracks the push's end: -1.34 %)."""
    from nmt_ros.study.pipeline import simulate_stage2

    model, tr, res = tracker.model, jump['truth'], jump_full
    sim = simulate_stage2(model, res, tr.q[0], tr.qd[0], tr.x0, float(tr.t[-1]))
    i = int(np.searchsorted(sim.t, sim.liftoff_s))
    height = model.jump_height(sim.x[i, :6], sim.x[i, 6:12])['height_m']
    assert abs(height / jump['height_m'] - 1) < 0.01, (height, jump['height_m'])


def test_rest_activations_from_the_first_torque_sample(tracker, jump):
    """a0 without the truth: min sum a^2 at rest reproducing tau_ref(0) (the jump starts from
    the static squat, which used the same criterion)."""
    tr = jump['truth']
    t, tau, theta, theta_dot, _ = jump['inputs']
    r = rest_activations(tracker.model, theta[0], tau[0])
    assert r.exact and np.abs(r.residual).max() < 1e-6
    np.testing.assert_allclose(r.a, tr.a[0], atol=1e-5)
    drift, gain = tracker.activation.affine(r.a)
    np.testing.assert_allclose(drift + gain * r.u, 0.0, atol=1e-9)   # held at rest
    impossible = rest_activations(tracker.model, theta[0], 5 * tau[0])
    assert not impossible.exact and np.all((impossible.a >= 0) & (impossible.a <= 1))
    assert np.abs(impossible.residual).max() > 1.0


def test_final_push_without_new_samples_is_harmless(tracker, jump):
    """A live node may signal the end of the data with no sample left to add."""
    t, tau, th, thd, thdd = (x[:60] for x in jump['inputs'])
    stream = tracker.start_stream(jump['truth'].a[0], float(t[1] - t[0]))
    stream, steps = tracker.push(stream, t, tau, th, thd, thdd)
    empty = np.zeros((0, 3))
    stream, final_steps = tracker.push(stream, np.zeros(0), empty, empty, empty, empty,
                                       final=True)
    assert final_steps   # the windows held back for look-ahead are completed at the end
    assert all(np.isfinite(s.f).all() for s in steps + final_steps)
