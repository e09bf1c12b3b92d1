"""Fault patterns the routine generator does not make, each applied to one noise realisation
of a routine and tracked offline (= live) by the moving-horizon estimator; the refined
torques against the truth over the whole routine, the landings and the flights, with the
re-initialisations and the coverage of the force-plate instants that exist.

    python bench/bench_unseen_faults.py [--bag bags/routine] [--seeds 1] [--duration 60]
                                        [--faults none,plate_gap,...] [--set K=V ...]
                                        [--json F] [--write-bag DIR]

The patterns (random times from the seed + 100, per minute of data):

    none            the realisation as generated
    plate_gap       6 bursts of 20-150 ms of force-plate messages absent (not NaN)
    mocap_gap       6 bursts of 50-300 ms of mocap frames absent
    all_occluded    6 stretches of 100-300 ms with every segment NaN
    long_occlusion  3 stretches of 1 s with one segment NaN
    stuck           6 stretches of 200-500 ms with one segment repeating its last value
    plate_step      Fy steps of +-5 % BW at three instants (a plate re-zeroed)
    hum             50 Hz mains hum, 1 % BW on the forces (x 0.17 m on the moment)
    gain            every plate channel 5 % high
    fx_offset       a constant fore-aft force offset of 3 % BW
    foot_offset / thigh_offset / hat_offset   marker misplacement: +5 / -3 / +4 deg throughout
    angle_drift     every angle drifting linearly to +3 deg over the minute
    jitter          mocap stamps jittered uniformly by +-2 ms (still in order)
    plate_jitter    force-plate stamps jittered uniformly by +-0.2 ms (still in order; the
                    estimates are stamped with them)
    mocap_late      every mocap stamp 10 ms late against the plate's (a fixed camera latency
                    stamped on arrival)
    clip            the plate saturating at 2.2 BW

About 20 s of CPU per pattern and minute of data (2-core machine).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from single_threaded import ROOT  # first: one BLAS thread before numpy loads

# isort: split
from bench_estimator_seeds import plate_rate_truth
import numpy as np

from nmt_ros.model.jumper import default_model
from nmt_ros.study.phase_scores import phase_scores
from nmt_ros.study.routine_observations import (
    RoutineObservationSettings,
    make_routine_observations,
)
from nmt_ros.tracking.moving_horizon.estimator import estimate
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

PATTERNS = ('none', 'plate_gap', 'mocap_gap', 'all_occluded', 'long_occlusion', 'stuck',
            'plate_step', 'hum', 'gain', 'fx_offset', 'foot_offset', 'thigh_offset',
            'hat_offset', 'angle_drift', 'jitter', 'plate_jitter', 'mocap_late',
            'clip')


def apply_fault(name: str, ta: np.ndarray, angles: np.ndarray, tw: np.ndarray,
                wrench: np.ndarray, body_weight: float, rng: np.random.Generator,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t_angles [s], angles [rad], t_wrench [s], wrench [N, N, N m]) with the pattern
    ``name`` applied (module docstring); the inputs are not changed."""
    ta, a, tw, w = ta.copy(), angles.copy(), tw.copy(), wrench.copy()
    end = min(float(ta[-1]), float(tw[-1]))

    def span(t: np.ndarray, start: float, length: float) -> np.ndarray:
        return (t >= start) & (t < start + length)

    def starts(n: int, margin: float = 1.0) -> np.ndarray:
        return rng.uniform(1.0, end - margin, round(n * end / 60.0))

    lever = np.array([1.0, 1.0, 0.17])
    if name == 'none':
        pass
    elif name == 'plate_gap':
        keep = np.ones(tw.size, bool)
        for s in starts(6):
            keep &= ~span(tw, s, rng.uniform(0.02, 0.15))
        tw, w = tw[keep], w[keep]
    elif name == 'mocap_gap':
        keep = np.ones(ta.size, bool)
        for s in starts(6):
            keep &= ~span(ta, s, rng.uniform(0.05, 0.3))
        ta, a = ta[keep], a[keep]
    elif name == 'all_occluded':
        for s in starts(6):
            a[span(ta, s, rng.uniform(0.1, 0.3))] = np.nan
    elif name == 'long_occlusion':
        for s in starts(3, 2.0):
            a[span(ta, s, 1.0), rng.integers(4)] = np.nan
    elif name == 'stuck':
        for s in starts(6):
            sel = np.flatnonzero(span(ta, s, rng.uniform(0.2, 0.5)))
            j = rng.integers(4)
            a[sel, j] = a[sel[0] - 1, j]
    elif name == 'plate_step':
        for s in rng.uniform(2.0, end - 2.0, 3):
            w[tw >= s, 1] += rng.choice([-1.0, 1.0]) * 0.05 * body_weight
    elif name == 'hum':
        w += 0.01 * body_weight * np.sin(2 * np.pi * 50.0 * tw)[:, None] * lever
    elif name == 'gain':
        w *= 1.05
    elif name == 'fx_offset':
        w[:, 0] += 0.03 * body_weight
    elif name in ('foot_offset', 'thigh_offset', 'hat_offset'):
        j, deg = {'foot_offset': (0, 5.0), 'thigh_offset': (2, -3.0),
                  'hat_offset': (3, 4.0)}[name]
        a[:, j] += np.radians(deg)
    elif name == 'angle_drift':
        a += np.radians(3.0) * (ta / 60.0)[:, None]
    elif name == 'jitter':
        ta = ta + rng.uniform(-0.002, 0.002, ta.size)
    elif name == 'plate_jitter':
        tw = tw + rng.uniform(-0.0002, 0.0002, tw.size)
    elif name == 'mocap_late':
        ta = ta + 0.010
    elif name == 'clip':
        w[:, 1] = np.minimum(w[:, 1], 2.2 * body_weight)
    else:
        raise ValueError(f'unknown fault pattern {name!r} (known: {", ".join(PATTERNS)})')
    return ta, a, tw, w


