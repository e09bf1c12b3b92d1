"""Streaming Stage 2 on a long stream (run by hand): CPU per second of stream, latency,
accuracy, determinism (issues 12 item 3 and 13).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_stage2_stream.py
        [--bag bags/routine] [--seconds 60] [--windows 0.04:0.01,0.1:0.02] [--rate 1080]
        [--no-full] [--profile]

Input: the routine's TRUE joint torques and joint kinematics (``/truth/*``, 120 Hz, cubic
splines of q, qd, tau to the force-plate grid ``--rate``): stance, countermovements,
push-offs, flight and landings, ``--seconds`` long - the stream the muscle tracker gets from
the skeletal tracker, without Stage 1's error. No ROS: ``Stage2Stream`` (the node's code) fed
one sample at a time, as the node's callback does.

Per window setting H:stride (s):

* CPU: thread CPU seconds of the ``add`` + ``process`` calls per second of stream (the node's
  Stage-2 work; the node adds rclpy receive/publish on top) and per planned window (p50/p99).
* Latency at 1x, a discrete-event replay of the measured call durations: sample j arrives at
  its data time t_j (plus a constant: Stage 1's lag, left out), each call starts when its
  sample has arrived and the previous call has ended, and an output's latency is the end of
  the call that produced it minus its sample's arrival. p50 / p99 / max in ms: the look-ahead
  H, up to a stride of waiting, and the compute (and any backlog).
* Accuracy: forces vs the full horizon on the same stream (max over muscles of RMS / F0; the
  full horizon is one bounded QP over the whole stream) and vs the true forces (RMS / F0
  at the truth's samples; mean and max over GMAX, HAMS, RF, VAS, GAS, SOL).
* Determinism: the same stream fed in random bursts of 1-500 samples gives identical outputs.

``--profile`` prints the cProfile of the first setting's streaming run (top 25 by own time).
"""
from __future__ import annotations

import argparse
import cProfile
import gc
from pathlib import Path
import pstats
import time

import numpy as np
from scipy.interpolate import CubicSpline

from nmt_ros.io.trial_bag import read_truth
from nmt_ros.model.jumper import default_model
from nmt_ros.tracking.stage2 import NeuromuscularTracker
from nmt_ros.tracking.streaming import Stage2Stream, initial_activations

DEFAULT_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'routine'
SCORED = ('gmax', 'hams', 'rf', 'vas', 'gas', 'sol')


def stream_input(bag: Path, seconds: float, rate_hz: float, model) -> dict:
    """The truth of ``bag`` on the grid k / rate_hz for ``seconds``: t, tau, theta,
    theta_dot [n, 3], and the true forces at the truth's own samples."""
    tr = read_truth(bag)
    end = min(seconds, float(tr.t[-1]))
    t = np.arange(int(np.floor(end * rate_hz + 1e-9)) + 1) / rate_hz
    J = np.column_stack([model.call(model.joint_angles, e)[0] for e in np.eye(6)])
    q, qd = CubicSpline(tr.t, tr.q)(t), CubicSpline(tr.t, tr.qd)(t)
    keep = tr.t <= end + 1e-9
    return {'t': t, 'tau': CubicSpline(tr.t, tr.tau)(t), 'theta': q @ J.T, 'theta_dot': qd @ J.T,
            'theta_ddot': CubicSpline(tr.t, tr.qd)(t, 1) @ J.T, 't_true': tr.t[keep],
            'f_true': tr.f[keep]}


def run_stream(model, tracker, inp: dict, length: float, stride: float, rate_hz: float,
               bursts: np.ndarray | None = None) -> dict:
    """Feed the stream (one sample per call, or ``bursts``); outputs and per-call timing."""
    stream = Stage2Stream(model, tracker, length, stride, rate_hz)
    t, tau, th, thd = inp['t'], inp['tau'], inp['theta'], inp['theta_dot']
    stamps = np.rint(t * 1e9).astype(np.int64)
    sizes = np.ones(t.size, dtype=int) if bursts is None else bursts
    outs, calls = [], []           # calls: (index of the last sample in, cpu s, n outputs)
    i = k = 0
    while i < t.size:
        n = int(sizes[k % sizes.size])
        c0 = time.thread_time()
        for j in range(i, min(i + n, t.size)):
            stream.add(stamps[j], t[j], tau[j], th[j], thd[j])
        out = stream.process(final=i + n >= t.size)
        if i + n >= t.size and out is None:
            out = stream.process(final=True)
        cpu = time.thread_time() - c0
        i, k = i + n, k + 1
        calls.append((min(i, t.size) - 1, cpu, 0 if out is None else out.t.size))
        if out is not None:
            outs.append(out)
    if not stream.finished:
        outs.append(stream.process(final=True))
    outs = [o for o in outs if o is not None]
    cat = {key: np.concatenate([getattr(o, key) for o in outs])
           for key in ('stamp_ns', 't', 'f', 'a', 'u')}
    if not np.array_equal(cat['stamp_ns'], stamps):
        raise RuntimeError('the stream did not return every sample once')
    return cat | {'calls': np.array(calls)}


