"""``nmt routine --out DIR``: a long synthetic routine (quiet stance, drop and countermovement
jumps, flights, landings) as an observation bag with its truth.

Writes ``DIR/<name>/`` (``routine``, or ``routine_faults`` with ``--faults``): the rosbag2 bag
(observations, every ``/truth/*`` and bias topic of a trial bag, the contact anchors, and with
faults the fault components), the OpenSim truth files (``truth.sto``, ``truth_states.sto``,
``truth_grf.mot``, ``truth_grf.xml``), ``routine.png`` and the routine's facts in
``metadata.yaml`` ``custom_data`` (``nmt.routine.*``). ``--both`` writes the clean and the
faulty bag from one simulation (the shipped pair).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import json
from pathlib import Path
import shutil
import sys
import time


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', required=True, type=Path, help='output directory')
    parser.add_argument('--name', default=None,
                        help='bag folder name (routine, or routine_faults with --faults)')
    parser.add_argument('--seed', type=int, default=0, help='routine, noise and fault seed')
    parser.add_argument('--duration', type=float, default=None,
                        help='seconds (60; --quick: 8)')
    parser.add_argument('--jumps', type=int, default=None,
                        help='jump cycles, the first a drop jump (5; --quick: 1)')
    parser.add_argument('--no-drop', action='store_true',
                        help='countermovement jumps only (start in quiet stance)')
    parser.add_argument('--faults', action='store_true',
                        help='occlusions, NaN samples, force-plate drift and spikes')
    parser.add_argument('--both', action='store_true',
                        help='write routine/ and its faulty twin routine_faults/ (same truth, '
                             'not repeated there) from one simulation')
    parser.add_argument('--truth-rate', type=float, default=1080.0, choices=(1080.0, 120.0),
                        help='rate of the kinematic and muscle truth topics (Hz)')
    parser.add_argument('--no-opensim', action='store_true',
                        help='leave out the OpenSim truth files (large for long routines)')
    parser.add_argument('--quick', action='store_true',
                        help='short, one jump, coarse plans (tests); not the shipped truth')
    parser.add_argument('--force', action='store_true', help='replace existing output')


def _say(msg: str) -> None:
    print(f'[nmt routine] {msg}', flush=True)


def settings_from_args(args: argparse.Namespace) -> object:
    """The RoutineSettings the arguments ask for."""
    from nmt_ros.study.routine import RoutineSettings

    if args.quick:
        s = RoutineSettings(duration_s=8.0, jumps=1, drop=False, first_stance_s=2.0,
                            min_stance_s=1.5, quick=True, seed=args.seed)
    else:
        s = RoutineSettings(seed=args.seed)
    if args.duration is not None:
        s = replace(s, duration_s=float(args.duration))
    if args.jumps is not None:
        s = replace(s, jumps=int(args.jumps))
    if args.no_drop:
        s = replace(s, drop=False)
    return s


def run(args: argparse.Namespace) -> int:
    from nmt_ros.model.jumper import default_model
    from nmt_ros.study.routine import make_routine
    from nmt_ros.study.routine_output import write_routine_folder

    names = (['routine', 'routine_faults'] if args.both
             else [args.name or ('routine_faults' if args.faults else 'routine')])
    folders = [args.out / n for n in names]
    for folder in folders:
        if folder.exists():
            if not args.force:
                print(f'error: {folder} exists (use --force to replace it)', file=sys.stderr)
                return 2
    settings = settings_from_args(args)
    model = default_model()
    c0, w0 = time.process_time(), time.perf_counter()
    try:
        routine = make_routine(model, settings, progress=_say)
    except (RuntimeError, ValueError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    sim_cpu = time.process_time() - c0
    for folder, faults in zip(folders, [False, True] if args.both else [args.faults]):
        if folder.exists():
            shutil.rmtree(folder)
        twin = args.both and faults
        facts = write_routine_folder(folder, model, routine, faults=faults,
                                     generation_cpu_s=sim_cpu, truth_rate_hz=args.truth_rate,
                                     opensim=not (args.no_opensim or twin),
                                     with_truth=not twin)
        _say(f'wrote {folder} ({facts["messages"]} messages, '
             f'{facts["bag_bytes"] / 1e6:.2f} MB)')
    for c in routine.cycles:
        _say(f'{c.kind} at {c.start_s:.2f} s: target {100 * c.target_height_m:.2f} cm, '
             f'achieved {100 * c.achieved_height_m:.2f} cm')
    parts = json.dumps({k: round(v, 1) for k, v in routine.cpu_s.items()})
    _say(f'simulation CPU {sim_cpu:.1f} s ({parts}), wall {time.perf_counter() - w0:.1f} s '
         'in all')
    return 0
