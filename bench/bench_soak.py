"""Soak benchmark (run by hand): the graph on a long looped stream at 1x, with the recorder.

    .venv/bin/python bench/bench_soak.py [--minutes 10] [--bag bags/reference_jump]
                                         [--rate 1] [--sample-s 5] [--out DIR]

The bag's observation topics are looped end to end with shifted stamps
(``nmt_ros.io.bag_loop``) to ``--minutes`` of data and replayed through ``nmt launch --record``
(the recorder splits its bag every 60 s of data, as a long recording would). Every
``--sample-s`` the resident set size (VmRSS) and CPU time of each node process are read from
``/proc``. Reported:

- RSS per node after the warm-up (``--warmup-s``, 2 min from the launch: the nodes' start-up
  and about a minute of data), at 2 and 5 min and at the end; growth after the warm-up
  (target < 10 %), peak;
- CPU share of each node after the warm-up (CPU seconds / wall seconds, 1.0 = one
  core);
- loss: every topic's published count (the producers' end-of-stream announcements) against
  the recorded count (target: 0 lost), the recording's files;
- errors: ERROR-level records on /nmt/status and the launcher's problems (target: 0);
- latency p99 per minute from the recording (the recorder's receive time of the estimate -
  that of the observation with the same stamp; only minutes that have estimates).

The default bag is the shipped 0.25 s reference jump, so a short run is quick; the
continuous estimator tracks every copy (push-off, flight and the seam to the next copy, where
it may lose control and re-initialise, reported). ``--bag bags/routine`` (stance, jumps,
flight, landings, a drop jump) is the realistic load. Say what else ran on the machine when
quoting figures.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nmt_ros.cli.launch import NODES, config_path, load_params, ros_environment  # noqa: E402
from nmt_ros.io.bag_loop import loop_bag  # noqa: E402
from nmt_ros.io.bags import bag_info  # noqa: E402
from nmt_ros.topics import (  # noqa: E402
    FORCE_PLATE_WRENCH,
    MUSCLE_FORCES,
    OBSERVATIONS,
    SKELETAL_JOINT_TORQUES,
    STATUS,
)

CLOCK_TICKS = os.sysconf('SC_CLK_TCK')


def children(pid: int) -> list[int]:
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out += [int(c) for c in (task / 'children').read_text().split()]
        except OSError:
            continue
    return out


def node_of(pid: int) -> str | None:
    try:
        cmd = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
    except OSError:
        return None
    for part in cmd:
        text = part.decode(errors='replace')
        if text.startswith('nmt_ros.nodes.'):
            return text[len('nmt_ros.nodes.'):]
    return None


def sample(pid: int) -> tuple[float, float] | None:
    """(RSS [MiB], CPU time [s]) of a live process."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
        stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    rss_kb = next(int(line.split()[1]) for line in status.splitlines()
                  if line.startswith('VmRSS:'))
    return rss_kb / 1024, (int(stat[11]) + int(stat[12])) / CLOCK_TICKS


def error_records(record: Path) -> dict[str, int]:
    from msg_adapters.diagnostics import from_diagnostic_array
    from nmt_ros.io.bags import read_bag

    seen: dict[str, set] = {}
    for msg in read_bag(record, [STATUS]):
        for r in from_diagnostic_array(msg.msg)[1]:
            if r.level >= 2:
                seen.setdefault(r.name.split(':')[0].lstrip('/'), set()).add(r.message)
    return {node: len(messages) for node, messages in seen.items()}