def replay_latency(calls: np.ndarray, rate_hz: float, speed: float = 1.0) -> np.ndarray:
    """Per-output latency [s] at replay ``speed`` from the calls' measured CPU durations."""
    end_prev = 0.0
    lat = []
    first = 0
    for last, cpu, n_out in calls:
        arrive = int(last) / rate_hz / speed
        end = max(arrive, end_prev) + cpu
        end_prev = end
        if n_out:
            idx = np.arange(first, first + int(n_out))
            lat.append(end - idx / rate_hz / speed)
            first += int(n_out)
    return np.concatenate(lat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--bag', type=Path, default=DEFAULT_BAG)
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--rate', type=float, default=1080.0)
    ap.add_argument('--windows', default='0.04:0.01,0.03:0.02,0.1:0.02',
                    help='H:stride pairs in s, comma separated')
    ap.add_argument('--no-full', action='store_true', help='skip the full-horizon reference')
    ap.add_argument('--profile', action='store_true')
    args = ap.parse_args()

    model = default_model()
    tracker = NeuromuscularTracker(model)
    names = list(tracker.names)
    f0 = tracker.f0
    inp = stream_input(args.bag, args.seconds, args.rate, model)
    dur = float(inp['t'][-1] - inp['t'][0])
    print(f'{args.bag.name}: {dur:.1f} s of true torques at {args.rate:g} Hz '
          f'({inp["t"].size} samples)')
    # warm-up of each setting on the first 0.5 s (the compiled kernels load on their first
    # call and CasADi maps are made per block size: ~0.4 s once per process, left out)
    warm = {k: v[:540] if k not in ('t_true', 'f_true') else v for k, v in inp.items()}

    full = None
    if not args.no_full:
        a0, _ = initial_activations(model, inp['theta'][0], inp['tau'][0], inp['theta_dot'][0])
        c0 = time.process_time()
        full = tracker.track(inp['t'], inp['tau'], inp['theta'], inp['theta_dot'],
                             inp['theta_ddot'], a0, mode='full')
        print(f'full horizon (one bounded QP over {dur:.0f} s): {time.process_time() - c0:.1f} '
              f's CPU, {full.plan_iterations[0]} interior-point iterations')
    scored = [names.index(n) for n in SCORED]
    step = int(round(args.rate / 120.0))
    if full is not None:
        n_true = min(inp['t_true'].size, (full.f.shape[0] - 1) // step + 1)
        rms = np.sqrt(np.mean((full.f[::step][:n_true] - inp['f_true'][:n_true]) ** 2,
                              axis=0)) / f0 * 100
        print(f'full horizon vs truth: mean {rms[scored].mean():.2f} / max '
              f'{rms[scored].max():.2f} % F0 over {", ".join(SCORED)}')
    print('\n| H ms | stride ms | CPU s / s stream | per window ms p50 / p99 | '
          'latency ms p50 / p99 / max | vs full max RMS % F0 | vs truth mean / max % F0 |')
    print('|---|---|---|---|---|---|---|')
    for k, pair in enumerate(args.windows.split(',')):
        length, stride = (float(x) for x in pair.split(':'))
        run_stream(model, tracker, warm, length, stride, args.rate)
        gc.freeze()        # as the node does after start-up
        prof = cProfile.Profile() if args.profile and k == 0 else None
        if prof is not None:
            prof.enable()
        res = run_stream(model, tracker, inp, length, stride, args.rate)
        if prof is not None:
            prof.disable()
        calls = res['calls']
        cpu = calls[:, 1]
        per_window = cpu[calls[:, 2] > 0] * 1e3
        lat = replay_latency(calls, args.rate) * 1e3
        vs_full = float('nan')
        if full is not None:
            vs_full = float(np.max(np.sqrt(np.mean((res['f'] - full.f) ** 2, axis=0)) / f0)) * 100
        # truth at its own samples (every step-th stream sample)
        n_true = min(inp['t_true'].size, (res['f'].shape[0] - 1) // step + 1)
        est = res['f'][::step][:n_true]
        rms = np.sqrt(np.mean((est - inp['f_true'][:n_true]) ** 2, axis=0)) / f0 * 100
        print(f'| {length * 1e3:.0f} | {stride * 1e3:.0f} | {cpu.sum() / dur:.3f} | '
              f'{np.percentile(per_window, 50):.2f} / {np.percentile(per_window, 99):.2f} | '
              f'{np.percentile(lat, 50):.1f} / {np.percentile(lat, 99):.1f} / {lat.max():.1f} | '
              f'{vs_full:.2f} | {rms[scored].mean():.2f} / {rms[scored].max():.2f} |')
        if prof is not None:
            pstats.Stats(prof).sort_stats('tottime').print_stats(25)
        if k == 0:
            rng = np.random.default_rng(0)
            again = run_stream(model, tracker, inp, length, stride, args.rate,
                               bursts=rng.integers(1, 501, size=4096))
            same = all(np.array_equal(again[key], res[key]) for key in ('t', 'f', 'a', 'u'))
            print(f'|  | determinism: random bursts of 1-500 samples give '
                  f'{"identical" if same else "DIFFERENT"} outputs |||||')


if __name__ == '__main__':
    main()
