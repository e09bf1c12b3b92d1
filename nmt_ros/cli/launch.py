"""``nmt launch``: the whole node graph, one process per node, until the replay is processed.

    nmt launch [--bag BAG] [--rate R] [--record OUT_BAG_DIR] [--params FILE] [--clock]
               [--view [--view-host ADDR] [--view-port PORT]]

Starts ``recorder`` (with ``--record``), ``muscle_tracker``, ``skeletal_tracker`` and
``observation_publisher`` as separate processes (``python -m nmt_ros.nodes.<node> --ros-args
--params-file <merged file>``), with the environment of this process (so
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, ``ROS_LOCALHOST_ONLY=1`` and ``ROS_DOMAIN_ID``
are inherited; ``OPENBLAS_NUM_THREADS``/``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` default to 1;
unless a Fast DDS profile is already chosen, ``config/fastdds_profile.xml``
shortens the reliable heartbeat so end-of-replay acknowledgements take ms, not 3 s).
Readiness propagates upstream: each tracker opens its inputs only when its outputs have
their subscribers (``wait_for``), and the replay starts only when the
observation topics have theirs (``expected_subscribers``), so no message is published before
its consumers exist. With ``--view`` the ``viewer`` node (Foxglove WebSocket server,
``nmt_ros.nodes.viewer``) is one of those consumers: its server listens and has advertised
every graph topic before the replay starts, so a viewer that connected first misses nothing.

The run ends when the observation publisher has replayed everything (and every reliable
subscriber acknowledged it), the trackers have flushed their last look-ahead/window and
exited (their outputs acknowledged too), and the recorder has taken every queued message and
finalised the bag (SIGINT). Exit code 0 when every node succeeded, 1 otherwise, 130 when
interrupted: SIGINT/SIGTERM to ``nmt launch`` is passed on to the nodes, so the recorder still
closes its bag (an interrupted recording stays readable). A launcher killed outright
(SIGKILL) takes its nodes with it: each gets SIGTERM from Linux when it dies
(``nmt_ros.nodes.launcher_link``), and the recorder still finalises its bag.

The parameters are ``config/nmt_graph.yaml`` (or ``--params FILE``, same shape: one
``<node>: ros__parameters:`` section per node) with the command-line choices and the
readiness settings merged on top; the merged file and each node's log go to ``--log-dir``.
"""
from __future__ import annotations

import argparse
from collections.abc import Mapping
import copy
from dataclasses import dataclass, field
from functools import partial
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

import yaml

from nmt_ros.nodes.launcher_link import launched_environment
from nmt_ros.topics import MUSCLE_OUTPUTS, SKELETAL_OUTPUTS

PACKAGE_ROOT = Path(__file__).resolve().parents[2]
NODES = ('viewer', 'recorder', 'muscle_tracker', 'skeletal_tracker', 'observation_publisher')
TRACKERS = ('muscle_tracker', 'skeletal_tracker')
#: Niceness of the nodes that yield the CPU when the cores are short (the others keep 0):
#: the recorder's queues are deep, and the muscle tracker waits for the skeletal tracker's
#: torques anyway, so the skeletal tracker, upstream of every estimate, goes first.
NODE_NICE = {'recorder': 5, 'muscle_tracker': 3}


def config_path(name: str) -> Path:
    """A shipped config file: source tree ``config/``, else the ament share directory."""
    local = PACKAGE_ROOT / 'config' / name
    if local.exists():
        return local
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory('nmt_ros')) / 'config' / name
    except Exception:  # noqa: BLE001 - no ament index: report the source-tree path
        return local


def default_bag() -> Path:
    return PACKAGE_ROOT / 'bags' / 'reference_jump'


#: Thread pools of numpy's BLAS/LAPACK (OpenBLAS, MKL) and OpenMP: one thread per node process
#: unless the user chose. Each node's factorisations are small; on 2 cores shared by four node
#: processes a multithreaded BLAS spins its threads against the others' and was measured 100x
#: slower for small factorisations under load.
SINGLE_THREADED_MATH = {'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1',
                        'MKL_NUM_THREADS': '1'}


def ros_environment() -> dict[str, str]:
    """This process's environment with the loopback-only ROS defaults, single-threaded BLAS
    (:data:`SINGLE_THREADED_MATH`, where the user set nothing) and unbuffered output."""
    env = dict(os.environ)
    for key, value in SINGLE_THREADED_MATH.items():
        env.setdefault(key, value)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('ROS_LOCALHOST_ONLY', '1')
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    if not (env.get('FASTRTPS_DEFAULT_PROFILES_FILE') or env.get('FASTDDS_DEFAULT_PROFILES_FILE')):
        profile = config_path('fastdds_profile.xml')
        if profile.exists():
            env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)
    env['PYTHONUNBUFFERED'] = '1'
    return env


