"""Benchmark: the collocation transcription (run by hand: python bench/bench_collocation.py).

Prints, for the muscle-driven optimal-tracking NLP of the shipped jump (1080 Hz, one interval
per force sample): the build CPU for windows of several lengths; the resident memory while
solvers of 12 distinct lengths (200-211 intervals) go through the bounded cache (it grows by
one solver's memory per entry until the cache is full, then levels off); a solve from the
skeletal tracker's guess (cold) against one warm-started from a previous solution, on data
of the same shape changed at its end (a window one step later) or everywhere (another noise
seed); and the PO's build CPU (N = 50, 100).
"""
import gc
import json
from pathlib import Path
import time

import numpy as np

from nmt_ros.model.jumper import default_model
from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.study.reference import JumpOptimizer, POSettings
from nmt_ros.tracking import collocation
from nmt_ros.tracking.conditioning import condition
from nmt_ros.tracking.optimal_tracker import (
    OptimalTrackingSettings,
    _muscle_guess,
    _on_grid,
    collocation_grid,
    fit_window,
    tracking_nlp,
)
from nmt_ros.tracking.skeletal_tracker import track

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'
MUSCLE = OptimalTrackingSettings(actuation='muscle')


def rss_mb() -> float:
    """Resident memory of this process [MB]."""
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1024
    raise RuntimeError('no VmRSS in /proc/self/status')


def builds(model) -> list[dict]:
    """Build CPU of one solver per window length."""
    out = []
    for n in (30, 60, 120, 269):
        collocation.solvers.clear()
        c = time.process_time()
        tracking_nlp(model, n, 1 / 1080, np.arange(0, n + 1, 9), MUSCLE)
        out.append({'intervals': n, 'build_cpu_s': round(time.process_time() - c, 3)})
    collocation.solvers.clear()
    return out


def bounded(model, lengths: range) -> list[float]:
    """Resident memory [MB] after each distinct window length went through the cache."""
    collocation.solvers.clear()
    gc.collect()
    trace = []
    for n in lengths:
        tracking_nlp(model, n, 1 / 1080, np.arange(0, n + 1, 9), MUSCLE)
        gc.collect()
        trace.append(round(rss_mb(), 1))
    return trace


def warm_start(model) -> dict:
    """The tracking NLP of the jump's fit window, solved for noise seed 1, then for changed
    data of the same shape: the last 5 force samples and the last angle sample from seed 2
    (what a window one step later brings) and all of seed 2. Each from the skeletal
    tracker's guess (cold, as ``track_optimal``) and from seed 1's solution and multipliers
    with ``WARM_START_IPOPT`` (warm)."""
    truth = read_truth(BAG)
    obs = {s: make_observations(truth, ObservationSettings(seed=s),
                                body_weight=model.p.body_weight)[0] for s in (1, 2)}
    guess = track(model, condition(obs[1].t_angles, obs[1].angles, obs[1].t_wrench,
                                   obs[1].wrench))
    t_end = float(guess.liftoff_s) + MUSCLE.flight_s
    w1, w2 = fit_window(obs[1], t_end), fit_window(obs[2], t_end)
    n, h, idx, keep = collocation_grid(w1)
    nlp = tracking_nlp(model, n, h, idx[keep], MUSCLE)
    tr = nlp.transcription
    lbx, ubx = tr.bounds({'a': 0.0, 'u': 0.0}, {'a': 1.0, 'u': 1.0})
    x0 = np.asarray(guess.x0)
    a, u = _muscle_guess(model, guess)
    z_guess = tr.pack({'q': _on_grid(guess.q, n), 'qd': _on_grid(guess.qd, n),
                       'qdd': _on_grid(guess.qdd, n), 'a': _on_grid(a, n), 'u': _on_grid(u, n)})

    def params(wrench: np.ndarray, angles: np.ndarray) -> np.ndarray:
        return tr.pack_parameters({'wrench': wrench, 'angles': angles, 'x0': x0})

    seed1 = tr.solve(nlp.solver, z_guess, params(w1.wrench[:n + 1], w1.angles[keep]), lbx, ubx)
    step_w, step_a = w1.wrench[:n + 1].copy(), w1.angles[keep].copy()
    step_w[-5:] = w2.wrench[n - 4:n + 1]
    step_a[-1] = w2.angles[keep][-1]
    cases = {'last_5_samples_changed': params(step_w, step_a),
             'all_data_changed': params(w2.wrench[:n + 1], w2.angles[keep])}
    warm_solver = tr.solver('warm', {
        'expand': False, 'print_time': False, 'show_eval_warnings': False,
        'ipopt': {'print_level': 0, 'tol': MUSCLE.tol, 'sb': 'yes',
                  **collocation.WARM_START_IPOPT}})
    out = {'intervals': n, 'seed1_iterations': seed1.iterations}
    for name, p in cases.items():
        c = time.process_time()
        cold = tr.solve(nlp.solver, z_guess, p, lbx, ubx)
        cold_cpu = time.process_time() - c
        c = time.process_time()
        warm = tr.solve(warm_solver, seed1.z, p, lbx, ubx, lam_g0=seed1.lam_g,
                        lam_x0=seed1.lam_x)
        warm_cpu = time.process_time() - c
        out[name] = {'cold': {'iterations': cold.iterations, 'cpu_s': round(cold_cpu, 2),
                              'status': cold.status},
                     'warm': {'iterations': warm.iterations, 'cpu_s': round(warm_cpu, 2),
                              'status': warm.status},
                     'max_angle_diff_deg': float(np.degrees(np.abs(
                         tr.unpack(warm.z)['q'][:, :4] - tr.unpack(cold.z)['q'][:, :4]).max()))}
    return out


def read_truth(bag: Path):
    from nmt_ros.io.trial_bag import read_truth as read
    return read(bag)


def main() -> None:
    model = default_model()
    out = {'cache_size': collocation.SOLVER_CACHE_SIZE}
    out['muscle_tracking_builds'] = builds(model)
    trace = bounded(model, range(200, 212))
    out['rss_mb_through_cache_12_lengths'] = trace
    out['mb_per_cached_solver'] = round((trace[3] - trace[0]) / 3, 1)
    out['warm_start'] = warm_start(model)
    for n in (50, 100):
        c = time.process_time()
        JumpOptimizer(model, POSettings(n_intervals=n))
        out[f'po_build_cpu_s_N{n}'] = round(time.process_time() - c, 3)
    print(json.dumps(out, indent=1))


if __name__ == '__main__':
    main()
