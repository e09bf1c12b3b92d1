"""What the live view costs the graph (run by hand): latency and loss with and without --view.

    .venv/bin/python bench/bench_view.py [--bag bags/reference_jump] [--repeat 5] [--rate 1]
                                         [--quiet-start 0.4]

Runs ``nmt launch --record`` (``run_graph``, config/nmt_graph.yaml) on the bag (by default
the shipped jump after 0.4 s of quiet standing, as bench_latency.py) in three
set-ups, interleaved ``--repeat`` times so that the machine's load falls on all alike:
``plain`` (no view), ``view`` (``--view``: the viewer node subscribed to every topic, its
server up, no client) and ``view+client`` (a Foxglove WebSocket client in this process,
connected before the replay and subscribed to every channel, counting what it receives).
Per run, from the recording: latency from an observation's publication to the joint-torque
and muscle-force estimates for that instant (p50 / p99), published == recorded for every
topic (lossless), and for the client the messages it received per topic against the
recording. Prints each run and the medians per set-up.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
from pathlib import Path
import socket
import struct
import sys
import tempfile
import threading
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nmt_ros.cli.launch import config_path, run_graph  # noqa: E402
from nmt_ros.io.bags import bag_info  # noqa: E402
from nmt_ros.study.recording_evaluation import final_statuses, graph_summary  # noqa: E402

MODES = ('plain', 'view', 'view+client')


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class CountingClient(threading.Thread):
    """A Foxglove WebSocket client subscribed to every channel, counting messages per topic."""

    def __init__(self, port: int, timeout_s: float = 300.0) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.timeout_s = timeout_s
        self.counts: dict[str, int] = {}
        self.connected = threading.Event()

    def run(self) -> None:
        asyncio.run(self._run())

    async def _run(self) -> None:
        import websockets

        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                ws = await websockets.connect(f'ws://127.0.0.1:{self.port}',
                                              subprotocols=['foxglove.sdk.v1'], max_size=None)
                break
            except OSError:
                if time.monotonic() > deadline:
                    return
                await asyncio.sleep(0.1)
        self.connected.set()
        topics: dict[int, str] = {}
        async with ws:
            try:
                while time.monotonic() < deadline:
                    frame = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
                    if isinstance(frame, str):
                        op = json.loads(frame)
                        if op['op'] == 'advertise':
                            await asyncio.sleep(0.05)
                            subs = []
                            for c in op['channels']:
                                topics[len(topics)] = c['topic']
                                subs.append({'id': len(topics) - 1, 'channelId': c['id']})
                            await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
                    elif frame[0] == 1:
                        (sub,) = struct.unpack_from('<I', frame, 1)
                        topic = topics[sub]
                        self.counts[topic] = self.counts.get(topic, 0) + 1
            except (TimeoutError, websockets.ConnectionClosed):
                return


def one_run(bag: Path, mode: str, rate: float) -> dict:
    with tempfile.TemporaryDirectory(prefix='nmt_bench_view_') as tmp:
        rec = Path(tmp) / 'rec'
        view = None
        client = None
        if mode != 'plain':
            port = free_port()
            view = {'host': '127.0.0.1', 'port': port}
            if mode == 'view+client':
                client = CountingClient(port)
                client.start()
        res = run_graph(bag=bag, rate=rate, record=rec, params=config_path('nmt_graph.yaml'),
                        log_dir=Path(tmp) / 'logs', view=view)
        if client is not None:
            client.join(timeout=10.0)
        if not (rec / 'metadata.yaml').exists():
            return {'mode': mode, 'ok': False, 'problems': res.problems}
        s = graph_summary(rec, None, batch=False)
        statuses = final_statuses(rec)
        viewer = statuses.get('viewer', {})
        graph_cpu_s = sum(float(v.get('cpu_s_active', 0.0)) for n, v in statuses.items()
                          if n != 'viewer')
        recorded = {t.name: t.message_count for t in bag_info(rec).topics}
    out = {'mode': mode, 'ok': res.returncode == 0 and s['lossless'], 'wall_s': res.wall_s,
           'torques': s['latency_ms']['joint_torques'], 'forces': s['latency_ms']['muscle_forces'],
           'cpu': {n: v['share'] for n, v in s['cpu'].items()}
           | {'viewer': float(viewer.get('cpu_share', 'nan'))},
           'viewer_cpu_s': float(viewer.get('cpu_s_active', 'nan')), 'graph_cpu_s': graph_cpu_s,
           'messages': sum(n for t, n in recorded.items() if t != '/nmt/status'),
           'problems': res.problems}
    if client is not None:
        data = [t for t in recorded if t.startswith(('/nmt/', '/mocap/', '/force_plate/'))
                and t != '/nmt/status']
        out['client_missing'] = sum(max(0, recorded[t] - client.counts.get(t, 0)) for t in data)
        out['client_received'] = sum(client.counts.get(t, 0) for t in data)
        out['client_scenes'] = client.counts.get('/nmt/view/scene', 0)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bag', type=Path, default=ROOT / 'bags' / 'reference_jump')
    parser.add_argument('--repeat', type=int, default=5)
    parser.add_argument('--rate', type=float, default=1.0)
    parser.add_argument('--quiet-start', type=float, default=0.4, metavar='S',
                        help='the jump after S s of quiet standing (bench_latency.padded_bag: '
                             "the trackers' start-up is over when the jump begins); 0: as is")
    args = parser.parse_args()
    from nmt_ros.cli.main import ros_environment_defaults

    ros_environment_defaults()
    # a domain of our own: other graphs on this machine (domain 0 by default) would otherwise
    # be heard by ours (their messages recorded, ours counted twice)
    os.environ.setdefault('ROS_DOMAIN_ID', str(101 + os.getpid() % 100))
    if args.quiet_start > 0:
        from bench_latency import padded_bag

        tmp = tempfile.TemporaryDirectory(prefix='nmt_bench_view_bag_')
        args.bag = padded_bag(args.bag, args.quiet_start, Path(tmp.name) / 'padded')
    print(f'bag {args.bag}, rate {args.rate:g}, {args.repeat} rounds of {MODES}, ROS domain '
          f'{os.environ["ROS_DOMAIN_ID"]}; load average {os.getloadavg()[0]:.1f}')
    print(f'{"mode":>12} | torques p50 p99 | forces p50 p99 | lossless | client got/missing '
          f'(scenes) | viewer CPU | wall s')
    runs = []
    for _ in range(args.repeat):
        for mode in MODES:
            r = one_run(args.bag, mode, args.rate)
            runs.append(r)
            if 'torques' not in r:
                print(f'{mode:>12} | failed: {r["problems"]}')
                continue
            client = (f'{r["client_received"]}/{r["client_missing"]} ({r["client_scenes"]})'
                      if 'client_missing' in r else '-')
            print(f'{mode:>12} | {r["torques"]["p50_ms"]:7.1f} {r["torques"]["p99_ms"]:5.1f} | '
                  f'{r["forces"]["p50_ms"]:6.1f} {r["forces"]["p99_ms"]:5.1f} | '
                  f'{str(r["ok"]):>8} | {client:>22} | '
                  f'{r["cpu"].get("viewer", float("nan")):10.2f} | {r["wall_s"]:5.1f}'
                  + ('' if not r['problems'] else f'  {r["problems"]}'), flush=True)
    viewed = [r for r in runs if r['mode'] != 'plain' and 'viewer_cpu_s' in r]
    if viewed:
        per = [1e6 * r['viewer_cpu_s'] / r['messages'] for r in viewed]
        share = [100 * r['viewer_cpu_s'] / r['graph_cpu_s'] for r in viewed]
        print(f'viewer CPU per graph message: median {np.median(per):.0f} us '
              f'(range {min(per):.0f}-{max(per):.0f}); viewer CPU time / the other nodes\' '
              f'{np.median(share):.0f} % (range {min(share):.0f}-{max(share):.0f})')
    print(f'\nmedians over {args.repeat} runs (load average now {os.getloadavg()[0]:.1f})')
    base = None
    for mode in MODES:
        rs = [r for r in runs if r['mode'] == mode and 'torques' in r]
        if not rs:
            continue
        med = {k: float(np.median([r[k.split('.')[0]][k.split('.')[1]] for r in rs]))
               for k in ('torques.p50_ms', 'torques.p99_ms', 'forces.p50_ms', 'forces.p99_ms')}
        base = base or med
        rel = {k: 100.0 * (med[k] / base[k] - 1.0) for k in med}
        lossless = sum(r['ok'] for r in rs)
        print(f'{mode:>12} | torques p50 {med["torques.p50_ms"]:6.1f} ms '
              f'({rel["torques.p50_ms"]:+.1f} %) p99 {med["torques.p99_ms"]:6.1f} '
              f'({rel["torques.p99_ms"]:+.1f} %) | forces p50 '
              f'{med["forces.p50_ms"]:6.1f} ({rel["forces.p50_ms"]:+.1f} %) p99 '
              f'{med["forces.p99_ms"]:6.1f} ({rel["forces.p99_ms"]:+.1f} %) | lossless '
              f'{lossless}/{len(rs)}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
