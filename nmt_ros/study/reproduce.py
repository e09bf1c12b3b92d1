"""The paper's study end to end, plus the robustness studies around it.

``reproduce(out, ...)``: NMT and IVD on the reference bag (metrics, Figs. 3-5), then
* other noise realisations (seeds) of the same truth: mean and worst of the main errors;
* a sweep of the noise scale (0.5x..3x the paper's): where Stage 1 degrades, and that loss of
  control is detected and reported;
* exact vs numerical Jacobians in Stage 1 (torque difference, CPU);
* Stage 2 in receding windows: the latency (H) / accuracy curve against the full horizon.
"""
from __future__ import annotations

from dataclasses import asdict, replace
import json
from pathlib import Path
import time

import numpy as np

from nmt_ros.io.trial_bag import read_observations, read_truth
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.parameters import JOINTS
from nmt_ros.records import Truth
from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.study.pipeline import NMTSettings, joint_kinematics, run_nmt
from nmt_ros.tracking.conditioning import condition
from nmt_ros.tracking.skeletal_tracker import SKTSettings
from nmt_ros.tracking.stage2 import NeuromuscularTracker
from nmt_ros.tracking.streaming import track_stage1


def _contact_rms_pct(t: np.ndarray, est: np.ndarray, truth: Truth, ref: np.ndarray,
                     ) -> np.ndarray:
    m = t <= truth.liftoff_s
    idx = np.rint(np.interp(t[m], truth.t, np.arange(truth.t.size))).astype(int)
    peaks = np.abs(ref[truth.t <= truth.liftoff_s]).max(axis=0)
    return 100 * np.sqrt(np.mean((est[m] - ref[idx]) ** 2, axis=0)) / peaks


def seed_study(model: JumperModel, truth: Truth, seeds: list[int],
               obs_settings: ObservationSettings, say: callable,
               settings: NMTSettings | None = None) -> dict:
    """NMT on other noise realisations: per-seed errors, mean and worst."""
    from nmt_ros.study.metrics import compute_metrics

    settings = settings if settings is not None else NMTSettings()
    rows = []
    for seed in seeds:
        obs, _ = make_observations(truth, replace(obs_settings, seed=seed),
                                   body_weight=model.p.body_weight)
        run = run_nmt(model, obs, settings)
        m = compute_metrics(model, run, truth)
        row = {'seed': seed, 'skt_status': m['skt']['status'],
               'skt_torque_pct': m['skt']['torque_rms_pct_peak'],
               'skt_angle_deg': m['skt']['angle_rms_deg'],
               'filtered_obs_angle_deg': m['skt']['filtered_observation_angle_rms_deg'],
               'skt_grf_n': m['skt']['grf_rms_n'],
               'skt_moment_error_reduction': m['skt'].get('moment_error_reduction'),
               'ivd_torque_pct': m['ivd']['torque_rms_pct_peak'],
               'ivd_liftoff_s': m['ivd']['liftoff_s'],
               'ivd_jump_height_m': m['ivd']['jump_height_m']}
        if 'nmt' in m:
            row.update({'nmt_jump_height_m': m['nmt']['jump_height_m'],
                        'nmt_liftoff_s': m['nmt']['liftoff_s'],
                        'nmt_torque_pct': m['nmt']['torque_rms_pct_peak'],
                        'stage2_tracking_pct': m['nmt']['stage2_tracking_rms_pct_peak'],
                        'muscle_force_pct_f0': m['nmt']['muscle_force_rms_pct_f0'],
                        'nmt_cpu_s': m['nmt']['cpu_s']})
        rows.append(row)
        say(f'seed {seed}: Stage 1 torque % {_short(row["skt_torque_pct"])}, NMT jump '
            f'{row.get("nmt_jump_height_m", float("nan")) * 100:.1f} cm')
    return {'seeds': rows, 'summary': _summarise(rows)}


def _short(d: dict) -> str:
    return '/'.join(f'{v:.1f}' for v in d.values())