def latency_per_minute(record: Path) -> dict[str, list[float]]:
    from nmt_ros.study.recording_evaluation import latency_ms, topic_times

    obs = topic_times(record, FORCE_PLATE_WRENCH)
    t0 = int(obs.publish_ns.min())
    out = {}
    for name, topic in (('joint_torques', SKELETAL_JOINT_TORQUES),
                        ('muscle_forces', MUSCLE_FORCES)):
        est = topic_times(record, topic)
        minute = (est.publish_ns - t0) // 60_000_000_000
        row = []
        for m in range(int(minute.max()) + 1 if minute.size else 0):
            sel = minute == m
            if sel.any():
                sub = type(est)(est.stamp_ns[sel], est.publish_ns[sel], est.log_ns[sel])
                row.append(round(latency_ms(sub, obs)['p99_ms'], 1))
        out[name] = row
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--bag', type=Path, default=ROOT / 'bags' / 'reference_jump')
    parser.add_argument('--rate', type=float, default=1.0)
    parser.add_argument('--sample-s', type=float, default=5.0)
    parser.add_argument('--warmup-s', type=float, default=120.0,
                        help='growth and CPU share are counted from this long after the launch '
                        '[s] (the nodes load their compiled kernels and wait for each other '
                        'for about a minute before the replay starts)')
    parser.add_argument('--out', type=Path, default=None,
                        help='work folder (default: a new temporary folder)')
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix='bench_soak_'))
    out.mkdir(parents=True, exist_ok=True)
    seconds = args.minutes * 60
    load0 = os.getloadavg()
    print(f'machine: {os.cpu_count()} cores, load average {load0[0]:.2f} before the run')
    looped, plan = loop_bag(args.bag, out / 'looped', seconds, OBSERVATIONS)
    print(f'looped {args.bag} x {plan.copies} = {looped.duration_ns / 1e9:.0f} s, '
          f'{looped.message_count} messages -> {looped.path}')
    params = load_params(config_path('nmt_graph.yaml'))
    params.setdefault('recorder', {}).setdefault('ros__parameters', {})['max_bag_duration'] = 60.0
    params_file = out / 'params.yaml'
    params_file.write_text(yaml.safe_dump(params, sort_keys=False), encoding='utf-8')
    record = out / 'recording'
    env = ros_environment()
    env.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    launch = subprocess.Popen(
        [sys.executable, '-m', 'nmt_ros.cli.main', 'launch', '--bag', str(looped.path),
         '--rate', str(args.rate), '--record', str(record), '--params', str(params_file),
         '--log-dir', str(out / 'logs'), '--timeout', str(seconds / args.rate + 600)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples: dict[str, list[tuple[float, float, float]]] = {n: [] for n in NODES}
    start = time.monotonic()
    while launch.poll() is None:
        now = time.monotonic() - start
        for pid in children(launch.pid):
            name = node_of(pid)
            got = sample(pid) if name else None
            if got is not None:
                samples[name].append((now, *got))
        time.sleep(args.sample_s)
    text = launch.stdout.read()
    wall = time.monotonic() - start
    print(text.strip())
    print(f'\nsoak of {seconds / 60:g} min at {args.rate:g}x: launch wall {wall:.0f} s, exit '
          f'code {launch.returncode}; load average (1/5/15 min) at the end '
          + '/'.join(f'{x:.1f}' for x in os.getloadavg()))
    report: dict = {'minutes': args.minutes, 'rate': args.rate, 'wall_s': wall,
                    'exit_code': launch.returncode, 'load_before': load0[0],
                    'load_after': os.getloadavg()[0], 'nodes': {}}
    print(f'RSS from {args.warmup_s:g} s after the launch (the warm-up) to the end:')
    print(f'{"node":22s} {"RSS warm":>9s} {"@2min":>6s} {"@5min":>6s} {"end":>6s} '
          f'{"peak":>6s} {"growth":>7s} {"CPU share":>9s}  [MiB]')
    for name, rows in samples.items():
        if len(rows) < 2:
            continue
        t, rss, cpu = (np.array(c) for c in zip(*rows))
        if t[-1] < args.warmup_s:
            report['nodes'][name] = {'exited_s': round(float(t[-1]), 1),
                                     'rss_peak_mib': round(float(rss.max()), 1)}
            print(f'{name:22s} exited after {t[-1]:.0f} s (peak RSS {rss.max():.1f} MiB): '
                  'not soaked')
            continue
        first = int(np.argmax(t >= args.warmup_s))
        ref = rss[first]
        growth = (rss[-1] - ref) / ref * 100
        # steady state: from the warm-up (start-up imports excluded) to the last sample
        share = (cpu[-1] - cpu[first]) / max(t[-1] - t[first], 1e-9)
        at = {m: float(rss[int(np.argmax(t >= 60.0 * m))]) if (t >= 60.0 * m).any()
              else float('nan') for m in (2, 5)}
        report['nodes'][name] = {'rss_warm_mib': round(float(ref), 1),
                                 'rss_2min_mib': round(at[2], 1),
                                 'rss_5min_mib': round(at[5], 1),
                                 'rss_end_mib': round(float(rss[-1]), 1),
                                 'rss_peak_mib': round(float(rss.max()), 1),
                                 'growth_pct': round(float(growth), 2),
                                 'cpu_share': round(float(share), 3),
                                 'series_s_mib_cpus': [[round(float(a), 1), round(float(b), 2),
                                                        round(float(c), 2)]
                                                       for a, b, c in zip(t, rss, cpu)]}
        print(f'{name:22s} {ref:9.1f} {at[2]:6.1f} {at[5]:6.1f} {rss[-1]:6.1f} '
              f'{rss.max():6.1f} {growth:6.1f}% {share:9.2f}')
    if (record / 'metadata.yaml').exists():
        from nmt_ros.study.recording_evaluation import graph_summary

        summary = graph_summary(record, None, batch=False)
        lost = {t: c['published'] - c['recorded'] for t, c in summary['counts'].items()
                if c['published'] >= 0 and c['published'] != c['recorded']}
        info = bag_info(record)
        errors = error_records(record)
        report.update(counts=summary['counts'], lost=lost, errors=errors,
                      files=len(info.relative_file_paths),
                      latency_p99_per_minute_ms=latency_per_minute(record))
        print(f'loss: {"0" if not lost else lost} over '
              + ', '.join(f'{t} {c["recorded"]}/{c["published"]}'
                          for t, c in summary['counts'].items())
              + f'; recording: {info.message_count} messages in '
              f'{len(info.relative_file_paths)} files')
        print(f'errors (ERROR records on {STATUS} per node): {errors or 0}')
        print(f'latency p99 per minute [ms]: {report["latency_p99_per_minute_ms"]}')
    (out / 'soak.json').write_text(json.dumps(report, indent=1))
    print(f'figures: {out / "soak.json"}')
    return 0 if launch.returncode == 0 else 1


if __name__ == '__main__':
    raise SystemExit(main())
