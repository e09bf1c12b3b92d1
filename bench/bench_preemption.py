"""What a middleware's wake-ups cost a computation on the same core, and what SCHED_BATCH saves
(``nmt_ros.nodes.thread_policy``, the nodes' ``batch_thread_prefixes``).

    python bench/bench_preemption.py [--seconds 10] [--wake-hz 2500] [--rounds 3] [--cpu 0]

The moving-horizon estimator runs the routine's first ``--seconds`` offline (the skeletal
tracker's computation) pinned to one CPU. Beside it, pinned to the same CPU, a process wakes
``--wake-hz`` times a second and touches 64 KiB (a middleware thread handling a message:
Fast DDS's threads in the skeletal tracker woke ~3,000 times a second in ``nmt demo``), under
the default policy or under SCHED_BATCH; or nothing runs beside it. The three modes alternate
for ``--rounds`` rounds. Reported per run: the estimator's thread CPU [s] (its own work, the
waker's CPU is not in it), its involuntary context switches, the waker's wake-ups.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import subprocess
import sys
import threading
import time

from single_threaded import ROOT  # first: one BLAS thread before numpy loads

# isort: split
import numpy as np

from nmt_ros.io.trial_bag import read_observations
from nmt_ros.model.jumper import default_model
from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator, time_order
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

WAKER = r'''
import os, signal, sys, time
cpu, hz, batch = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == 'batch'
os.sched_setaffinity(0, {cpu})
if batch:
    os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
buf, page = bytearray(65536), bytes(range(256)) * 256
wakes, period = 0, 1.0 / hz
stop = []
signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
print('ready', flush=True)
while not stop:
    time.sleep(period)
    buf[:] = page
    wakes += 1
print(wakes, flush=True)
'''


def involuntary_switches() -> int:
    """Involuntary context switches of the calling thread so far."""
    status = Path(f'/proc/self/task/{threading.get_native_id()}/status').read_text()
    return int(status.split('nonvoluntary_ctxt_switches:')[1].split()[0])


def run(mode: str, args: argparse.Namespace, model, data) -> tuple[float, int, int]:
    """(estimator thread CPU [s], its involuntary switches, waker wake-ups) for one run."""
    ta, a, tw, w = data
    estimator = MovingHorizonEstimator(model, MovingHorizonSettings())
    waker = None
    if mode != 'alone':
        waker = subprocess.Popen([sys.executable, '-c', WAKER, str(args.cpu),
                                  str(args.wake_hz), mode], stdout=subprocess.PIPE, text=True)
        assert waker.stdout.readline().strip() == 'ready'
    switches, cpu = involuntary_switches(), time.thread_time()
    for _t, kind, i in time_order(ta, tw):
        if kind == 0:
            estimator.add_angles(ta[i], a[i])
        else:
            estimator.add_wrench(tw[i], w[i])
        estimator.poll()
    cpu, switches = time.thread_time() - cpu, involuntary_switches() - switches
    wakes = 0
    if waker is not None:
        waker.terminate()
        wakes = int(waker.stdout.read().split()[-1])
        waker.wait()
    return cpu, switches, wakes


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=str(ROOT / 'bags' / 'routine'))
    ap.add_argument('--seconds', type=float, default=10.0, help='seconds of the bag [s]')
    ap.add_argument('--wake-hz', type=float, default=2500.0, help="the waker's rate [Hz]")
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--cpu', type=int, default=0, help='the CPU both run on')
    args = ap.parse_args()
    if not hasattr(os, 'sched_setaffinity'):
        print('needs Linux (sched_setaffinity, SCHED_BATCH)')
        return 1
    os.sched_setaffinity(0, {args.cpu})
    obs = read_observations(args.bag)
    sa, sw = obs.t_angles <= args.seconds, obs.t_wrench <= args.seconds
    data = (obs.t_angles[sa], obs.angles[sa], obs.t_wrench[sw], obs.wrench[sw])
    model = default_model()
    results: dict[str, list[tuple[float, int, int]]] = {}
    print(f'estimator on {args.seconds:g} s of {Path(args.bag).name}, CPU {args.cpu}; waker '
          f'{args.wake_hz:g} Hz on the same CPU')
    for r in range(args.rounds):
        for mode in ('alone', 'normal', 'batch'):
            cpu, switches, wakes = run(mode, args, model, data)
            results.setdefault(mode, []).append((cpu, switches, wakes))
            print(f'round {r + 1} {mode:6s}: estimator {cpu:6.2f} s CPU, {switches:7d} '
                  f'involuntary switches; waker {wakes} wake-ups', flush=True)
    print('median over rounds:')
    for mode, rows in results.items():
        cpu, switches, wakes = np.median(np.array(rows, dtype=float), axis=0)
        print(f'  {mode:6s}: estimator {cpu:6.2f} s CPU ({cpu / args.seconds:.3f} s per s '
              f'of data), {switches:7.0f} involuntary switches, waker {wakes:.0f} wake-ups')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
