"""The moving-horizon estimator (live Stage 1) on a long stream: accuracy by phase against the
truth for each refined lag (the lag/accuracy curve that sets the default ``lag_s``), the
low-latency estimate, restarts, and CPU per update and per second of data.

    python bench/bench_estimator.py [--bag bags/routine] [--duration 20] [--lags 0.025,0.05,0.1]
                                    [--update-rate 120] [--set key=value ...]
                                    [--json out.json] [--busiest 5]

The estimator is fed the recording in time order exactly as the node feeds it (offline =
live). CPU is process time of this process (one core), the estimator's construction (its
compiled kernel made or loaded) left out; on a machine shared with other jobs the per-update
figures rise, the accuracy does not change.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import time

from single_threaded import ROOT  # first: one BLAS thread before numpy loads

# isort: split
import numpy as np

from nmt_ros.io.trial_bag import read_observations, read_truth
from nmt_ros.model.jumper import default_model
from nmt_ros.study.phase_scores import format_phase_scores, phase_scores
from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator, estimate
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--duration', type=float, default=20.0, help='seconds of the bag [s]')
    ap.add_argument('--lags', default='0.025,0.05,0.1', help='refined lags to run [s]')
    ap.add_argument('--update-rate', type=float, default=None, help='updates per second')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help='MovingHorizonSettings overrides (Python literals)')
    ap.add_argument('--json', default=None, help='write the figures here')
    ap.add_argument('--busiest', type=int, default=5,
                    help='list this many seconds of data with the most estimator CPU')
    args = ap.parse_args()
    overrides = MovingHorizonSettings.overrides(args.set)
    model = default_model()
    truth, obs = read_truth(args.bag), read_observations(args.bag)
    sa, sw = obs.t_angles <= args.duration, obs.t_wrench <= args.duration
    results = {}
    for lag in (float(x) for x in args.lags.split(',')):
        st = MovingHorizonSettings().with_(**overrides)
        st = st.with_(lag_s=lag, window_s=max(st.window_s, lag + 0.05))
        if args.update_rate:
            st = st.with_(update_rate_hz=args.update_rate)
        # the estimator built once untimed: its kernel and functions are made (or loaded)
        # once per process, 4.5-5.3 s here, which a node spends before its inputs open; the
        # timed run then counts the stream's work only (until 2026-12-07 it counted that
        # too: +0.08 s per s of a 60 s run)
        MovingHorizonEstimator(model, st)
        c0 = time.process_time()
        run = estimate(model, obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw],
                       obs.wrench[sw], st)
        cpu = time.process_time() - c0
        span = float(obs.t_wrench[sw][-1] - obs.t_wrench[sw][0])
        ref = phase_scores(model, truth, run.refined.t, run.refined.tau,
                           run.refined.muscles['f'])
        low = phase_scores(model, truth, run.low_latency.t, run.low_latency.tau,
                           run.low_latency.muscles['f'])
        upd = run.update_cpu_s * 1e3
        results[lag] = {'refined': ref, 'low_latency': low, 'restarts': run.restarts,
                        'cpu_s_per_s': cpu / span, 'update_ms_p50': float(np.median(upd)),
                        'update_ms_p99': float(np.percentile(upd, 99)),
                        'updates': int(upd.size), 'settings': {
                            'lag_s': st.lag_s, 'window_s': st.window_s,
                            'update_rate_hz': st.update_rate_hz}}
        print(f'== lag {lag * 1e3:.0f} ms (window {st.window_s * 1e3:.0f} ms, '
              f'{st.update_rate_hz:g} updates/s): {span:.1f} s of data, restarts '
              f'{run.restarts}, CPU {cpu / span:.2f} s per s, update p50 '
              f'{np.median(upd):.2f} ms p99 {np.percentile(upd, 99):.2f} ms', flush=True)
        # CPU per second of data: a live node falls behind in the seconds above one core's
        # share and works the backlog off after (re-initialisations, rescue iterations)
        second = np.floor(run.update_t_s).astype(int)
        per_s = np.bincount(second - second.min(), weights=run.update_cpu_s) * 1e3
        busiest = np.argsort(per_s)[::-1][:args.busiest]
        results[lag]['cpu_ms_per_s_of_data'] = {'p50': float(np.median(per_s)),
                                                'max': float(per_s.max())}
        print(f'CPU per second of data: p50 {np.median(per_s):.0f} ms, busiest '
              + ', '.join(f'{second.min() + k}-{second.min() + k + 1} s {per_s[k]:.0f} ms'
                          for k in sorted(busiest)))
        print('refined')
        print(format_phase_scores(ref))
        print('low latency')
        print(format_phase_scores(low), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