def _summarise(rows: list[dict]) -> dict:
    """Mean and worst (max) of every numeric leaf across rows."""
    out: dict = {}
    for key in rows[0]:
        vals = [r.get(key) for r in rows]
        if isinstance(vals[0], dict):
            out[key] = {k: {'mean': float(np.nanmean([v[k] for v in vals])),
                            'worst': float(np.nanmax([v[k] for v in vals]))}
                        for k in vals[0] if isinstance(vals[0][k], (int, float))}
        elif isinstance(vals[0], (int, float)) and key != 'seed':
            arr = np.array(vals, dtype=float)
            out[key] = {'mean': float(np.nanmean(arr)), 'worst': float(np.nanmax(arr)),
                        'best': float(np.nanmin(arr))}
    return out


def noise_sweep(model: JumperModel, truth: Truth, scales: list[float], seeds: list[int],
                obs_settings: ObservationSettings, say: callable) -> list[dict]:
    """Stage 1 against the noise scale: errors, and loss of control detected and reported."""
    rows = []
    for scale in scales:
        for seed in seeds:
            obs, _ = make_observations(truth, replace(obs_settings, seed=seed,
                                                      noise_scale=scale),
                                       body_weight=model.p.body_weight)
            cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
            res = track_stage1(model, cond)
            row = {'noise_scale': scale, 'seed': seed, 'status': res.status,
                   'events': res.events, 'cpu_s': res.cpu_s}
            if res.ok:
                pct = _contact_rms_pct(res.t, res.tau, truth, truth.tau)
                row['torque_rms_pct_peak'] = dict(zip(JOINTS, pct.tolist()))
            rows.append(row)
            say(f'noise x{scale:g} seed {seed}: {res.status}'
                + (f' ({res.events[0]["reason"]} at {res.events[0]["t"]:.3f} s)'
                   if res.events else f', torque % {_short(row["torque_rms_pct_peak"])}'))
    return rows


def optimal_study(model: JumperModel, truth: Truth, obs: object, seeds: list[int],
                  obs_settings: ObservationSettings, say: callable,
                  stage1: str = 'optimal', run: object | None = None) -> dict:
    """The whole NMT with Stage 1 by optimal tracking (``stage1``: 'optimal', free joint
    torques, or 'optimal_muscle', muscle-made torques); seed 0 = the shipped observations
    (``run``: its NMT run if already made)."""
    from nmt_ros.study.metrics import compute_metrics

    settings = NMTSettings(stage1=stage1)
    run = run if run is not None else run_nmt(model, obs, settings)
    shipped = compute_metrics(model, run, truth)
    say(f'{stage1}, shipped bag: Stage 1 torque % '
        f'{_short(shipped["skt"]["torque_rms_pct_peak"])}, NMT '
        f'jump {shipped["nmt"]["jump_height_m"] * 100:.1f} cm')
    others = seed_study(model, truth, [s for s in seeds if s != 0], obs_settings, say, settings)
    return {'shipped': {k: shipped[k] for k in ('skt', 'nmt')}, 'seeds': others}


def stage2_weight_study(model: JumperModel, truth: Truth, run: object, k_rs: list[float],
                        say: callable) -> list[dict]:
    """Stage 2 against its effort weight kR (Appendix B: 1000), on the actual torques and
    kinematics and on ``run``'s Stage 1: tracking, NMT jump, muscle forces vs actual."""
    from nmt_ros.study.metrics import jump_from
    from nmt_ros.study.pipeline import simulate_stage2
    from nmt_ros.tracking.stage2 import load_stage2_settings

    actual = jump_from(model, truth.t, truth.q, truth.qd, truth.liftoff_s)['jump_height_m']
    f0 = model.p.muscles.f0
    skt = run.skt
    inputs = [('actual torques', truth.t, truth.q, truth.qd, truth.qdd, truth.tau, truth.x0,
               truth.liftoff_s), (f'Stage 1 ({run_label(run)})', skt.t, skt.q, skt.qd, skt.qdd,
                                  skt.tau, skt.x0, skt.liftoff_s)]
    rows = []
    for name, t, q, qd, qdd, tau, x0, lo in inputs:
        for k_r in k_rs:
            tracker = NeuromuscularTracker(model, load_stage2_settings(k_r=k_r))
            s2 = tracker.track_motion(t, q, qd, qdd, tau, x0, lo + 0.01)
            sim = simulate_stage2(model, s2, q[0], qd[0], x0, float(s2.t[-1]) + 0.02)
            jump = jump_from(model, sim.t, sim.x[:, :6], sim.x[:, 6:12], sim.liftoff_s)
            m = s2.t <= truth.liftoff_s
            idx = np.rint(np.interp(s2.t[m], truth.t, np.arange(truth.t.size))).astype(int)
            f_pct = 100 * np.sqrt(np.mean((s2.f[m] - truth.f[idx]) ** 2, axis=0)) / f0
            rows.append({'input': name, 'k_r': k_r,
                         'tracking_pct_peak': dict(zip(JOINTS,
                                                       (100 * s2.rms_error_relative).tolist())),
                         'nmt_jump_height_m': jump['jump_height_m'],
                         'nmt_jump_error_pct': 100 * (jump['jump_height_m'] / actual - 1),
                         'muscle_force_rms_pct_f0_mean': float(f_pct.mean()),
                         'muscle_force_rms_pct_f0_max': float(f_pct.max())})
            say(f'Stage 2 kR {k_r:g} on {name}: NMT jump {rows[-1]["nmt_jump_error_pct"]:+.2f} %'
                f', forces {f_pct.mean():.2f} % F0 (mean)')
    return rows