def load_params(path: str | os.PathLike) -> dict[str, Any]:
    data = yaml.safe_load(Path(path).read_text(encoding='utf-8')) or {}
    if not isinstance(data, dict):
        raise ValueError(f'{path}: expected a mapping of node sections')
    return data


def _section(params: dict[str, Any], node: str) -> dict[str, Any]:
    return params.setdefault(node, {}).setdefault('ros__parameters', {})


def bag_parameters(bag: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """What the trackers must know of a bag: its rates (from the header stamps), its
    subject (``BAG/subject.yaml`` when there is one, else the shipped jumper) and, for a lab
    recording whose import found a support the plates do not measure (a drop jump's box),
    the step-off the estimator starts at (``nmt import-lab``'s momentum balance)."""
    from nmt_ros.io.trial_bag import observation_rates
    from nmt_ros.model.subject import subject_file

    angle_rate, wrench_rate = observation_rates(bag)
    subject = subject_file(bag)
    subject = '' if subject is None else str(subject.resolve())
    skeletal = {'angle_rate_hz': angle_rate, 'wrench_rate_hz': wrench_rate,
                'subject_file': subject}
    step_off = imported_step_off_s(bag)
    if step_off is not None:
        skeletal['start_s'] = step_off
    return {'skeletal_tracker': skeletal,
            'muscle_tracker': {'input_rate_hz': wrench_rate, 'subject_file': subject}}


def imported_step_off_s(bag: str | os.PathLike) -> float | None:
    """The step-off after an unmeasured support that ``nmt import-lab`` recorded in the
    bag's metadata (``nmt.import`` momentum_balance step_off_s) [s, trial time], or None."""
    from nmt_ros.io.bags import bag_info

    facts = (bag_info(bag).custom_data or {}).get('nmt.import')
    if not facts:
        return None
    value = (json.loads(facts).get('momentum_balance') or {}).get('step_off_s')
    return None if value is None else float(value)


def graph_parameters(base: Mapping[str, Any], *, bag: str | os.PathLike | None = None,
                     rate: float | None = None, record: str | os.PathLike | None = None,
                     publish_clock: bool = False, view: bool = False) -> dict[str, Any]:
    """``base`` (node sections) plus the run's choices and the readiness chain (``view``:
    the viewer subscribes to every data topic, so each has one subscriber more)."""
    params = copy.deepcopy(dict(base))
    obs = _section(params, 'observation_publisher')
    if bag is not None:
        obs['bag'] = str(Path(bag).resolve())
        for node, values in bag_parameters(bag).items():
            section = _section(params, node)
            for k, v in values.items():
                section.setdefault(k, v)      # a parameter file's value wins
    if rate is not None:
        obs['rate'] = float(rate)
    if publish_clock:
        obs['publish_clock'] = True
    recording = record is not None
    others = int(recording) + int(view)      # consumers besides the trackers
    obs['expected_subscribers'] = 1 + others
    obs['exit_when_finished'] = True
    skel = _section(params, 'skeletal_tracker')
    # joint torques feed the muscle tracker (and the recorder, the viewer); the rest only those
    skel['wait_for'] = [f'{SKELETAL_OUTPUTS[0]}={1 + others}'] + (
        [f'{t}={others}' for t in SKELETAL_OUTPUTS[1:]] if others else [])
    skel['exit_when_finished'] = True
    muscle = _section(params, 'muscle_tracker')
    muscle['wait_for'] = [f'{t}={others}' for t in MUSCLE_OUTPUTS] if others else ['']
    muscle['exit_when_finished'] = True
    if recording:
        _section(params, 'recorder')['output'] = str(Path(record).resolve())
    else:
        params.pop('recorder', None)
    if not view:
        params.pop('viewer', None)
    return params


@dataclass
class GraphRun:
    """What ``run_graph`` did."""

    returncode: int
    node_returncodes: dict[str, int | None]
    record: Path | None
    log_dir: Path
    params_file: Path
    wall_s: float
    interrupted: bool = False
    problems: list[str] = field(default_factory=list)


def _last_error(log: Path) -> str:
    """': <last ERROR line>' of a node's log, or ''."""
    try:
        lines = log.read_text(errors='replace').splitlines()
    except OSError:
        return ''
    errors = [line for line in lines if '[ERROR]' in line or 'Error' in line]
    return f': {errors[-1].strip()[-200:]}' if errors else ''


def _lower_priority(increment: int) -> None:
    """The node yields the CPU to the others (``NODE_NICE``)."""
    try:
        os.nice(increment)
    except OSError:
        pass


def _stop(procs: Mapping[str, subprocess.Popen], names: tuple[str, ...] | None = None,
          grace_s: float = 15.0) -> None:
    """SIGINT the (alive) processes, wait up to ``grace_s``, then SIGKILL what is left."""
    chosen = [procs[n] for n in (names or tuple(procs)) if n in procs]
    for p in chosen:
        if p.poll() is None:
            try:
                p.send_signal(signal.SIGINT)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace_s
    for p in chosen:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _wait(procs: Mapping[str, subprocess.Popen], names: tuple[str, ...], deadline: float,
          problems: list[str]) -> bool:
    """Wait until ``names`` exited; False (with a problem noted) on timeout or when another
    node died first."""
    others = [n for n in procs if n not in names]
    while True:
        if all(procs[n].poll() is not None for n in names if n in procs):
            return True
        for n in others:
            rc = procs[n].poll()
            if rc not in (None, 0):
                problems.append(f'{n} failed with code {rc}')
                return False
        if time.monotonic() > deadline:
            late = [n for n in names if n in procs and procs[n].poll() is None]
            problems.append(f'timed out waiting for {late}')
            return False
        time.sleep(0.05)


def run_graph(*, bag: str | os.PathLike | None = None, rate: float = 1.0,
              record: str | os.PathLike | None = None,
              params: str | os.PathLike | None = None,
              log_dir: str | os.PathLike | None = None, timeout_s: float = 120.0,
              publish_clock: bool = False, extra_params: Mapping[str, Any] | None = None,
              view: Mapping[str, Any] | None = None) -> GraphRun:
    """Run the graph once (see the module docstring); never raises on node failures.
    ``view``: the viewer node's parameters (host, port, ...) to serve the live view."""
    bag = Path(bag) if bag is not None else default_bag()
    log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix='nmt_launch_'))
    log_dir.mkdir(parents=True, exist_ok=True)
    base = load_params(params or config_path('nmt_graph.yaml'))
    merged = graph_parameters(base, bag=bag, rate=rate, record=record,
                              publish_clock=publish_clock, view=view is not None)
    if view is not None:
        subject = _section(merged, 'skeletal_tracker').get('subject_file', '')
        _section(merged, 'viewer').update({'subject_file': subject, **view})
    for node, values in (extra_params or {}).items():
        _section(merged, node).update(values)
    params_file = log_dir / 'params.yaml'
    params_file.write_text(yaml.safe_dump(merged, sort_keys=False), encoding='utf-8')
    names = [n for n in NODES if (n != 'recorder' or record is not None)
             and (n != 'viewer' or view is not None)]
    env = launched_environment(ros_environment())   # the nodes end if this process dies
    procs: dict[str, subprocess.Popen] = {}
    logs = {}
    problems: list[str] = []
    interrupted = False
    start = time.monotonic()
    previous_term = signal.getsignal(signal.SIGTERM)

    def on_term(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    try:
        for name in names:
            logs[name] = open(log_dir / f'{name}.log', 'wb')  # noqa: SIM115 (closed below)
            procs[name] = subprocess.Popen(
                [sys.executable, '-m', f'nmt_ros.nodes.{name}', '--ros-args',
                 '--params-file', str(params_file)],
                env=env, stdout=logs[name], stderr=subprocess.STDOUT,
                preexec_fn=(partial(_lower_priority, NODE_NICE[name]) if name in NODE_NICE
                            else None))
        deadline = start + timeout_s
        ok = _wait(procs, ('observation_publisher',), deadline, problems)
        if ok:
            ok = _wait(procs, TRACKERS, deadline, problems)
        if not ok:
            _stop(procs, tuple(n for n in names if n != 'recorder'))
        if 'recorder' in procs:
            _stop(procs, ('recorder',), grace_s=30.0)
        _stop(procs)
    except KeyboardInterrupt:
        interrupted = True
        problems.append('interrupted')
        _stop(procs, tuple(n for n in names if n not in ('recorder', 'viewer')), grace_s=10.0)
        _stop(procs, ('viewer',), grace_s=5.0)
        _stop(procs, ('recorder',), grace_s=30.0)
    finally:
        signal.signal(signal.SIGTERM, previous_term)
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in logs.values():
            f.close()
    codes = {n: p.returncode for n, p in procs.items()}
    for n, rc in codes.items():
        if rc not in (0, None) and not interrupted:
            why = 'stopped' if rc < 0 else f'exited with code {rc}'
            problems.append(f'{n} {why}{_last_error(log_dir / (n + ".log"))} '
                            f'(log: {log_dir / (n + ".log")})')
    record_path = Path(record) if record is not None else None
    if record_path is not None and not (record_path / 'metadata.yaml').exists():
        problems.append(f'the recording {record_path} has no metadata.yaml')
        try:
            from nmt_ros.io.bags import reindex

            reindex(record_path)
            problems.append(f'repaired {record_path} with reindex')
        except Exception as exc:  # noqa: BLE001 - reported
            problems.append(f'reindex of {record_path} failed: {exc}')
    returncode = 130 if interrupted else (0 if not problems else 1)
    return GraphRun(returncode=returncode, node_returncodes=codes, record=record_path,
                    log_dir=log_dir, params_file=params_file,
                    wall_s=time.monotonic() - start, interrupted=interrupted,
                    problems=problems)


# --------------------------------------------------------------------------- CLI

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=None, help='bag with the observation topics '
                        '(default: bags/reference_jump)')
    parser.add_argument('--rate', type=float, default=1.0, help='replay speed factor')
    parser.add_argument('--record', default=None, metavar='OUT_BAG_DIR',
                        help='record every topic into this new bag folder')
    parser.add_argument('--params', default=None, metavar='FILE',
                        help='parameter file with one section per node '
                             '(default: config/nmt_graph.yaml)')
    parser.add_argument('--clock', action='store_true', help='publish /clock during the replay')
    parser.add_argument('--log-dir', default=None, help='node logs and the merged parameters '
                        '(default: a new temporary folder)')
    parser.add_argument('--duration', type=float, default=0.0, metavar='S',
                        help='replay only the first S seconds of the bag (default: all)')
    parser.add_argument('--start', type=float, default=None, metavar='S',
                        help='the skeletal tracker estimates from S s of trial time on '
                             '(default: the step-off nmt import-lab found after an unmeasured '
                             'support, else the first sample)')
    parser.add_argument('--timeout', type=float, default=None,
                        help='give up after this many seconds (default: the replay time + '
                             '420 s: a first run compiles the estimators)')
    parser.add_argument('--view', action='store_true', help='serve the live view (Foxglove '
                        'WebSocket) from before the replay starts; see `nmt view`')
    from nmt_ros.cli.view import add_view_options

    add_view_options(parser)


