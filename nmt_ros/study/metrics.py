"""Errors against the actual performance, as ``metrics.json`` (INTERFACES.md schema + extras).

All errors are RMS over the ground-contact phase of the actual jump (0 <= t <= lift-off),
on the estimates' own samples (the force-plate instants), against the truth at the same
instants. Jump height = ballistic apex of the whole-body COM from lift-off minus its height
standing upright (``JumperModel.jump_height``).
"""
from __future__ import annotations

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.parameters import JOINTS, MUSCLES, SEGMENTS
from nmt_ros.records import Truth
from nmt_ros.study.pipeline import NMTRun


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def _truth_index(truth: Truth, t: np.ndarray) -> np.ndarray:
    idx = np.rint(np.interp(t, truth.t, np.arange(truth.t.size))).astype(int)
    if np.abs(truth.t[idx] - t).max() > 1e-6:
        raise ValueError('estimates must be sampled on the truth grid')
    return idx


def _named(names: tuple[str, ...], values: np.ndarray) -> dict[str, float]:
    return {n: float(v) for n, v in zip(names, np.ravel(values))}


def jump_from(model: JumperModel, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
              liftoff_s: float) -> dict[str, float]:
    """Jump height from the state at lift-off (interpolated to the lift-off instant)."""
    if not np.isfinite(liftoff_s):
        return {'jump_height_m': float('nan'), 'liftoff_s': float('nan')}
    qi = np.array([np.interp(liftoff_s, t, q[:, j]) for j in range(6)])
    qdi = np.array([np.interp(liftoff_s, t, qd[:, j]) for j in range(6)])
    h = model.jump_height(qi, qdi)
    return {'jump_height_m': h['height_m'], 'liftoff_s': float(liftoff_s)}


def takeoffs(t: np.ndarray, fy: np.ndarray, threshold_n: float,
             min_flight_s: float = 0.1) -> np.ndarray:
    """Lift-off instants [s] of every jump in a long record: the vertical force fy [N] at
    times t [s] falls below ``threshold_n`` (interpolated crossing) after being above it, and
    stays below for at least ``min_flight_s`` (a flight, not a flicker of the force)."""
    t, fy = np.asarray(t, dtype=float), np.asarray(fy, dtype=float)
    up = fy >= threshold_n
    out = []
    for i in np.flatnonzero(up[:-1] & ~up[1:]):
        back = np.flatnonzero(up[i + 1:])
        end = t[i + 1 + back[0]] if back.size else t[-1]
        if end - t[i + 1] < min_flight_s:
            continue
        w = (fy[i] - threshold_n) / (fy[i] - fy[i + 1])
        out.append(t[i] + w * (t[i + 1] - t[i]))
    return np.array(out)


def jump_heights(model: JumperModel, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
                 liftoffs: np.ndarray) -> np.ndarray:
    """Jump height [m] (``JumperModel.jump_height``) from the state at each lift-off [s]."""
    return np.array([jump_from(model, t, q, qd, float(lo))['jump_height_m']
                     for lo in np.atleast_1d(liftoffs)])