def run_label(run: object) -> str:
    """'muscle-driven optimal tracking' etc. from a run's Stage-1 result."""
    return 'optimal tracking, muscle torques' if run.skt.muscles is not None else 'Stage 1'


def jacobian_study(model: JumperModel, obs: object) -> dict:
    """Exact (AD) vs numerical (central differences) Jacobians in Stage 1."""
    cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
    exact = track_stage1(model, cond, SKTSettings(jacobians='exact'))
    numer = track_stage1(model, cond, SKTSettings(jacobians='numerical'))
    n = min(exact.t.size, numer.t.size)
    peak = np.abs(exact.tau[:n]).max(axis=0)
    diff = np.abs(exact.tau[:n] - numer.tau[:n]).max(axis=0) / peak
    return {'max_torque_difference_rel_peak': dict(zip(JOINTS, diff.tolist())),
            'cpu_s_exact': exact.cpu_s, 'cpu_s_numerical': numer.cpu_s,
            'faster': 'exact' if exact.cpu_s < numer.cpu_s else 'numerical'}


def window_study(model: JumperModel, run: object, truth: Truth, windows_s: list[float],
                 say: callable) -> list[dict]:
    """Stage 2 in receding windows of length H vs the full horizon (same Stage-1 input)."""
    skt = run.skt
    s2_full = run.stage2
    keep = np.searchsorted(skt.t, s2_full.t - 1e-12)
    th, thd, thdd = joint_kinematics(model, skt.q[keep], skt.qd[keep], skt.qdd[keep])
    tracker = NeuromuscularTracker(model)
    f0 = model.p.muscles.f0
    m = s2_full.t <= truth.liftoff_s
    rows = []
    for h in windows_s:
        c = time.process_time()
        s2 = tracker.track(s2_full.t, skt.tau[keep], th, thd, thdd, run.a0, mode='windowed',
                           window_length=h)
        cpu = time.process_time() - c
        diff = 100 * np.sqrt(np.mean((s2.f[m] - s2_full.f[m]) ** 2, axis=0)) / f0
        track_pct = 100 * np.sqrt(np.mean(s2.tracking_error[m] ** 2, axis=0)) / np.abs(
            s2.tau_ref[m]).max(axis=0)
        rows.append({'window_s': h, 'latency_s': s2.latency_s,
                     'max_force_difference_pct_f0': float(diff.max()),
                     'mean_force_difference_pct_f0': float(diff.mean()),
                     'torque_tracking_pct_peak': dict(zip(JOINTS, track_pct.tolist())),
                     'cpu_s': cpu})
        say(f'Stage 2 window {h * 1000:.0f} ms: max force difference {diff.max():.2f} % F0, '
            f'CPU {cpu:.2f} s')
    return rows


