"""Stage 1 (skeletal motion tracker) and the IVD baseline (issue 4)."""
from pathlib import Path

import numpy as np

from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.tracking.conditioning import ConditioningSettings, FixedLagConditioner, condition
from nmt_ros.tracking.ivd import inverse_dynamics_baseline, simulate_open_loop
from nmt_ros.tracking.skeletal_tracker import SKTSettings, initial_state, reference_arrays
from nmt_ros.tracking.streaming import Stage1Stream, track_stage1

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'





def contact_rms(t, est, truth, ref):
    m = t <= truth.liftoff_s
    idx = np.rint(t[m] * 1080).astype(int)
    return np.sqrt(np.mean((est[m] - ref[idx]) ** 2, axis=0))


def test_tracker_reproduces_the_truth_from_clean_data(model, truth):
    """Noise-free observations (filters wide enough for this fast push): the feedback-
    linearised tracker follows the actual jump (torques < 5 % of peak, angles < 0.1 deg)."""
    obs, _ = make_observations(truth, ObservationSettings(noise_scale=0.0),
                               body_weight=model.p.body_weight)
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench,
                     ConditioningSettings(angle_cutoff_hz=20.0))
    res = track_stage1(model, cond)
    assert res.ok
    peak = np.abs(truth.tau[truth.t <= truth.liftoff_s]).max(axis=0)
    pct = 100 * contact_rms(res.t, res.tau, truth, truth.tau) / peak
    assert (pct < 5.0).all(), pct
    assert np.degrees(contact_rms(res.t, res.q[:, :4], truth, truth.q[:, :4])).max() < 0.1
    assert contact_rms(res.t, res.s[:, :2], truth, truth.s[:, :2]).max() < 0.01 * 737


def test_exact_and_numerical_jacobians_give_the_same_torques(model, obs):
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
    exact = track_stage1(model, cond, SKTSettings(jacobians='exact'))
    numer = track_stage1(model, cond, SKTSettings(jacobians='numerical'))
    peak = np.abs(exact.tau).max(axis=0)
    assert (np.abs(exact.tau - numer.tau).max(axis=0) / peak < 1e-4).all()


def test_live_fixed_lag_stream_matches_batch(model, obs):
    """Fed sample by sample with 100 ms of look-ahead, Stage 1 gives the batch torques."""
    batch = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    cond = FixedLagConditioner(ConditioningSettings(lookahead_s=0.1))
    stream = Stage1Stream(model, conditioner=cond)
    outs, ia = [], 0
    for k, t in enumerate(obs.t_wrench):
        while ia < obs.t_angles.size and obs.t_angles[ia] <= t + 1e-12:
            cond.add_angles(obs.t_angles[ia], obs.angles[ia])
            ia += 1
        cond.add_wrench(t, obs.wrench[k])
        if k % 9 == 8:
            outs.append(stream.poll())
    cond.close()
    outs.append(stream.poll())
    tau = np.concatenate([o.tau for o in outs if o is not None])
    t = np.concatenate([o.t for o in outs if o is not None])
    np.testing.assert_allclose(t, batch.t)
    peak = np.abs(batch.tau).max(axis=0)
    rms = np.sqrt(np.mean((tau - batch.tau)[t <= 0.2] ** 2, axis=0)) / peak
    assert (rms < 0.02).all(), rms


def test_paper_findings_on_the_shipped_bag(model, truth, obs):
    """SKT vs filtered observations and vs IVD, on the shipped trial (paper Fig. 3)."""
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
    skt = track_stage1(model, cond)
    assert skt.ok
    # Foot and shank closer to the actual than the filtered observations (paper Fig. 3B).
    m = skt.t <= truth.liftoff_s
    ang = contact_rms(skt.t, skt.q[:, :4], truth, truth.q[:, :4])
    obs_ang = contact_rms(skt.t, cond.angles(skt.t), truth, truth.q[:, :4])
    assert ang[0] < obs_ang[0] and ang[1] < obs_ang[1]
    # The ground moment: closer to the actual than the biased observation.
    m_err = contact_rms(skt.t, skt.s[:, 2:3], truth, truth.s[:, 2:3])[0]
    obs_m_err = contact_rms(skt.t, cond.wrench(skt.t)[:, 2:3], truth, truth.s[:, 2:3])[0]
    assert m_err < 0.6 * obs_m_err
    # IVD: its open-loop simulation leaves the ground early (paper Fig. 3C).
    init = initial_state(model, reference_arrays(cond, np.array([0.0]))[0])
    ivd = simulate_open_loop(model, inverse_dynamics_baseline(model, cond, init), init)
    assert ivd.sim_liftoff_s < truth.liftoff_s - 0.005
    assert abs(skt.liftoff_s - truth.liftoff_s) < abs(ivd.sim_liftoff_s - truth.liftoff_s)
    # The IVD simulation's ground forces deviate far more than the tracker's.
    ivd_f = contact_rms(ivd.sim_t[ivd.sim_t <= ivd.t[-1]], ivd.sim_s[ivd.sim_t <= ivd.t[-1]],
                        truth, truth.s)
    skt_f = contact_rms(skt.t[m], skt.s[m], truth, truth.s)
    assert (ivd_f[:2] > 3 * skt_f[:2]).all()