def replay_timeout_s(bag: str | os.PathLike | None, rate: float, duration_s: float = 0.0,
                     margin_s: float = 420.0) -> float:
    """Wall time a graph run may take: the replayed span at ``rate`` plus ``margin_s``."""
    from nmt_ros.io.bags import bag_info

    info = bag_info(Path(bag) if bag is not None else default_bag())
    span = info.duration_ns * 1e-9
    if duration_s > 0:
        span = min(span, duration_s)
    return span / rate + margin_s


def run(args: argparse.Namespace) -> int:
    if args.record and Path(args.record).exists() and any(Path(args.record).iterdir()):
        print(f'error: {args.record} exists and is not empty', file=sys.stderr)
        return 2
    timeout = args.timeout or replay_timeout_s(args.bag, args.rate, args.duration)
    extra = {'observation_publisher': {'duration_s': args.duration}} if args.duration else None
    if args.start is not None:
        extra = {**(extra or {}), 'skeletal_tracker': {'start_s': float(args.start)}}
    view = None if not args.view else {
        'host': args.view_host, 'port': args.view_port,
        'scene_rate_hz': float(args.scene_rate), 'scene_source': args.scene_source}
    if view is not None:
        print(f'live view: ws://{args.view_host}:{args.view_port} (Foxglove or Lichtblick; '
              f'layout {config_path("foxglove_layout.json")})', flush=True)
    result = run_graph(bag=args.bag, rate=args.rate, record=args.record, params=args.params,
                       log_dir=args.log_dir, timeout_s=timeout, publish_clock=args.clock,
                       extra_params=extra, view=view)
    print(format_run(result))
    return result.returncode


def format_run(result: GraphRun) -> str:
    lines = [f'graph {"interrupted" if result.interrupted else "finished"} after '
             f'{result.wall_s:.1f} s; exit codes: ' +
             ', '.join(f'{n} {rc}' for n, rc in result.node_returncodes.items())]
    lines += [f'  problem: {p}' for p in result.problems]
    lines.append(f'  logs and parameters: {result.log_dir}')
    if result.record is not None and (result.record / 'metadata.yaml').exists():
        from nmt_ros.io.bags import bag_info

        info = bag_info(result.record)
        lines.append(f'  recording: {result.record} ({info.message_count} messages)')
        for t in sorted(info.topics, key=lambda t: t.name):
            lines.append(f'    {t.name:42s} {t.message_count:6d}')
    return '\n'.join(lines)
