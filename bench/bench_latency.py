"""Live-graph benchmark (run by hand): accuracy vs look-ahead/window, latency, CPU, throughput.

    .venv/bin/python bench/bench_latency.py [--bag bags/reference_jump] [--rates 1 2 4 8]
                                            [--repeat 1] [--skip-graph]

1. Streaming vs batch without ROS (``nmt_ros.tracking.streaming``, the nodes' code path, fed the
   observations sample by sample with the skeletal tracker's polling rule):
   Stage 1 joint torques vs the batch ``track_stage1`` (same settings) for look-aheads 10..150 ms,
   RMS in % of each joint's peak (all samples; and the samples streamed before the final
   flush), and the look-ahead's share of the latency; Stage 2 muscle forces for windows H
   (fed the streamed Stage-1 output) vs the batch windowed Stage 2 on the batch Stage-1
   output (same H), and the batch windowed vs the full horizon, max over muscles of RMS/F0.
2. The graph as processes (``nmt launch --record``), for the accuracy-first and the
   low-latency parameter files, at each replay rate, on the bag and on the same jump preceded
   by ``--quiet-start`` seconds of quiet standing (so the start-up of the trackers, about
   0.1 s for the initial state, is over when the jump begins): latency from an observation's
   arrival to the torque / muscle-force estimate for that instant (the recorder's receive
   times; p50/p99/max), each
   node's CPU share while active, messages published == recorded, wall time. The fastest
   rate at which every message was recorded and every node finished is reported.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nmt_ros.cli.launch import config_path, run_graph  # noqa: E402
from nmt_ros.io.trial_bag import read_observations  # noqa: E402
from nmt_ros.model.jumper import default_model  # noqa: E402
from nmt_ros.model.parameters import JOINTS  # noqa: E402
from nmt_ros.tracking.conditioning import ConditioningSettings, condition  # noqa: E402
from nmt_ros.tracking.skeletal_tracker import SKTSettings  # noqa: E402
from nmt_ros.tracking.stage2 import NeuromuscularTracker  # noqa: E402
from nmt_ros.tracking.streaming import (  # noqa: E402
    Stage1Stream,
    Stage2Stream,
    initial_activations,
    track_stage1,
)

LOOKAHEADS = (0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.12, 0.15)
WINDOWS = (0.02, 0.03, 0.05, 0.1)


def stream_stage1(model, obs, skt, lookahead, poll_min=0.008):
    """Stage 1 as the node runs it: poll once the final horizon advanced poll_min."""
    stream = Stage1Stream(model, skt, ConditioningSettings(lookahead_s=lookahead))
    events = sorted([(t, 0, i) for i, t in enumerate(obs.t_angles)]
                    + [(t, 1, i) for i, t in enumerate(obs.t_wrench)])
    outs, polled = [], -np.inf
    for t, kind, i in events:
        (stream.add_angles if kind == 0 else stream.add_wrench)(
            t, (obs.angles if kind == 0 else obs.wrench)[i])
        if stream.final_until - polled >= poll_min:
            polled = stream.final_until
            out = stream.poll()
            if out is not None:
                outs.append(out)
    streamed = sum(o.t.size for o in outs)
    outs.append(stream.finish())
    outs = [o for o in outs if o is not None]
    cat = {k: np.concatenate([getattr(o, k) for o in outs]) for k in ('t', 'tau', 'q', 'qd')}
    return cat, streamed, stream.status


def stage2_stream(model, tracker, t, tau, th, thd, window, stride=0.01):
    stream = Stage2Stream(model, tracker, window, stride)
    outs = []
    for i in range(t.size):
        stream.add(i, t[i], tau[i], th[i], thd[i])
        if i % 9 == 8:
            outs.append(stream.process())
    outs.append(stream.process(final=True))
    return np.concatenate([o.f for o in outs if o is not None])


def accuracy_tables(bag: Path) -> None:
    model = default_model()
    obs = read_observations(bag)
    skt = SKTSettings().with_(substeps=1)
    c0 = time.process_time()
    batch = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench),
                         skt)
    batch_cpu = time.process_time() - c0
    default = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench))
    peak = np.abs(batch.tau).max(axis=0)
    d_sub = np.sqrt(np.mean((batch.tau - default.tau) ** 2, axis=0)) / peak * 100
    print(f'bag {bag}: {obs.t_angles.size} angle, {obs.t_wrench.size} force samples '
          f'({obs.t_wrench[-1]:.3f} s); batch Stage 1 (substeps 1) {batch_cpu:.2f} s CPU '
          f'= {batch_cpu / obs.t_wrench[-1]:.2f} x real time')
    print('substeps 1 vs the batch default (2): torque RMS % peak ' + ', '.join(
        f'{j} {v:.2f}' for j, v in zip(JOINTS, d_sub)))
    print('\n1a. Stage 1 streamed vs batch (same settings), RMS % of peak')
    print(f'{"look-ahead":>10} | {"ankle":>6} {"knee":>6} {"hip":>6} | streamed part: '
          f'{"ankle":>6} {"knee":>6} {"hip":>6} | streamed/all | CPU x real time')
    th_b, thd_b, thdd_b = (model.batch(model.joint_angles, x)[0]
                           for x in (batch.q, batch.qd, batch.qdd))
    tracker = NeuromuscularTracker(model)
    a0, _ = initial_activations(model, th_b[0], batch.tau[0], thd_b[0])
    streams = {}
    for la in LOOKAHEADS:
        c0 = time.process_time()
        out, n_stream, status = stream_stage1(model, obs, skt, la)
        cpu = time.process_time() - c0
        streams[la] = out
        # Tracking ends a few ms after the tracked lift-off, which the stream and the batch
        # may place one or two samples apart: compare the common samples.
        n = min(out['t'].size, batch.t.size)
        err = np.sqrt(np.mean((out['tau'][:n] - batch.tau[:n]) ** 2, axis=0)) / peak * 100
        es = np.sqrt(np.mean((out['tau'][:n_stream] - batch.tau[:n_stream]) ** 2, axis=0)
                     ) / peak * 100 if n_stream else np.full(3, np.nan)
        print(f'{la * 1e3:8.0f} ms | {err[0]:6.2f} {err[1]:6.2f} {err[2]:6.2f} | '
              f'{"":14s}{es[0]:6.2f} {es[1]:6.2f} {es[2]:6.2f} | {n_stream:4d}/{out["t"].size}'
              f' | {cpu / obs.t_wrench[-1]:.2f} {status if status != "ok" else ""}')
    print('   latency of a torque estimate >= look-ahead + up to one mocap period (8.3 ms) '
          '+ compute')
    print('\n1b. Stage 2 muscle forces, max over muscles of RMS / F0 [%]')
    print(f'{"H":>6} | windowed vs full horizon (batch) | stream vs batch windowed, Stage 1 '
          f'look-ahead: ' + ' '.join(f'{la * 1e3:5.0f}ms' for la in (0.02, 0.05, 0.1)))
    full = tracker.track(batch.t, batch.tau, th_b, thd_b, thdd_b, a0, mode='full')
    for h in WINDOWS:
        ref = tracker.track(batch.t, batch.tau, th_b, thd_b, thdd_b, a0, mode='windowed',
                            window_length=h, window_stride=0.01)
        vs_full = (np.sqrt(np.mean((ref.f - full.f) ** 2, axis=0)) / tracker.f0).max() * 100
        cells = []
        for la in (0.02, 0.05, 0.1):
            s = streams[la]
            th, thd = (model.batch(model.joint_angles, x)[0] for x in (s['q'], s['qd']))
            f = stage2_stream(model, tracker, s['t'], s['tau'], th, thd, h)
            n = min(f.shape[0], ref.f.shape[0])
            cells.append((np.sqrt(np.mean((f[:n] - ref.f[:n]) ** 2, axis=0)) / tracker.f0).max()
                         * 100)
        print(f'{h * 1e3:4.0f}ms | {vs_full:32.2f} | {"":40s}' +
              ' '.join(f'{c:7.2f}' for c in cells))
    print('   stride 10 ms, saturation plan; latency of a force estimate >= Stage-1 latency '
          '+ H + up to a stride')


def padded_bag(bag: Path, pad_s: float, out: Path) -> Path:
    """The bag's observations after ``pad_s`` of quiet standing (the first sample held), as a
    lab trial starts: the tracker's start-up (initial state) is then over before the jump."""
    from nmt_ros.io.trial_bag import write_trial_bag
    from nmt_ros.records import Observations

    obs = read_observations(bag)
    na, nw = int(round(pad_s * 120)), int(round(pad_s * 1080))
    angles = np.vstack([np.repeat(obs.angles[:1], na, axis=0), obs.angles])
    wrench = np.vstack([np.repeat(obs.wrench[:1], nw, axis=0), obs.wrench])
    padded = Observations(t_angles=np.arange(angles.shape[0]) / 120.0, angles=angles,
                          t_wrench=np.arange(wrench.shape[0]) / 1080.0, wrench=wrench,
                          frame_id=obs.frame_id)
    write_trial_bag(out, padded)
    return out


