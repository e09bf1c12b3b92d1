"""Benchmark: Stage 1 (skeletal motion tracker) CPU on the reference jump (run by hand).

Prints the CPU time of conditioning + tracking for the shipped trial, its ratio to the trial's
duration (< 1: faster than real time), exact vs numerical Jacobians, RK4 substeps 2 vs 4, and a
profile of where the time goes. The paper: 28 s of CPU for Stage 1.

Then Stage 1 by optimal tracking (offline, beyond the paper), free and muscle-made torques:
the one-off NLP build per trial length, the solve, IPOPT iterations and where the solve's CPU
goes (CasADi's Hessian and Jacobian evaluations vs the rest, mostly MUMPS).
"""
import cProfile
import json
from pathlib import Path
import pstats
import time

from nmt_ros.io.trial_bag import read_observations
from nmt_ros.model.jumper import default_model
from nmt_ros.tracking.conditioning import condition
from nmt_ros.tracking.optimal_tracker import (
    OptimalTrackingSettings,
    collocation_grid,
    track_optimal,
    tracking_nlp,
)
from nmt_ros.tracking.skeletal_tracker import SKTSettings
from nmt_ros.tracking.streaming import track_stage1

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'


def timed(model, obs, settings, repeat=5):
    best = float('inf')
    for _ in range(repeat):
        c = time.process_time()
        cond = condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
        res = track_stage1(model, cond, settings)
        best = min(best, time.process_time() - c)
    return best, res


def main() -> None:
    model = default_model()
    obs = read_observations(BAG)
    duration = float(obs.t_wrench[-1])
    out = {'trial_duration_s': duration}
    for name, st in (('exact_2_substeps', SKTSettings()),
                     ('numerical_2_substeps', SKTSettings(jacobians='numerical')),
                     ('exact_4_substeps', SKTSettings(substeps=4))):
        cpu, res = timed(model, obs, st)
        out[name] = {'cpu_s': cpu, 'real_time_ratio': cpu / duration, 'status': res.status}
    print(json.dumps(out, indent=1))
    print(json.dumps(optimal(model, obs, duration), indent=1))
    prof = cProfile.Profile()
    prof.enable()
    track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    prof.disable()
    pstats.Stats(prof).sort_stats('cumulative').print_stats(12)


def optimal(model, obs, duration: float) -> dict:
    """Build and solve times of optimal tracking (torque and muscle actuation)."""
    guess = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    n, h, idx, keep = collocation_grid(obs)
    out = {}
    for actuation in ('torque', 'muscle'):
        st = OptimalTrackingSettings(actuation=actuation)
        c = time.process_time()
        solver = tracking_nlp(model, n, h, idx[keep], st).solver
        build = time.process_time() - c
        res = track_optimal(model, obs, guess, st)
        stats = solver.stats()
        out[actuation] = {
            'build_cpu_s': build, 'solve_cpu_s': res.cpu_s,
            'solve_real_time_ratio': res.cpu_s / duration, 'iterations': stats['iter_count'],
            'status': res.status,
            'casadi_cpu_s': {k[len('t_proc_nlp_'):]: v for k, v in stats.items()
                             if k.startswith('t_proc_nlp_')}}
    return {'optimal_tracking': out}


if __name__ == '__main__':
    main()
