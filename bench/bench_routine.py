"""Benchmark: routine generation (run by hand: python bench/bench_routine.py [--quick]).

Simulates the shipped routine (60 s: a drop jump, then four countermovement jumps between
quiet stances; seed 0) as ``nmt routine`` does, or the ``--quick`` one of the tests, and prints
the CPU time by part (collocation plans, forward simulation, feedback design) with the jump
heights. Target: 60 s of routine in under 10 minutes of CPU on the 2-core machine; --quick
under 1 minute. CPU time (process_time) is what is compared: wall time depends on the load.
"""
import json
import sys
import time

from nmt_ros.model.jumper import default_model
from nmt_ros.study.routine import RoutineSettings, make_routine


def main() -> None:
    quick = '--quick' in sys.argv
    settings = (RoutineSettings(duration_s=8.0, jumps=1, drop=False, first_stance_s=2.0,
                                min_stance_s=1.5, quick=True, seed=3) if quick
                else RoutineSettings())
    model = default_model()
    c0, w0 = time.process_time(), time.perf_counter()
    routine = make_routine(model, settings)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    print(json.dumps({
        'routine_s': settings.duration_s, 'cpu_s': cpu, 'wall_s': wall,
        'cpu_by_part_s': routine.cpu_s,
        'cycles': [{k: c.as_dict()[k] for k in ('kind', 'target_height_m',
                                                 'achieved_height_m', 'plan_iterations',
                                                 'plan_cpu_s', 'replans')}
                   for c in routine.cycles],
        'target_cpu_s': 60.0 if quick else 600.0}, indent=1))


if __name__ == '__main__':
    main()