def write_bag(args: argparse.Namespace, fine: object, bw: float, seed: int) -> int:
    """The ``--write-bag`` job (see its help)."""
    from dataclasses import replace

    from nmt_ros.io.trial_bag import write_trial_bag

    obs, _ = make_routine_observations(fine, RoutineObservationSettings(seed=seed), bw)
    sa, sw = obs.t_angles <= args.duration, obs.t_wrench <= args.duration
    ta, a, tw, w = obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw], obs.wrench[sw]
    rng = np.random.default_rng(100 + seed)
    for name in args.faults.split(','):
        ta, a, tw, w = apply_fault(name, ta, a, tw, w, bw, rng)
    info = write_trial_bag(args.write_bag, replace(obs, t_angles=ta, angles=a, t_wrench=tw,
                                                   wrench=w, t_ankle=None, ankle=None))
    print(f'{args.write_bag}: {info.message_count} messages, {args.faults} on realisation '
          f'{seed}, {args.duration:g} s')
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--seeds', default='1',
                    help='noise realisations, comma-separated (faults: seed + 100); with '
                    'more than one, each pattern also gets the mean over them (restarts: sum)')
    ap.add_argument('--duration', type=float, default=60.0, help='seconds of the routine [s]')
    ap.add_argument('--faults', default=','.join(PATTERNS))
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help='MovingHorizonSettings overrides (Python literals), e.g. '
                    'frame_clock_alpha=0 saturation_min_bw=0: without the repairs')
    ap.add_argument('--json', default=None, help='write the figures here')
    ap.add_argument('--write-bag', default=None, metavar='DIR',
                    help='instead of tracking: every pattern of --faults applied in turn to '
                    "the first seed's realisation, written as an observation bag (no truth) "
                    'for the live graph (nmt demo --bag DIR)')
    args = ap.parse_args()
    settings = MovingHorizonSettings().with_(**MovingHorizonSettings.overrides(args.set))
    seeds = [int(x) for x in args.seeds.split(',')]
    model = default_model()
    bw = model.p.body_weight
    truth, fine = plate_rate_truth(args.bag)
    scored = truth.between(0.0, args.duration)
    if args.write_bag:
        return write_bag(args, fine, bw, seeds[0])
    rows = []
    print('fault            seed restarts  coverage  torques % of peak (ankle / knee / hip): '
          'all; landing; flight')

    def show(row: dict, seed: str) -> None:
        print(f"{row['fault']:16s} {seed:>4s} {row['restarts']:8d}  "
              f"{row['coverage_of_plate_instants']:8.4f}  "
              + '; '.join(' / '.join(f'{v:.2f}' for v in row[ph])
                          for ph in ('all', 'landing', 'flight')), flush=True)

    for name in args.faults.split(','):
        mine = []
        for seed in seeds:
            obs, _ = make_routine_observations(fine, RoutineObservationSettings(seed=seed), bw)
            sa, sw = obs.t_angles <= args.duration, obs.t_wrench <= args.duration
            rng = np.random.default_rng(100 + seed)
            ta, a, tw, w = apply_fault(name, obs.t_angles[sa], obs.angles[sa],
                                       obs.t_wrench[sw], obs.wrench[sw], bw, rng)
            run = estimate(model, ta, a, tw, w, settings)
            t_est = run.refined.t
            orig = obs.t_wrench[sw]
            if tw.size == orig.size and not np.array_equal(tw, orig):
                # stamps moved (plate_jitter): each estimate belongs to its sample's true
                # instant, where the truth is
                t_est = orig[np.searchsorted(tw, t_est)]
            s = phase_scores(model, scored, t_est, run.refined.tau)
            row = {'fault': name, 'seed': seed, 'restarts': run.restarts,
                   'coverage_of_plate_instants': float(np.isin(tw, run.refined.t).mean()),
                   **{ph: [round(v, 2) for v in s[ph]['torque_rms_pct_peak'].values()]
                      for ph in ('all', 'landing', 'flight')}}
            mine.append(row)
            show(row, str(seed))
        rows += mine
        if len(mine) > 1:
            mean = {'fault': name, 'seed': 'mean',
                    'restarts': int(sum(r['restarts'] for r in mine)),
                    'coverage_of_plate_instants': float(np.mean(
                        [r['coverage_of_plate_instants'] for r in mine])),
                    **{ph: [round(float(v), 2) for v in np.mean([r[ph] for r in mine], 0)]
                       for ph in ('all', 'landing', 'flight')}}
            rows.append(mean)
            show(mean, 'mean')
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
