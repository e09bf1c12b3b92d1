"""Two commits' live graphs compared in alternating `nmt demo` runs (run by hand).

    python bench/bench_graph_pairs.py --before REV [--after HEAD] [--pairs 2] [--duration 0]
                                      [--out /tmp/graph_pairs]

On a shared 2-core VM one run's latency and even its CPU seconds change by the hour (the
host's steal, other tenants): a figure from a single run cannot tell two commits apart. This
runs ``nmt demo`` on ``--before`` and on ``--after`` back to back, ``--pairs`` times, and prints
per run the CPU seconds of each node (and their sum), the refined / low-latency / muscle
latency p50 / p99 and the refined coverage, so that each comparison is between neighbours in
time, with the CPU time of a fixed workload taken just before and after each run (the
machine's speed then; ``SPEED_PROBE``). ``--before`` is checked out into a temporary git
worktree and run with this checkout's virtual environment (its modules first on
``PYTHONPATH``); ``--after`` ``HEAD`` is this checkout as it is (uncommitted changes
included). Each demo gets its own ``ROS_DOMAIN_ID``; nothing else of ours should run
meanwhile. The load average before each run is printed with it.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[1]


#: A fixed CPU workload (dense 120 x 120 solves and a pure-Python loop: LAPACK and the
#: interpreter, as in the trackers), its CPU time printed with each run: this VM's speed
#: changes by the run (the same code's skeletal tracker took 35 and 45 CPU s in two demos 15
#: min apart), and the probe, taken just before and just after a demo, says whether the
#: machine was slow then.
SPEED_PROBE = """
import time
import numpy as np
a = np.random.default_rng(0).normal(size=(120, 120))
c = time.process_time()
for _ in range(300):
    a = np.linalg.solve(a + 120.0 * np.eye(120), a)
s = 0
for i in range(1_500_000):
    s += i * i
print((time.process_time() - c) * 1e3)
"""


def speed_probe_ms() -> float:
    """CPU time [ms] of ``SPEED_PROBE`` in a fresh process (one BLAS thread)."""
    done = subprocess.run([sys.executable, '-c', SPEED_PROBE], capture_output=True, text=True,
                          env=dict(os.environ, OPENBLAS_NUM_THREADS='1'), check=True)
    return float(done.stdout)


def run_demo(source: Path, out: Path, duration: float, domain: int) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_LOCALHOST_ONLY='1', OPENBLAS_NUM_THREADS='1')
    if source != ROOT:
        env['PYTHONPATH'] = str(source)
    cmd = [sys.executable, '-m', 'nmt_ros.cli.main', 'demo', '--out', str(out)]
    if duration > 0:
        cmd += ['--duration', str(duration)]
    load = os.getloadavg()[0]
    probe = speed_probe_ms()
    done = subprocess.run(cmd, cwd=source, env=env, capture_output=True, text=True,
                          timeout=1800)
    probe = (probe, speed_probe_ms())
    if done.returncode != 0:
        raise SystemExit(f'nmt demo failed in {source}:\n{done.stdout[-2000:]}'
                         f'{done.stderr[-2000:]}')
    summary = json.loads((out / 'summary.json').read_text())
    summary['load_before'] = load
    summary['speed_probe_ms'] = probe
    return summary


def line(label: str, s: dict) -> str:
    cpu = s['cpu']
    lat = s['latency_ms']
    cover = s.get('phases', {}).get('refined', {}).get('all', {}).get('coverage', float('nan'))
    return (f'{label:7s} load {s["load_before"]:4.1f} | speed probe '
            f'{s["speed_probe_ms"][0]:.0f}/{s["speed_probe_ms"][1]:.0f} ms | CPU s '
            + ' '.join(f'{k.split("_")[0][:5]} {v["cpu_s"]:5.1f}' for k, v in cpu.items())
            + f' sum {sum(v["cpu_s"] for v in cpu.values()):5.1f} | p50/p99 ms '
            + ' '.join(f'{k.replace("_joint_torques", "").replace("joint_torques", "refined")}'
                       f' {v["p50_ms"]:.0f}/{v["p99_ms"]:.0f}' for k, v in lat.items())
            + f' | cover {cover:.3f}'
            + (f" | others {s['host']['other_cores']:.2f} cores, steal "
               f"{s['host']['steal_pct']:.1f} %" if 'host' in s else ''))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--before', required=True, help='git revision run first in each pair')
    ap.add_argument('--after', default='HEAD', help="git revision run second ('HEAD': this "
                    'checkout as it is)')
    ap.add_argument('--pairs', type=int, default=2)
    ap.add_argument('--duration', type=float, default=0.0,
                    help='seconds of the routine (0: all 60 s)')
    ap.add_argument('--out', default=None, help='folder for the demos (default: temporary)')
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix='graph_pairs_'))
    out.mkdir(parents=True, exist_ok=True)
    trees = {}
    # a run killed by a signal skips the removal below: its worktree's registration stays
    # behind and would refuse the same path; forget registrations whose directory is gone
    subprocess.run(['git', '-C', str(ROOT), 'worktree', 'prune'], check=True,
                   capture_output=True)
    for label, rev in (('before', args.before), ('after', args.after)):
        if label == 'after' and rev == 'HEAD':
            trees[label] = ROOT
            continue
        tree = out / f'worktree_{label}'
        if not tree.exists():
            subprocess.run(['git', '-C', str(ROOT), 'worktree', 'add', '--detach', str(tree),
                            rev], check=True, capture_output=True)
        trees[label] = tree
    print(f'before = {args.before}, after = {args.after}; demos in {out}', flush=True)
    try:
        for k in range(args.pairs):
            for n, label in enumerate(('before', 'after')):
                summary = run_demo(trees[label], out / f'{label}_{k}', args.duration,
                                   150 + (2 * k + n) % 60)
                print(line(f'{label[0]}{k}', summary), flush=True)
    finally:
        for tree in trees.values():
            if tree != ROOT:
                subprocess.run(['git', '-C', str(ROOT), 'worktree', 'remove', '--force',
                                str(tree)], capture_output=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
