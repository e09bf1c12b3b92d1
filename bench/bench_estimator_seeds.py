"""The moving-horizon estimator (live Stage 1) on fresh noise realisations of a routine: the
shipped routine's truth observed again with the routine generator's noise and bias under other
seeds (``study.routine_observations``), each realisation tracked offline (= live) and scored
by phase against the truth (refined and low-latency), with the height of every jump from the
tracked motion (``study.recording_evaluation.jump_table``, as ``nmt demo`` reports it); per
seed, then the mean and the worst over the seeds.

    python bench/bench_estimator_seeds.py [--bag bags/routine] [--seeds 1,2,3,4]
                                          [--duration 60] [--faults] [--set key=value ...]
                                          [--json F]

One realisation of a shipped bag says little about hidden ones: the estimator's losses of
control (and so its errors) change with the noise. ``--set`` overrides a
``MovingHorizonSettings`` field (Python literal), to compare variants on the same seeds.
About 16 s of CPU per seed and minute of data (2-core machine, idle).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
from pathlib import Path
import warnings

from single_threaded import ROOT  # first: one BLAS thread before numpy loads

# isort: split
import numpy as np

from nmt_ros import topics
from nmt_ros.io.bags import read_topics_arrays
from nmt_ros.io.trial_bag import read_truth
from nmt_ros.model.jumper import default_model
from nmt_ros.records import Truth
from nmt_ros.study.metrics import takeoffs
from nmt_ros.study.phase_scores import PHASES, phase_scores
from nmt_ros.study.recording_evaluation import jump_table
from nmt_ros.study.routine_observations import (
    RoutineObservationSettings,
    make_routine_observations,
)
from nmt_ros.tracking.moving_horizon.estimator import estimate
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE


def plate_rate_truth(bag: str) -> tuple[Truth, Truth]:
    """(the bag's truth, the same on the force-plate instants): the generator needs the
    ground wrench at every plate instant; a routine bag keeps its kinematic truth at the
    mocap rate, whose instants are plate instants (the angles are only read there)."""
    truth = read_truth(bag)
    gw = read_topics_arrays(bag, [topics.TRUTH_GROUND_WRENCH])[topics.TRUTH_GROUND_WRENCH]
    t = (gw.stamp_ns - truth.info['epoch_ns']) * 1e-9
    s = np.column_stack([gw.force[:, 0], gw.force[:, 1], gw.torque[:, 2]])
    q = np.column_stack([np.interp(t, truth.t, truth.q[:, k]) for k in range(6)])
    zeros = {f: np.zeros((t.size, getattr(truth, f).shape[1])) for f in
             ('qd', 'qdd', 'a', 'u', 'f', 'tau')}
    return truth, replace(truth, t=t, q=q, s=s, point_forces=np.zeros((t.size, 2, 2)),
                          **zeros)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--seeds', default='1,2,3,4')
    ap.add_argument('--duration', type=float, default=60.0, help='seconds of the routine [s]')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help='MovingHorizonSettings overrides (Python literals)')
    ap.add_argument('--without-angle-bias', action='store_true',
                    help="remove the generator's smooth angle bias (skin motion) from the "
                    'observed angles, keeping their noise (to see what the bias causes)')
    ap.add_argument('--faults', action='store_true',
                    help="the routine generator's faults too (marker occlusions, NaN frames, "
                    'force-plate drift, spikes: RoutineObservationSettings(faults=True))')
    ap.add_argument('--json', default=None, help='write the figures here')
    args = ap.parse_args()
    overrides = MovingHorizonSettings.overrides(args.set)
    settings = MovingHorizonSettings().with_(**overrides)
    model = default_model()
    truth, fine = plate_rate_truth(args.bag)
    scored = truth.between(0.0, args.duration)
    rows = []
    for seed in (int(x) for x in args.seeds.split(',')):
        obs, parts = make_routine_observations(
            fine, RoutineObservationSettings(seed=seed, faults=args.faults),
            model.p.body_weight)
        if args.without_angle_bias:
            obs = replace(obs, angles=obs.angles - parts['smooth_angle_bias'])
        sa, sw = obs.t_angles <= args.duration, obs.t_wrench <= args.duration
        run = estimate(model, obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw],
                       obs.wrench[sw], settings)
        ref = phase_scores(model, scored, run.refined.t, run.refined.tau,
                           run.refined.muscles['f'])
        low = phase_scores(model, scored, run.low_latency.t, run.low_latency.tau)
        r = run.refined
        lift = takeoffs(r.t, r.s[:, 1], OBSERVATION_NOISE.force_sd_bw * model.p.body_weight)
        jumps = jump_table(model, scored, r.t, r.q, r.qd, lift)
        row = {'seed': seed, 'restarts': run.restarts,
               'coverage': ref['all']['coverage'],
               'jumps_tracked': jumps['tracked'], 'jumps': len(jumps['jumps']),
               'jump_error_pct': jumps['mean_abs_error_pct'],
               'jump_errors_pct': [j['error_pct'] for j in jumps['jumps']],
               **{ph: [*_torques(ref[ph]),
                       ref[ph].get('muscle_force_rms_pct_f0', {}).get('mean', math.nan)]
                  for ph in PHASES},
               **{f'low_latency {ph}': _torques(low[ph]) for ph in PHASES}}
        rows.append(row)
        print(f"seed {seed}: {run.restarts} re-initialisations, coverage "
              f"{row['coverage']:.3f}; torques ankle/knee/hip % of peak, muscles % F0: " +
              '; '.join(f"{ph} {' / '.join(f'{v:.1f}' for v in row[ph])}" for ph in PHASES) +
              f"; jumps {row['jumps_tracked']} of {row['jumps']} tracked, mean |height error| "
              f"{row['jump_error_pct']:.1f} % (signed: "
              f"{' '.join(f'{e:+.0f}' for e in row['jump_errors_pct'])}); low-latency torques " +
              '; '.join(f"{ph} {' / '.join(f'{v:.1f}' for v in row[f'low_latency {ph}'])}"
                        for ph in PHASES), flush=True)
        for e in run.events:
            if e.level == 'error':
                print(f'  seed {seed}, t = {e.t:.3f} s: {e.message}', flush=True)
    summary = {'settings': overrides, 'seeds': rows}
    for name, fn in (('mean', _nanmean), ('worst', _nanmax)):
        summary[name] = {'restarts': float(fn([r['restarts'] for r in rows])),
                         'jump_error_pct': float(fn([r['jump_error_pct'] for r in rows])),
                         'jump_signed_error_pct': float(fn([np.nanmean(r['jump_errors_pct'])
                                                            for r in rows])),
                         **{ph: np.round(fn([r[ph] for r in rows], axis=0), 2).tolist()
                            for ph in [*PHASES, *(f'low_latency {p}' for p in PHASES)]}}
        print(f"{name}: {summary[name]['restarts']:g} re-initialisations; " +
              '; '.join(f"{ph} {' / '.join(f'{v:.1f}' for v in summary[name][ph])}"
                        for ph in PHASES) +
              f"; mean |jump height error| {summary[name]['jump_error_pct']:.1f} % (signed "
              f"{summary[name]['jump_signed_error_pct']:+.1f} %); low-latency "
              "torques " + '; '.join(
                  f"{ph} {' / '.join(f'{v:.1f}' for v in summary[name][f'low_latency {ph}'])}"
                  for ph in PHASES))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))
    return 0


def _torques(scores: dict) -> list[float]:
    """A phase's torque errors [% peak] (ankle, knee, hip); NaN where the span scored has
    none of that phase (say a short --duration without quiet stance)."""
    torques = scores.get('torque_rms_pct_peak')
    return list(torques.values()) if torques else [math.nan] * 3


def _nanmean(x: object, axis: int | None = None) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)     # a phase no seed had
        return np.nanmean(x, axis=axis)


def _nanmax(x: object, axis: int | None = None) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        return np.nanmax(x, axis=axis)


if __name__ == '__main__':
    raise SystemExit(main())
