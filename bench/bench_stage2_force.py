"""Stage 2's force term k_f: muscle forces against the truth on a long stream, by phase.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_stage2_force.py [--duration 10]
        [--k-f 0,1e4,1e5,1e6,1e7]

(run by hand; about a minute per k_f value on this 2-core machine). Stage 1 is the live
moving-horizon estimator fed the first ``--duration`` s of ``bags/routine`` (its refined
estimate, as the muscle tracker node receives it); Stage 2 is the batch = live stream
(``tracking.streaming.track_stage2``, 100 ms receding windows) with ``k_f`` overridden, the
rest of ``tracking/data/stage2.yaml`` as shipped. Printed per k_f: the muscle forces' RMS
against the truth by phase (``study.phase_scores``; % F0, mean and max over the nine muscles),
how well the muscles' torques C f follow Stage 2's reference (RMS, % of each joint's peak: the
force term must act on co-contraction only, not on the tracked torques) and Stage 2's CPU
time.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import time

import numpy as np

from nmt_ros.io.trial_bag import read_observations, read_truth
from nmt_ros.model.jumper import default_model
from nmt_ros.study.phase_scores import format_phase_scores, phase_scores
from nmt_ros.tracking.moving_horizon.estimator import estimate
from nmt_ros.tracking.stage2 import NeuromuscularTracker, load_stage2_settings
from nmt_ros.tracking.streaming import track_stage2

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--duration', type=float, default=10.0, help='seconds of the bag [s]')
    ap.add_argument('--k-f', default='0,1e4,1e5,1e6,1e7', help='force-term weights to run')
    args = ap.parse_args()
    model = default_model()
    truth, obs = read_truth(args.bag), read_observations(args.bag)
    sa, sw = obs.t_angles <= args.duration, obs.t_wrench <= args.duration
    c = time.process_time()
    run = estimate(model, obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw], obs.wrench[sw])
    ref = run.refined
    print(f'Stage 1 (moving horizon, refined): {args.duration:g} s in '
          f'{time.process_time() - c:.1f} s CPU; its own muscle forces:')
    print(format_phase_scores(phase_scores(model, truth, ref.t, ref.tau, ref.muscles['f'])))
    theta, = model.batch(model.joint_angles, ref.q)
    theta_dot, = model.batch(model.joint_angles, ref.qd)
    for k_f in (float(x) for x in args.k_f.split(',')):
        tracker = NeuromuscularTracker(model, load_stage2_settings(k_f=k_f))
        c = time.process_time()
        s2 = track_stage2(model, ref.t, ref.tau, theta, theta_dot, tracker, 0.1,
                          rate_hz=1080.0)
        cpu = time.process_time() - c
        err = s2.tau_muscle - s2.tau_ref
        peak = np.abs(s2.tau_ref).max(axis=0)
        follow = 100 * np.sqrt(np.mean(err ** 2, axis=0)) / peak
        print(f'== k_f {k_f:g}: Stage 2 {cpu:.1f} s CPU; C f vs its reference RMS '
              f'{" / ".join(f"{x:.2f}" for x in follow)} % of peak (ankle / knee / hip)')
        print(format_phase_scores(phase_scores(model, truth, s2.t, None, s2.f)), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