def graph_tables(bag: Path, rates: list[float], repeat: int, label: str = '') -> None:
    from nmt_ros.study.recording_evaluation import graph_summary

    print(f'\n2. the graph as processes (nmt launch --record){label}, latency from an '
          'observation\'s arrival (receive times) [ms]')
    header = (f'{"params":>12} {"rate":>5} | torques p50 p99 max | forces p50 p99 max | '
              'CPU share obs/skel/musc/rec | lossless | wall s')
    print(header)
    best: dict[str, float] = {}
    for name in ('nmt_graph.yaml', 'nmt_graph_low_latency.yaml'):
        for rate in rates:
            for _ in range(repeat):
                with tempfile.TemporaryDirectory(prefix='nmt_bench_') as tmp:
                    rec = Path(tmp) / 'rec'
                    res = run_graph(bag=bag, rate=rate, record=rec,
                                    params=config_path(name), log_dir=Path(tmp) / 'logs')
                    if not (rec / 'metadata.yaml').exists():
                        print(f'{name:>12} {rate:5g} | failed: {res.problems}')
                        continue
                    s = graph_summary(rec, None, batch=False)
                lt, lf = s['latency_ms']['joint_torques'], s['latency_ms']['muscle_forces']
                cpu = '/'.join(f'{s["cpu"].get(n, {}).get("share", float("nan")):.2f}'
                               for n in ('observation_publisher', 'skeletal_tracker',
                                         'muscle_tracker', 'recorder'))
                ok = s['lossless'] and res.returncode == 0
                if ok:
                    best[name] = max(best.get(name, 0.0), rate)
                print(f'{name.replace("nmt_graph", "").strip("_.yaml") or "accuracy":>12} '
                      f'{rate:5g} | {lt["p50_ms"]:7.1f} {lt["p99_ms"]:5.1f} {lt["max_ms"]:5.1f}'
                      f' | {lf["p50_ms"]:6.1f} {lf["p99_ms"]:5.1f} {lf["max_ms"]:5.1f} | '
                      f'{cpu:>27} | {str(ok):>8} | {res.wall_s:5.1f}'
                      + ('' if res.returncode == 0 else f'  {res.problems}'))
    for name, rate in best.items():
        print(f'fastest rate with every message recorded and every node finished ({name}): '
              f'{rate:g}x (of {rates})')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bag', type=Path, default=ROOT / 'bags' / 'reference_jump')
    parser.add_argument('--rates', type=float, nargs='+', default=[1.0, 2.0, 4.0, 8.0])
    parser.add_argument('--repeat', type=int, default=1)
    parser.add_argument('--skip-graph', action='store_true')
    parser.add_argument('--skip-accuracy', action='store_true')
    parser.add_argument('--quiet-start', type=float, default=0.4, metavar='S',
                        help='also run the graph on the bag preceded by S s of quiet standing '
                             '(0: do not; Stage 1 itself loses control after ~0.7 s of a held '
                             'first sample, also in batch)')
    args = parser.parse_args()
    from nmt_ros.cli.main import ros_environment_defaults

    ros_environment_defaults()
    if not args.skip_accuracy:
        accuracy_tables(args.bag)
    if not args.skip_graph:
        graph_tables(args.bag, args.rates, args.repeat)
        if args.quiet_start > 0:
            with tempfile.TemporaryDirectory(prefix='nmt_bench_bag_') as tmp:
                bag = padded_bag(args.bag, args.quiet_start, Path(tmp) / 'padded')
                graph_tables(bag, args.rates, args.repeat,
                             f' on the jump after {args.quiet_start:g} s of quiet standing')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
