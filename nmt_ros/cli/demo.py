"""``nmt demo [--out DIR]``: the shipped routine through the live ROS 2 graph, recorded, reported.

What ``make demo`` runs: ``nmt launch`` on ``bags/routine`` (60 s) at real time with every
topic recorded to ``DIR/recording`` (a rosbag2 MCAP bag), then a report read back from the
recording (``nmt_ros.study.recording_evaluation``): jump height of the tracked motion against
the truth, joint-torque and muscle-force errors against the truth phase by phase (quiet stance,
movement, flight, landing) with their coverage, the agreement with the batch
trackers, latency from an observation's publication to its estimates (p50/p99), each node's
CPU share, and messages published vs recorded. ``DIR/summary.json`` holds the numbers,
``DIR/logs`` the node logs and the parameters used. Outputs of a previous demo in ``DIR``
(those three names) are replaced.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import shutil
import sys

from nmt_ros.cli.launch import default_bag, format_run, replay_timeout_s, run_graph

OWNED = ('recording', 'logs', 'summary.json')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', default='demo_out', help='output folder (default demo_out)')
    parser.add_argument('--bag', default=None, help='bag to replay (default bags/routine: a '
                        '60 s routine of stance, drop and countermovement jumps)')
    parser.add_argument('--rate', type=float, default=1.0, help='replay speed factor')
    parser.add_argument('--params', default=None, metavar='FILE',
                        help='graph parameters (default config/nmt_graph.yaml)')
    parser.add_argument('--duration', type=float, default=0.0, metavar='S',
                        help='replay only the first S seconds of the bag (default: all)')
    parser.add_argument('--timeout', type=float, default=None,
                        help='give up after S seconds (default: the replay time + 420 s)')


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in OWNED:
        target = out / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    bag = Path(args.bag) if args.bag else default_bag().parent / 'routine'
    recording = out / 'recording'
    print(f'nmt demo: replaying {bag} through the live graph (rate {args.rate:g}), '
          f'recording to {recording} ...', flush=True)
    timeout = args.timeout or replay_timeout_s(bag, args.rate, args.duration)
    extra = {'observation_publisher': {'duration_s': args.duration}} if args.duration else None
    from nmt_ros.study.host_load import cpu_times, format_host_load, host_load

    before = cpu_times()
    result = run_graph(bag=bag, rate=args.rate, record=recording, params=args.params,
                       log_dir=out / 'logs', timeout_s=timeout, extra_params=extra)
    after = cpu_times()
    print(format_run(result).splitlines()[0])
    for problem in result.problems:
        print(f'  problem: {problem}')
    if not (recording / 'metadata.yaml').exists():
        print(f'error: no recording in {recording}; see {result.log_dir}', file=sys.stderr)
        return result.returncode or 1

    from nmt_ros.study.recording_evaluation import format_summary, graph_summary

    summary = graph_summary(recording, bag)
    summary['graph'] = {'returncode': result.returncode, 'wall_s': round(result.wall_s, 2),
                        'node_returncodes': result.node_returncodes,
                        'problems': result.problems}
    if before is not None and after is not None:
        summary['host'] = host_load(before, after)
    (out / 'summary.json').write_text(json.dumps(summary, indent=1, default=float) + '\n',
                                      encoding='utf-8')
    print()
    print(format_summary(summary))
    if 'host' in summary:
        print(format_host_load(summary['host']))
    print()
    print(f'files: recording {recording} (nmt bag info {recording}), '
          f'numbers {out / "summary.json"}, logs and parameters {result.log_dir}')
    ok = result.returncode == 0 and summary['lossless']
    if not ok:
        print('nmt demo: FAILED (see problems above)', file=sys.stderr)
    return 0 if ok else 1
