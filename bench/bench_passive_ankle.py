"""The estimate's joint angles and the model's passive joint torques there, against the truth,
over an interval of a synthetic bag (run by hand): how much of the dynamics' joint torque the
passive torques carry where the estimate errs (the take-off failure in README "Known
limitations").

    python bench/bench_passive_ankle.py [--bag bags/routine] [--from 40.75] [--to 41.1]

The moving-horizon estimator runs offline (= live) from the bag's start to ``--to``; every
25 ms in the interval it prints the refined estimate's joint angles (ankle, knee, hip; deg),
the passive torques at the estimate and at the truth, and the refined (muscles') joint torques
against the truth's [N m].
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nmt_ros.io.trial_bag import read_observations, read_truth  # noqa: E402
from nmt_ros.model.jumper import default_model  # noqa: E402
from nmt_ros.tracking.moving_horizon.estimator import estimate  # noqa: E402
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings  # noqa: E402


def at(t: float, ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values [n, k] at instant t [s] (linear interpolation)."""
    return np.array([np.interp(t, ts, values[:, j]) for j in range(values.shape[1])])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--from', dest='t0', type=float, default=40.75, help='[s]')
    ap.add_argument('--to', dest='t1', type=float, default=41.1, help='[s]')
    args = ap.parse_args()
    model = default_model()
    obs = read_observations(args.bag)
    truth = read_truth(args.bag)
    sa, sw = obs.t_angles <= args.t1 + 0.1, obs.t_wrench <= args.t1 + 0.1
    run = estimate(model, obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw], obs.wrench[sw],
                   MovingHorizonSettings())
    r = run.refined
    print(f'{"t [s]":>7s} | joint angles est / truth [deg] | passive torques est / truth '
          '[N m] | muscle torques est / truth [N m]  (ankle, knee, hip)')
    for t in np.arange(args.t0, args.t1 + 1e-9, 0.025):
        q, qd = at(t, r.t, r.q), at(t, r.t, r.qd)
        qt, qdt = at(t, truth.t, truth.q), at(t, truth.t, truth.qd)
        th, tht = (np.degrees(np.ravel(model.call(model.joint_angles, x)[0])) for x in (q, qt))
        pas, pas_t = (np.ravel(model.call(model.passive_torques, x, v)[0])
                      for x, v in ((q, qd), (qt, qdt)))

        def fmt(a: np.ndarray, b: np.ndarray) -> str:
            return ' '.join(f'{x:6.0f}' for x in a) + ' /' + ' '.join(f'{x:6.0f}' for x in b)

        print(f'{t:7.3f} | {fmt(th, tht)} | {fmt(pas, pas_t)} | '
              f'{fmt(at(t, r.t, r.tau), at(t, truth.t, truth.tau))}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