def compute_metrics(model: JumperModel, run: NMTRun, truth: Truth,
                    po: dict | None = None) -> dict:
    """metrics.json content for one NMT run on a synthetic trial."""
    lo = truth.liftoff_s
    actual = jump_from(model, truth.t, truth.q, truth.qd, lo)
    peaks = np.abs(truth.tau[truth.t <= lo]).max(axis=0)
    f0 = model.p.muscles.f0
    out: dict = {'actual': {**actual, 'torque_peak_nm': _named(JOINTS, peaks)}}
    if po:
        out['po'] = {k: po[k] for k in ('cpu_s', 'wall_s', 'iterations', 'jump_height_m')
                     if k in po}

    skt = run.skt
    m = skt.t <= lo
    idx = _truth_index(truth, skt.t[m])
    tau_err = _rms(skt.tau[m] - truth.tau[idx])
    ang_err = np.degrees(_rms(skt.q[m, :4] - truth.q[idx, :4]))
    obs_err = np.degrees(_rms(run.cond.angles(skt.t[m]) - truth.q[idx, :4]))
    s_err = _rms(skt.s[m] - truth.s[idx])
    # Moment bias reduction: RMS of the model moment's error vs RMS of the observed moment's
    # bias (the slow error the tracker should not follow), both against the truth.
    obs_m_err = _rms(run.cond.wrench(skt.t[m])[:, 2] - truth.s[idx, 2])
    out['skt'] = {
        'cpu_s': run.cpu_s.get('stage1', skt.cpu_s), 'status': skt.status,
        'events': skt.events,
        'torque_rms_nm': _named(JOINTS, tau_err),
        'torque_rms_pct_peak': _named(JOINTS, 100 * tau_err / peaks),
        'angle_rms_deg': _named(SEGMENTS, ang_err),
        'filtered_observation_angle_rms_deg': _named(SEGMENTS, obs_err),
        'grf_rms_n': {'fore_aft': float(s_err[0]), 'vertical': float(s_err[1])},
        'moment_rms_nm': float(s_err[2]),
        'filtered_observation_moment_rms_nm': float(obs_m_err),
        'liftoff_s': skt.liftoff_s,
        **{k: v for k, v in jump_from(model, skt.t, skt.q, skt.qd, skt.liftoff_s).items()
           if k == 'jump_height_m'},
    }
    if obs_m_err > 0:
        out['skt']['moment_error_reduction'] = float(1 - s_err[2] / obs_m_err)
    if skt.muscles is not None:      # muscle-driven Stage 1: its own muscle forces
        f1_err = _rms(skt.muscles['f'][m] - truth.f[idx])
        out['skt']['muscle_force_rms_pct_f0'] = _named(MUSCLES, 100 * f1_err / f0)

    ivd = run.ivd
    mi = ivd.t <= lo
    idx = _truth_index(truth, ivd.t[mi])
    ivd_err = _rms(ivd.tau[mi] - truth.tau[idx])
    out['ivd'] = {
        'torque_rms_nm': _named(JOINTS, ivd_err),
        'torque_rms_pct_peak': _named(JOINTS, 100 * ivd_err / peaks),
        'simulation': ivd.sim_status,
        **jump_from(model, ivd.sim_t, ivd.sim_q, ivd.sim_qd, ivd.sim_liftoff_s),
    }

    if run.stage2 is not None:
        s2 = run.stage2
        ms = s2.t <= lo
        idx = _truth_index(truth, s2.t[ms])
        nmt_tau_err = _rms(s2.tau_muscle[ms] - truth.tau[idx])
        f_err = _rms(s2.f[ms] - truth.f[idx])
        corr = [float(np.corrcoef(s2.f[ms, i], truth.f[idx, i])[0, 1])
                if np.std(truth.f[idx, i]) > 1e-9 and np.std(s2.f[ms, i]) > 1e-9 else
                float('nan') for i in range(len(MUSCLES))]
        track_err = _rms(s2.tracking_error[ms])
        sim = run.nmt_sim
        out['nmt'] = {
            'cpu_s': run.cpu_s.get('nmt_total'),
            'cpu_s_parts': {k: run.cpu_s[k] for k in ('stage1', 'stage2') if k in run.cpu_s},
            'torque_rms_nm': _named(JOINTS, nmt_tau_err),
            'torque_rms_pct_peak': _named(JOINTS, 100 * nmt_tau_err / peaks),
            'stage2_tracking_rms_pct_peak': _named(
                JOINTS, 100 * track_err / np.abs(s2.tau_ref[ms]).max(axis=0)),
            'muscle_force_rms_n': _named(MUSCLES, f_err),
            'muscle_force_rms_pct_f0': _named(MUSCLES, 100 * f_err / f0),
            'muscle_force_correlation': _named(MUSCLES, np.array(corr)),
            'muscle_peak_force_over_f0': _named(MUSCLES, s2.f[ms].max(axis=0) / f0),
            'actual_peak_force_over_f0': _named(MUSCLES, truth.f[idx].max(axis=0) / f0),
            'saturation': s2.saturation.summary() if s2.saturation is not None else {},
            **jump_from(model, sim.t, sim.x[:, :6], sim.x[:, 6:12], sim.liftoff_s),
        }
        ma = sim.t <= lo
        idx = _truth_index(truth, sim.t[ma])
        ssim, = model.batch(model.contact_outputs, sim.x[ma, :6], sim.x[ma, 6:12], sim.x0)
        out['nmt']['simulation_angle_rms_deg'] = _named(
            SEGMENTS, np.degrees(_rms(sim.x[ma, :4] - truth.q[idx, :4])))
        s_err = _rms(ssim - truth.s[idx])
        out['nmt']['simulation_grf_rms_n'] = {'fore_aft': float(s_err[0]),
                                              'vertical': float(s_err[1])}
        out['nmt']['recruitment_onset_s'] = recruitment_onsets(s2.t, s2.a)
        out['actual']['recruitment_onset_s'] = recruitment_onsets(truth.t, truth.a)
    return out


def recruitment_onsets(t: np.ndarray, a: np.ndarray, level: float = 0.5) -> dict[str, float]:
    """First time each muscle's activation reaches ``level`` (NaN if never)."""
    out = {}
    for i, name in enumerate(MUSCLES):
        above = np.nonzero(a[:, i] >= level)[0]
        out[name] = float(t[above[0]]) if above.size else float('nan')
    return out