def reproduce(out: Path, bag: Path, quick: bool = False, say: callable = print,
              po: dict | None = None) -> dict:
    """The whole study on ``bag`` (a synthetic trial bag); writes ``out``; returns metrics."""
    from nmt_ros.model.jumper import default_model
    from nmt_ros.study.batch import track_bag
    from nmt_ros.study.report import markdown_report

    model = default_model()
    t0 = time.perf_counter()
    say('[1/6] NMT and IVD on the reference observations')
    metrics = track_bag(bag, out, say=say, stage1='skt')   # the paper's method first
    if metrics is None:
        raise ValueError(f'{bag} has no /truth/* topics: cannot reproduce the study on it')
    if po is not None:
        metrics['po'] = po
    truth = read_truth(bag)
    obs = read_observations(bag)
    obs_settings = ObservationSettings(**json.loads(
        metrics['custom_data'].get('nmt.observation_settings', '{}')))
    seeds = [1, 2] if quick else [1, 2, 3, 4, 5]
    say(f'[2/6] {len(seeds)} other noise realisations')
    metrics['seeds'] = seed_study(model, truth, seeds, obs_settings, say)
    scales = [0.5, 1.0, 3.0] if quick else [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    say(f'[3/6] noise sweep x{scales}')
    metrics['noise_sweep'] = noise_sweep(model, truth, scales, [1] if quick else [1, 2],
                                         obs_settings, say)
    say('[4/6] exact vs numerical Jacobians')
    metrics['jacobians'] = jacobian_study(model, obs)
    say('[5/6] Stage 2 windows (latency / accuracy)')
    run = run_nmt(model, obs, NMTSettings())
    windows = [0.02, 0.1] if quick else [0.01, 0.02, 0.05, 0.1, 0.15, 0.2]
    metrics['stage2_windows'] = window_study(model, run, truth, windows, say)
    say('[6/6] beyond the paper: Stage 1 by optimal tracking (joint torques free, then made by '
        'the muscles), same observations and seeds')
    metrics['optimal_stage1'] = optimal_study(model, truth, obs, [0] + seeds, obs_settings, say)
    muscle_run = run_nmt(model, obs, NMTSettings(stage1='optimal_muscle'))
    metrics['muscle_stage1'] = optimal_study(model, truth, obs, [0] + seeds, obs_settings, say,
                                             stage1='optimal_muscle', run=muscle_run)
    say('Stage 2 effort weight kR (Appendix B: 1000)')
    metrics['stage2_weights'] = stage2_weight_study(model, truth, muscle_run,
                                                    [1000.0, 100.0] if quick
                                                    else [1000.0, 300.0, 100.0, 30.0], say)
    metrics['settings'] = {'nmt': _settings_dict(NMTSettings()), 'quick': quick}
    metrics['wall_s'] = time.perf_counter() - t0
    (out / 'metrics.json').write_text(json.dumps(metrics, indent=1, default=float))
    (out / 'report.md').write_text(markdown_report(metrics) + _extra_report(metrics))
    say(f'wrote {out}/metrics.json, report.md, figures ({metrics["wall_s"]:.0f} s)')
    return metrics


def _optimal_report(m: dict) -> list[str]:
    """Rows for Stage 1 by optimal tracking next to the paper's tracker."""
    studies = [(m[k], name) for k, name in (('optimal_stage1', 'optimal, free torques'),
                                            ('muscle_stage1', 'optimal, muscle torques'))
               if k in m]
    if not studies:
        return []

    def seed_mean(summary: dict, key: str) -> str:
        return '/'.join(f'{v["mean"]:.1f}' for v in summary[key].values())

    def grf(b: dict) -> str:
        return f'{b["grf_rms_n"]["fore_aft"]:.1f} / {b["grf_rms_n"]["vertical"]:.1f}'

    cols = [(m['skt'], m['nmt'], m['seeds']['summary'])] + [
        (o['shipped']['skt'], o['shipped']['nmt'], o['seeds']['summary']) for o, _ in studies]
    rows = [
        ('torque RMS % of peak', lambda sk, nm, se: _short(sk['torque_rms_pct_peak'])),
        ('seeds: mean torque %', lambda sk, nm, se: seed_mean(se, 'skt_torque_pct')),
        ('angles RMS deg', lambda sk, nm, se: _short(sk['angle_rms_deg'])),
        ('GRF RMS N', lambda sk, nm, se: grf(sk)),
        ('moment RMS N m', lambda sk, nm, se: f'{sk["moment_rms_nm"]:.1f}'),
        ('Stage 1 CPU s', lambda sk, nm, se: f'{sk["cpu_s"]:.2f}'),
        ('Stage 2 tracking % of Stage-1 peak',
         lambda sk, nm, se: _short(nm['stage2_tracking_rms_pct_peak'])),
        ('NMT jump cm', lambda sk, nm, se: f'{nm["jump_height_m"] * 100:.1f}'),
        ('seeds: NMT jump cm (mean / lowest)',
         lambda sk, nm, se: f'{se["nmt_jump_height_m"]["mean"] * 100:.1f} / '
                            f'{se["nmt_jump_height_m"]["best"] * 100:.1f}'),
        ('seeds: mean Stage 2 tracking %',
         lambda sk, nm, se: seed_mean(se, 'stage2_tracking_pct')),
        ('muscle force RMS % F0', lambda sk, nm, se: _short(nm['muscle_force_rms_pct_f0'])),
    ]
    out = ['### Beyond the paper: Stage 1 by optimal tracking (offline)', '',
           '| | paper\'s tracker (SKT) | ' + ' | '.join(name for _, name in studies) + ' |',
           '|---|---|' + '---|' * len(studies)]
    out += ['| ' + ' | '.join([label] + [fmt(*c) for c in cols]) + ' |' for label, fmt in rows]
    return out + ['']


def _settings_dict(s: NMTSettings) -> dict:
    return json.loads(json.dumps(asdict(s), default=str))


def _extra_report(m: dict) -> str:
    lines = ['', '## Robustness', '']
    lines += _optimal_report(m)
    s = m['seeds']['summary']
    lines.append(f'Other noise seeds ({len(m["seeds"]["seeds"])}): SKT torque RMS % of peak, '
                 'mean / worst: ' + ', '.join(
                     f'{j} {s["skt_torque_pct"][j]["mean"]:.1f} / '
                     f'{s["skt_torque_pct"][j]["worst"]:.1f}' for j in JOINTS) + '.')
    if 'nmt_jump_height_m' in s:
        lines.append(f'NMT jump height over seeds: mean {s["nmt_jump_height_m"]["mean"] * 100:.1f}'
                     f' cm (range {s["nmt_jump_height_m"]["best"] * 100:.1f}..'
                     f'{s["nmt_jump_height_m"]["worst"] * 100:.1f} cm); actual '
                     f'{m["actual"]["jump_height_m"] * 100:.1f} cm.')
    lines += ['', '| noise scale | seed | Stage 1 status | torque RMS % peak (ankle/knee/hip) |',
              '|---|---|---|---|']
    for r in m['noise_sweep']:
        tq = _short(r['torque_rms_pct_peak']) if 'torque_rms_pct_peak' in r else \
            f'lost control: {r["events"][0]["reason"]} at {r["events"][0]["t"]:.3f} s'
        lines.append(f'| {r["noise_scale"]:g} | {r["seed"]} | {r["status"]} | {tq} |')
    j = m['jacobians']
    lines += ['', 'Exact vs numerical Jacobians: max torque difference '
              + ', '.join(f'{k} {v:.1e}' for k, v in j['max_torque_difference_rel_peak'].items())
              + f' of peak; CPU exact {j["cpu_s_exact"]:.2f} s, numerical '
              f'{j["cpu_s_numerical"]:.2f} s.', '',
              '| Stage 2 window H (ms) | latency (ms) | max force diff vs full (% F0) | CPU (s) |',
              '|---|---|---|---|']
    for r in m['stage2_windows']:
        lines.append(f'| {r["window_s"] * 1000:.0f} | {r["latency_s"] * 1000:.0f} | '
                     f'{r["max_force_difference_pct_f0"]:.2f} | {r["cpu_s"]:.2f} |')
    if 'stage2_weights' in m:
        lines += ['', 'Stage 2 effort weight kR (Appendix B: 1000; `nmt track --stage2-kr`):',
                  '',
                  '| input | kR | tracking % of peak | NMT jump error % '
                  '| forces % F0 (mean / max) |',
                  '|---|---|---|---|---|']
        for r in m['stage2_weights']:
            lines.append(f'| {r["input"]} | {r["k_r"]:g} | {_short(r["tracking_pct_peak"])} | '
                         f'{r["nmt_jump_error_pct"]:+.2f} | '
                         f'{r["muscle_force_rms_pct_f0_mean"]:.2f} / '
                         f'{r["muscle_force_rms_pct_f0_max"]:.2f} |')
    return '\n'.join(lines) + '\n'
