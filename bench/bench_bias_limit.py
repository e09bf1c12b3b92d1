"""Study: what limits the NMT jump height (run by hand; about 2 minutes).

The default pipeline (Stage 1 by optimal tracking with muscle-made torques, Stage 2, the NMT
simulation) on observations of the shipped truth built from chosen error components of one
noise realisation: none, noise only, bias only, angle bias only, force bias only, all. Seeds
0 and 1 have a vertical-force bias that pulls down, 2 and 3 one that pushes up. Prints the
Stage-1 and NMT jump errors, and the impulse of each seed's vertical-force bias as a share of
the jump height (what a force-consistent estimate loses to it).

    python bench/bench_bias_limit.py [--seeds 0 1 2 3]
"""
import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from nmt_ros.io.trial_bag import read_truth
from nmt_ros.model.jumper import default_model
from nmt_ros.study.metrics import compute_metrics, jump_from
from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.study.pipeline import NMTSettings, run_nmt

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'
PARTS = {'none': (), 'noise': ('angle_noise', 'wrench_noise'),
         'bias': ('angle_bias', 'wrench_bias'), 'angle bias': ('angle_bias',),
         'force bias': ('wrench_bias',),
         'all': ('angle_noise', 'wrench_noise', 'angle_bias', 'wrench_bias')}


def observations(truth, model, seed: int, parts: tuple[str, ...]):
    obs, comp = make_observations(truth, ObservationSettings(seed=seed),
                                  body_weight=model.p.body_weight)
    angles = truth.q[comp['angle_index'], :4].copy()
    wrench = truth.s[comp['wrench_index']].copy()
    for part in parts:
        (angles if part.startswith('angle') else wrench)[...] += comp[part]
    return dataclasses.replace(obs, angles=angles, wrench=wrench), comp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2, 3])
    args = parser.parse_args()
    model = default_model()
    truth = read_truth(BAG)
    actual = jump_from(model, truth.t, truth.q, truth.qd, truth.liftoff_s)
    v_up = float(model.call(model.com_velocity, truth.q[truth.t <= truth.liftoff_s][-1],
                            truth.qd[truth.t <= truth.liftoff_s][-1])[0][1])
    mass = model.p.body_weight / 9.81
    rows = []
    for seed in args.seeds:
        _, comp = observations(truth, model, seed, ())
        impulse = float(np.sum(comp['wrench_bias'][:, 1]) / 1080.0)          # N s
        # Jump height change of a take-off velocity change impulse / m: v dv / g.
        share = 100 * v_up * (impulse / mass) / 9.81 / actual['jump_height_m']
        print(f'seed {seed}: vertical-force bias impulse {impulse:+.2f} N s '
              f'({share:+.1f} % of the jump height)', flush=True)
        for name, parts in PARTS.items():
            obs, _ = observations(truth, model, seed, parts)
            run = run_nmt(model, obs, NMTSettings(stage1='optimal_muscle'))
            m = compute_metrics(model, run, truth)
            row = {'seed': seed, 'errors': name,
                   'stage1_jump_pct': 100 * (m['skt']['jump_height_m']
                                             / actual['jump_height_m'] - 1),
                   'nmt_jump_pct': 100 * (m['nmt']['jump_height_m']
                                          / actual['jump_height_m'] - 1),
                   'stage1_torque_pct': m['skt']['torque_rms_pct_peak']}
            rows.append(row)
            print(f'  {name:10s} Stage-1 jump {row["stage1_jump_pct"]:+.2f} %, NMT jump '
                  f'{row["nmt_jump_pct"]:+.2f} %', flush=True)
    print(json.dumps(rows, indent=1))


if __name__ == '__main__':
    main()
