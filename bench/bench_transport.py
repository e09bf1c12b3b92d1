"""Transport benchmark (run by hand): what rclpy costs per message here, and whether the
publisher holds its schedule and the recorder keeps up.

    .venv/bin/python bench/bench_transport.py [--seconds 5] [--sections subscribe publish
        recorder] [--rates 1 4] [--hog] [--recorder-python PY]

1. ``subscribe``: CPU per received message [us] (all threads of the subscriber process, so
   the middleware's receive threads count) for WrenchStamped and JointState at 1080 Hz (and
   some modes at 4320 Hz, where batching pays),
   RELIABLE KEEP_LAST 5000, with a callback per message under rclpy's SingleThreadedExecutor,
   MultiThreadedExecutor and EventsExecutor (``rclpy.experimental``), typed and raw, and
   with the recorder's batched take (``nmt_ros.nodes.polled_subscriptions``, every 10 ms).
2. ``publish``: CPU per ``publish`` call [us] (typed message vs CDR bytes) at 1080 Hz, and the
   timing of a drift-free sleep-until-deadline loop: lateness of each send vs the nominal
   schedule (p50/p99/max) and the achieved rate.
3. ``recorder``: the graph's transport at each rate: ``nmt run observation_publisher`` on the
   shipped bag looped to ``--seconds`` of data, a load process publishing the seven estimate
   topics at the force-plate rate (JointState, in batches every 1/120 s as the trackers
   publish), ``nmt run recorder`` (of ``--recorder-python``'s checkout, so the recorder of
   another branch can be compared), optionally a CPU hog (``--hog``: a busy loop in another
   process). Reported: messages published vs recorded per topic, the publisher's lateness
   p50/p99 and wall time vs nominal, each process's CPU share.

Timing figures depend on the machine's load: say what else was running when quoting them.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RATE_HZ = 1080.0
DEPTH = 5000
ESTIMATE_TOPICS = ('/nmt/skeletal/joint_torques', '/nmt/skeletal/segment_angles',
                   '/nmt/skeletal/generalized_coordinates', '/nmt/skeletal/ground_wrench',
                   '/nmt/muscle/forces', '/nmt/muscle/activations', '/nmt/muscle/excitations')
SUBSCRIBE_MODES = ('single-typed', 'single-raw', 'multi-typed', 'multi-raw', 'events-typed',
                   'events-raw', 'polled-raw', 'polled-typed')
FAST_MODES = ('single-raw', 'events-typed', 'polled-raw', 'polled-typed')   # also at 4x


def environment() -> dict[str, str]:
    from nmt_ros.cli.launch import ros_environment

    env = ros_environment()
    env.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    return env


def role(name: str, *args: object) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), '--role', name, *map(str, args)]


def qos():
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE)


def message(kind: str):
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    if kind == 'wrench':
        return WrenchStamped
    msg = JointState()
    msg.name = ['gmax', 'ilpso', 'hams', 'bfsh', 'rf', 'vas', 'gas', 'sol', 'ta']
    msg.position = [0.1] * 9
    msg.velocity = [0.2] * 9
    msg.effort = [300.0] * 9
    return msg


def message_type(kind: str) -> type:
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    return WrenchStamped if kind == 'wrench' else JointState


def percentiles(values: list[float]) -> dict[str, float]:
    import numpy as np

    if not values:
        return {'p50': float('nan'), 'p99': float('nan'), 'max': float('nan')}
    a = np.asarray(values)
    return {'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99)),
            'max': float(a.max())}


# --------------------------------------------------------------------------- roles

def role_publisher(kind: str, mode: str, seconds: float, rate_hz: float) -> None:
    """Publish ``kind`` at ``rate_hz`` on /bench for ``seconds`` (sleep until each deadline)."""
    import rclpy
    from rclpy.duration import Duration
    from rclpy.serialization import serialize_message

    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    pub = node.create_publisher(message_type(kind), '/bench', qos())
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)
    msg = message(kind)
    msg = msg() if isinstance(msg, type) else msg
    payload = serialize_message(msg) if mode == 'raw' else msg
    n = int(seconds * rate_hz)
    late, cpu = [], 0.0
    start = time.monotonic_ns()
    period = 1e9 / rate_hz
    for i in range(n):
        due = start + int(i * period)
        wait = due - time.monotonic_ns()
        if wait > 0:
            time.sleep(wait * 1e-9)
        c0 = time.process_time()
        late.append((time.monotonic_ns() - due) / 1e6)
        pub.publish(payload)
        cpu += time.process_time() - c0
    wall = (time.monotonic_ns() - start) / 1e9
    pub.wait_for_all_acked(Duration(seconds=10))
    print(json.dumps({'n': n, 'cpu_us_per_publish': cpu / n * 1e6, 'late_ms': percentiles(late),
                      'rate_hz': n / wall}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def role_subscriber(kind: str, mode: str, count: int) -> None:
    """Receive ``count`` messages on /bench in ``mode``; print CPU per message."""
    import rclpy
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

    rclpy.init()
    node = rclpy.create_node('bench_subscriber')
    executor_name, how = mode.split('-')
    raw = how == 'raw'
    got = [0]
    if executor_name == 'polled':
        from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions

        inputs = PolledSubscriptions(node)
        inputs.add('/bench', message_type(kind), qos(), raw=raw)

        def take() -> None:
            got[0] += sum(len(v) for v in inputs.take_all().values())
        node.create_timer(0.01, take)
        executor = SingleThreadedExecutor()
    else:
        def on_message(*_args: object) -> None:
            got[0] += 1
        node.create_subscription(message_type(kind), '/bench', on_message, qos(), raw=raw)
        if executor_name == 'events':
            from rclpy.experimental import EventsExecutor

            executor = EventsExecutor()
        else:
            executor = (SingleThreadedExecutor() if executor_name == 'single'
                        else MultiThreadedExecutor())
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 60
        while got[0] == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        c0, w0, n0 = time.process_time(), time.monotonic(), got[0]
        while got[0] < count and time.monotonic() - w0 < 60:
            executor.spin_once(timeout_sec=0.2)
        cpu, wall, n = time.process_time() - c0, time.monotonic() - w0, got[0] - n0
        print(json.dumps({'n': n, 'cpu_us_per_msg': cpu / max(n, 1) * 1e6,
                          'cpu_share': cpu / wall}), flush=True)
    except Exception as exc:  # noqa: BLE001 - reported as the mode's result
        print(json.dumps({'error': f'{exc.__class__.__name__}: {exc}'}), flush=True)


def role_load(seconds: float, rate: float) -> None:
    """The seven estimate topics at the force-plate rate x ``rate``, in batches of 1/120 s."""
    import rclpy
    from rclpy.duration import Duration

    from nmt_ros.nodes.node_base import data_qos

    rclpy.init()
    node = rclpy.create_node('bench_load')
    pubs = [node.create_publisher(message_type('joint'), t, data_qos(DEPTH))
            for t in ESTIMATE_TOPICS]
    deadline = time.monotonic() + 60
    while any(p.get_subscription_count() == 0 for p in pubs) and time.monotonic() < deadline:
        time.sleep(0.01)
    msg = message('joint')
    batches = int(seconds * 120)
    per_batch = int(RATE_HZ / 120)
    start = time.monotonic()
    c0 = time.process_time()
    for b in range(batches):
        wait = start + b / (120 * rate) - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        for _ in range(per_batch):
            for p in pubs:
                p.publish(msg)
    wall = time.monotonic() - start
    cpu = time.process_time() - c0
    for p in pubs:
        p.wait_for_all_acked(Duration(seconds=10))
    print(json.dumps({'published': {t: batches * per_batch for t in ESTIMATE_TOPICS},
                      'wall_s': wall, 'cpu_share': cpu / wall}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def role_hog(seconds: float) -> None:
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


# --------------------------------------------------------------------------- sections

def run_json(cmd: list[str], env: dict[str, str], timeout: float = 120) -> dict:
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    lines = [line for line in out.stdout.splitlines() if line.startswith('{')]
    if not lines:
        return {'error': (out.stderr.strip().splitlines() or ['no output'])[-1]}
    return json.loads(lines[-1])


def section_subscribe(seconds: float) -> None:
    env = environment()
    print('\n1. subscribe: CPU per received message (subscriber process, all threads)')
    print(f'{"type":14s} {"mode":14s} {"rate":>5s} {"us/msg":>8s} {"share":>6s}')
    runs = [(kind, mode, RATE_HZ) for kind in ('wrench', 'joint') for mode in SUBSCRIBE_MODES]
    runs += [('wrench', mode, 4 * RATE_HZ) for mode in FAST_MODES]
    for kind, mode, rate_hz in runs:
        n = int(seconds * rate_hz)
        sub = subprocess.Popen(role('subscriber', kind, mode, n - 10), env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        pub = subprocess.Popen(role('publisher', kind, 'raw', seconds, rate_hz), env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            out, err = sub.communicate(timeout=seconds + 60)
        except subprocess.TimeoutExpired:
            sub.kill()
            out, err = sub.communicate()
        pub.kill()
        pub.wait()
        lines = [line for line in out.splitlines() if line.startswith('{')]
        res = json.loads(lines[-1]) if lines else {
            'error': (err.strip().splitlines() or ['crashed'])[-1][:70]}
        name = 'WrenchStamped' if kind == 'wrench' else 'JointState(9)'
        label = mode + ('*' if mode == 'events-raw' else '')
        if 'error' in res:
            print(f'{name:14s} {label:14s} {rate_hz:5.0f} failed: {res["error"]}')
        else:
            print(f'{name:14s} {label:14s} {rate_hz:5.0f} {res["cpu_us_per_msg"]:8.1f} '
                  f'{res["cpu_share"]:6.3f}')
    print('  * the EventsExecutor of Jazzy calls a raw callback with the bytes only: a '
          'callback taking (data, message info), which a recorder needs for the receive and '
          'send times, fails with "SystemError: null argument to internal routine"')


def section_publish(seconds: float) -> None:
    env = environment()
    print('\n2. publish at 1080 Hz, sleep-until-deadline loop (one polled subscriber)')
    print(f'{"type":14s} {"payload":8s} {"us/publish":>10s} {"late p50":>9s} {"p99":>7s} '
          f'{"max [ms]":>9s} {"rate [Hz]":>10s}')
    for kind in ('wrench', 'joint'):
        for mode in ('typed', 'raw'):
            sub = subprocess.Popen(role('subscriber', kind, 'polled-raw',
                                        int(seconds * RATE_HZ) - 10), env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            res = run_json(role('publisher', kind, mode, seconds, RATE_HZ), env,
                           timeout=seconds + 60)
            sub.kill()
            sub.wait()
            name = 'WrenchStamped' if kind == 'wrench' else 'JointState(9)'
            if 'error' in res:
                print(f'{name:14s} {mode:8s} failed: {res["error"]}')
                continue
            late = res['late_ms']
            print(f'{name:14s} {mode:8s} {res["cpu_us_per_publish"]:10.1f} {late["p50"]:9.3f} '
                  f'{late["p99"]:7.3f} {late["max"]:9.3f} {res["rate_hz"]:10.1f}')


def section_recorder(seconds: float, rates: list[float], hog: bool, recorder_python: str,
                     bag: Path) -> None:
    from nmt_ros.io.bag_loop import loop_bag
    from nmt_ros.io.bags import bag_info
    from nmt_ros.study.recording_evaluation import final_statuses
    from nmt_ros.topics import OBSERVATIONS

    env = environment()
    work = Path(tempfile.mkdtemp(prefix='bench_transport_'))
    looped = work / 'looped'
    loop_bag(bag, looped, seconds, OBSERVATIONS)
    print(f'\n3. recorder: {seconds:g} s of observations ({looped}) + 7 estimate topics at '
          f'1080 Hz x rate{" + CPU hog" if hog else ""}; recorder: {recorder_python}')
    for rate in rates:
        out = work / f'rec_{rate:g}'
        nmt = [sys.executable, '-m', 'nmt_ros.cli.main']
        rec_cmd = [recorder_python, '-m', 'nmt_ros.cli.main', 'run', 'recorder',
                   '--ros-args', '-p', f'output:={out}', '-p', 'exclude:=[/rosout]']
        recorder = subprocess.Popen(rec_cmd, env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.STDOUT, cwd=work)
        hogger = (subprocess.Popen(role('hog', seconds / rate + 30), env=env)
                  if hog else None)
        load = subprocess.Popen(role('load', seconds, rate), env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True)
        time.sleep(1.0)
        publisher = subprocess.Popen(nmt + ['run', 'observation_publisher', '--ros-args', '-p',
                                            f'bag:={looped}', '-p', f'rate:={rate}', '-p',
                                            'expected_subscribers:=1'],
                                     env=env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.STDOUT)
        start = time.monotonic()
        load_out, _ = load.communicate(timeout=seconds / rate + 120)
        publisher.wait(timeout=seconds / rate + 120)
        wall = time.monotonic() - start
        time.sleep(1.0)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=120)
        if hogger is not None:
            hogger.kill()
            hogger.wait()
        published = json.loads(load_out.strip().splitlines()[-1])['published']
        statuses = final_statuses(out)
        pub_status = statuses.get('observation_publisher', {})
        for key, value in pub_status.items():
            if key.startswith('published.'):
                published[key[len('published.'):]] = int(value)
        recorded = {t.name: t.message_count for t in bag_info(out).topics}
        lost = {t: n - recorded.get(t, 0) for t, n in published.items()
                if recorded.get(t, 0) != n}
        rec_status = statuses.get('recorder', {})
        total = sum(published.values())
        print(f'  rate {rate:g}: {total} messages ({total / (seconds / rate):.0f}/s), '
              f'{"none lost" if not lost else f"LOST {lost}"}; wall {wall:.1f} s '
              f'(nominal {seconds / rate:.1f} s)')
        print(f'    publisher: late p50 {float(pub_status.get("late_p50_ms", "nan")):.3f} ms, '
              f'p99 {float(pub_status.get("late_p99_ms", "nan")):.3f} ms, max '
              f'{float(pub_status.get("max_late_ms", "nan")):.1f} ms, CPU share '
              f'{float(pub_status.get("cpu_share", "nan")):.2f}; recorder: CPU share '
              f'{float(rec_status.get("cpu_share", "nan")):.2f}, largest take '
              f'{rec_status.get("largest_take", "?")}, '
              f'queue peak {rec_status.get("queue_max_mb", "?")} MiB')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--role', nargs='+', help=argparse.SUPPRESS)
    parser.add_argument('--seconds', type=float, default=5.0,
                        help='stream length per measurement [s] (default 5)')
    parser.add_argument('--sections', nargs='+', default=['subscribe', 'publish', 'recorder'],
                        choices=['subscribe', 'publish', 'recorder'])
    parser.add_argument('--rates', type=float, nargs='+', default=[1.0, 4.0])
    parser.add_argument('--hog', action='store_true', help='run a CPU hog beside the recorder')
    parser.add_argument('--bag', type=Path, default=ROOT / 'bags' / 'reference_jump')
    parser.add_argument('--recorder-python', default=sys.executable,
                        help="python of the checkout whose recorder is measured")
    args = parser.parse_args()
    if args.role:
        name, rest = args.role[0], args.role[1:]
        if name == 'publisher':
            role_publisher(rest[0], rest[1], float(rest[2]), float(rest[3]))
        elif name == 'subscriber':
            role_subscriber(rest[0], rest[1], int(rest[2]))
        elif name == 'load':
            role_load(float(rest[0]), float(rest[1]))
        elif name == 'hog':
            role_hog(float(rest[0]))
        return 0
    print(f'machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start')
    if 'subscribe' in args.sections:
        section_subscribe(args.seconds)
    if 'publish' in args.sections:
        section_publish(args.seconds)
    if 'recorder' in args.sections:
        section_recorder(args.seconds, args.rates, args.hog, args.recorder_python, args.bag)
    print(f'load average {os.getloadavg()[0]:.2f} at the end')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
