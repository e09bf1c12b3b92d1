"""``nmt reference --out DIR``: the reference jump by parameter optimisation, and its bag.

Writes ``DIR/reference_jump/``: the rosbag2 bag (observations + truth), ``reference.json``
(optimisation record and checks), ``truth.sto``/``truth_grf.mot``/``truth_grf.xml`` (the truth
as OpenSim files) and ``reference_jump.png``.
"""
from __future__ import annotations

import argparse
from dataclasses import asdict
import json
from pathlib import Path
import shutil
import sys
import time

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', required=True, type=Path, help='output directory')
    parser.add_argument('--name', default='reference_jump', help='bag folder name')
    parser.add_argument('--quick', action='store_true',
                        help='coarse meshes and 2 starts (tests); not the shipped truth')
    parser.add_argument('--starts', type=int, default=None, help='multi-start count (5)')
    parser.add_argument('--seed', type=int, default=0, help='noise and multi-start seed')
    parser.add_argument('--noise-scale', type=float, default=1.0,
                        help="multiplies the paper's noise SDs and biases")
    parser.add_argument('--force', action='store_true', help='replace an existing output')


def _say(msg: str) -> None:
    print(f'[nmt reference] {msg}', flush=True)


def run(args: argparse.Namespace) -> int:
    from nmt_ros.io.trial_bag import write_trial_bag
    from nmt_ros.model.jumper import default_model
    from nmt_ros.records import truth_from_simulation
    from nmt_ros.study.figures import plot_reference_jump
    from nmt_ros.study.observations import ObservationSettings, make_observations
    from nmt_ros.study.opensim_results import write_opensim_truth
    from nmt_ros.study.reference import POSettings, make_reference

    folder = args.out / args.name
    if folder.exists():
        if not args.force:
            print(f'error: {folder} exists (use --force to replace it)', file=sys.stderr)
            return 2
        shutil.rmtree(folder)
    model = default_model()
    settings = POSettings(n_intervals=50) if args.quick else POSettings()
    coarse = 25 if args.quick else 50
    starts = args.starts if args.starts is not None else (2 if args.quick else 5)
    t0 = time.perf_counter()
    ref = make_reference(model, settings, starts=starts, coarse_intervals=coarse,
                         seed=args.seed, progress=_say)
    sim = ref.simulation
    truth = truth_from_simulation(model, sim.t, sim.x, sim.u, sim.x0, sim.liftoff_s)
    obs_settings = ObservationSettings(seed=args.seed, noise_scale=args.noise_scale)
    obs, comp = make_observations(truth, obs_settings, body_weight=model.p.body_weight)
    record = {
        'po': {'cpu_s': ref.cpu_s, 'wall_s': ref.wall_s,
               'iterations': int(sum(r.iterations for r in ref.starts) + ref.po.iterations),
               'iterations_refined': ref.po.iterations,
               'iterations_per_start': [r.iterations for r in ref.starts],
               'status_per_start': [r.status for r in ref.starts],
               'converged': bool(ref.po.success), 'settings': asdict(settings),
               'coarse_intervals': coarse, 'tf_s': ref.po.tf,
               'excitation_nodes': ref.po.excitation_nodes.tolist(),
               'jump_height_m': ref.checks['jump_height_m']},
        'actual': {'jump_height_m': ref.checks['jump_height_m'],
                   'rise_from_squat_m': ref.checks['rise_from_squat_m'],
                   'liftoff_s': truth.liftoff_s,
                   'peak_vertical_force_bw': float(truth.s[:, 1].max() / model.p.body_weight)},
        'squat': {'q': ref.po.squat.q.tolist(), 'anchors_m': ref.po.squat.x0.tolist(),
                  'activations': ref.po.squat.a.tolist(), 'tau_nm': ref.po.squat.tau.tolist()},
        'checks': ref.checks,
        'observations': obs.info,
        'quick': bool(args.quick),
    }
    _say(f'jump height {ref.checks["jump_height_m"] * 100:.2f} cm above standing '
         f'({ref.checks["rise_from_squat_m"] * 100:.2f} cm above the squat), lift-off '
         f'{truth.liftoff_s * 1000:.1f} ms, peak vertical force '
         f'{record["actual"]["peak_vertical_force_bw"]:.2f} BW')
    _say(f'PO: {record["po"]["iterations"]} iterations, CPU {ref.cpu_s:.1f} s, wall '
         f'{ref.wall_s:.1f} s, {ref.checks["starts_converged"]}/{starts} starts converged '
         f'(apex spread {ref.checks["start_apex_spread_m"] * 1000:.3f} mm), mesh refinement '
         f'changed the apex by {ref.checks["mesh_refinement_apex_change_m"] * 1000:.3f} mm')
    info = write_trial_bag(folder, obs, truth, comp, custom_data={
        'nmt.jump_height_m': repr(ref.checks['jump_height_m']),
        'nmt.observation_settings': json.dumps(asdict(obs_settings))})
    (folder / 'reference.json').write_text(json.dumps(record, indent=1, default=_json))
    write_opensim_truth(folder, model, truth)
    plot_reference_jump(truth, obs, folder / 'reference_jump.png',
                        body_weight=model.p.body_weight)
    _say(f'wrote {folder} ({info.message_count} messages, '
         f'{time.perf_counter() - t0:.1f} s in all)')
    return 0


def _json(x: object) -> object:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f'not JSON serialisable: {type(x)}')