def test_loss_of_control_is_detected_and_reported(model, truth):
    """4x the paper's noise, and long quiet standing (the slowly unstable mode of Table 1's
    weights): the tracker stops with a reason instead of hanging or diverging."""
    cases = []
    for seed in (3, 4):
        obs, _ = make_observations(truth, ObservationSettings(noise_scale=4.0, seed=seed),
                                   body_weight=model.p.body_weight)
        cases.append(condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    rng = np.random.default_rng(0)
    t_a, t_w = np.arange(360) / 120, np.arange(3240) / 1080   # 3 s standing in the squat
    cases.append(condition(t_a, truth.q[0, :4] + rng.normal(size=(360, 4)) * np.radians(
        [5, 3, 2, 1]), t_w, truth.s[0] + rng.normal(size=(3240, 3)) * [14.7, 14.7, 2.5]))
    for cond in cases:
        res = track_stage1(model, cond)
        assert res.status == 'lost_control'
        ev = res.events[0]
        assert ev['reason'] and 0 <= ev['t'] <= cond.t_end
        assert np.isfinite(res.tau).all()   # what was returned is usable
        assert np.abs(res.tau).max() < SKTSettings().max_torque_nm + 1.0
        assert res.t.size == 0 or res.t[-1] < ev['t']   # nothing past the event


def test_optimal_tracking_is_consistent_and_beats_the_tracker(model, truth, obs):
    """Stage 1 by optimal tracking: a solution of Eq. 1 (collocation), closer to the actual
    torques and ground forces than the paper's tracker on the shipped trial."""
    from nmt_ros.tracking.optimal_tracker import track_optimal

    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
    skt = track_stage1(model, cond)
    opt = track_optimal(model, obs, skt)
    assert opt.ok, opt.status
    # Dynamically consistent: the torques reproduce the motion through Eq. 1.
    res, = model.batch(model.dynamics_residual, opt.q, opt.qd, opt.qdd, opt.tau, opt.x0)
    assert np.abs(res).max() < 1e-6
    peak = np.abs(truth.tau[truth.t <= truth.liftoff_s]).max(axis=0)
    e_opt = contact_rms(opt.t, opt.tau, truth, truth.tau) / peak
    e_skt = contact_rms(skt.t, skt.tau, truth, truth.tau) / peak
    assert (e_opt < e_skt).all(), (e_opt, e_skt)
    f_opt = contact_rms(opt.t, opt.s[:, :2], truth, truth.s[:, :2])
    f_skt = contact_rms(skt.t, skt.s[:, :2], truth, truth.s[:, :2])
    assert (f_opt < f_skt).all()
    assert abs(opt.liftoff_s - truth.liftoff_s) < 0.002


def test_conditioning_names_bad_input(obs):
    """Batch input with a NaN or a gap is refused with an error naming the problem."""
    import pytest

    w = obs.wrench.copy()
    w[100, 1] = np.nan
    with pytest.raises(ValueError, match=r'wrench observations must be finite: NaN or inf at '
                                         r'sample 100 \(t = 0\.0926 s\), column 1'):
        condition(obs.t_angles, obs.angles, obs.t_wrench, w)
    keep = np.ones(obs.t_wrench.size, bool)
    keep[120:125] = False
    with pytest.raises(ValueError, match='uniformly spaced'):
        condition(obs.t_angles, obs.angles, obs.t_wrench[keep], obs.wrench[keep])
