"""The graph as separate processes: ``nmt launch`` end to end on the shipped (short) bag, at
1x and faster, SIGINT during a launch, a launcher killed outright, ``nmt run`` of single
nodes and a killed recorder."""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from conftest import batch_samples
from process_groups import children, kill_group, popen_group, running
import pytest
from typescript_reader import read_with_typescript

from nmt_ros.io.bags import bag_info, read_raw, reindex

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'reference_jump'
NMT = [sys.executable, '-m', 'nmt_ros.cli.main']


def nmt(*args, log: Path | None = None, env: dict | None = None):
    stdout = subprocess.PIPE if log is None else open(log, 'w')  # noqa: SIM115
    return popen_group([*NMT, *map(str, args)], stdout=stdout, stderr=subprocess.STDOUT,
                       text=True, env={**os.environ, **(env or {})})


def wait_for_text(path: Path, text: str, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors='replace'):
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize('rate', [1.0, 4.0])
def test_launch_processes_the_replay_and_records_everything(tmp_path, rate):
    import pstats

    from nmt_ros.study.recording_evaluation import graph_summary

    record, profiles = tmp_path / 'rec', tmp_path / 'profiles'
    # at 4x every node also runs under cProfile (NMT_PROFILE_DIR): same outcome, and a
    # profile of each node's main thread
    env = {'NMT_PROFILE_DIR': str(profiles)} if rate > 1 else {}
    proc = nmt('launch', '--record', record, '--rate', rate, '--log-dir', tmp_path / 'logs',
               env=env)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    assert 'graph finished' in out and 'problem' not in out
    summary = graph_summary(record, BAG, batch=False)
    assert summary['lossless'], summary['counts']
    counts = summary['counts']
    assert counts['/force_plate/wrench'] == {'published': 269, 'recorded': 269}
    # Stage 1: every instant the same estimator gives offline; Stage 2: every force-plate
    # instant from its first torque to its last (instants Stage 1 withheld are bridged)
    assert counts['/nmt/skeletal/joint_torques']['recorded'] == batch_samples()
    assert counts['/nmt/muscle/forces']['recorded'] >= batch_samples()
    assert set(summary['node_states'].values()) >= {'finished'}
    lat = summary['latency_ms']
    assert lat['joint_torques']['n'] == batch_samples()
    assert lat['muscle_forces']['n'] == counts['/nmt/muscle/forces']['recorded']
    assert 0 < lat['joint_torques']['p50_ms'] < lat['muscle_forces']['p50_ms']
    params = (tmp_path / 'logs' / 'params.yaml').read_text()
    assert 'expected_subscribers: 2' in params and f'rate: {rate}' in params
    # the live recording as a TypeScript consumer reads it (test_ts_reader.py): every
    # message metadata.yaml counts, every data topic as recorded
    ts = read_with_typescript(record)
    assert ts['metadata']['topics'] == {t: v['count'] for t, v in ts['topics'].items()}
    assert {t: ts['topics'][t]['count'] for t in counts} == {
        t: c['recorded'] for t, c in counts.items()}
    if env:
        for node in ('observation_publisher', 'skeletal_tracker', 'muscle_tracker',
                     'recorder'):
            stats = pstats.Stats(str(profiles / f'{node}.prof'))
            # its executor's loop was profiled
            assert any('spin_once' in fn[2] for fn in stats.stats), node


def replaying_launch(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    """(launcher, recording) of ``nmt launch --record`` at 0.05x (~5 s of replay), once the
    replay has begun (its start waits for discovery, seconds on a loaded machine)."""
    record, logs = tmp_path / 'rec', tmp_path / 'logs'
    proc = nmt('launch', '--record', record, '--rate', 0.05, '--log-dir', logs)
    if not wait_for_text(logs / 'recorder.log', 'first message on /force_plate/wrench',
                         120.0):
        kill_group(proc)
        pytest.fail('the replay did not begin within 120 s')
    return proc, record


def test_sigint_during_launch_leaves_a_readable_bag(tmp_path):
    proc, record = replaying_launch(tmp_path)
    try:
        time.sleep(1.0)   # well into the replay (269 force-plate samples in ~5 s)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        kill_group(proc)          # its nodes too, whatever happened to the launcher
    assert proc.returncode == 130, out
    info = bag_info(record)              # metadata.yaml written: the bag was finalised
    counts = {t.name: t.message_count for t in info.topics}
    assert 0 < counts['/force_plate/wrench'] < 269
    assert sum(1 for _ in read_raw(record, ['/mocap/segment_angles'])) == counts[
        '/mocap/segment_angles']


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='PR_SET_PDEATHSIG')
def test_a_killed_launcher_takes_its_nodes_and_leaves_a_readable_bag(tmp_path):
    proc, record = replaying_launch(tmp_path)
    try:
        nodes = children(proc.pid)
        assert len(nodes) == 4, nodes         # recorder, both trackers, the publisher
        proc.kill()                           # SIGKILL: the launcher stops nothing itself
        proc.wait(timeout=30)
        deadline = time.monotonic() + 60
        while any(running(n) for n in nodes) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = [n for n in nodes if running(n)]
    finally:
        kill_group(proc)
    assert not left, f'nodes still running after their launcher was killed: {left}'
    info = bag_info(record)              # the recorder finalised the bag on its SIGTERM
    counts = {t.name: t.message_count for t in info.topics}
    assert 0 < counts['/force_plate/wrench'] < 269


def test_nmt_run_single_nodes_and_a_killed_recorder(tmp_path):
    record, log = tmp_path / 'rec', tmp_path / 'recorder.log'
    recorder = nmt('run', 'recorder', '--ros-args', '-p', f'output:={record}', '-p',
                   'flush_period_s:=0.2', log=log)
    player = None
    try:
        player = nmt('run', 'observation_publisher', '--ros-args', '-p', f'bag:={BAG}',
                     '-p', 'rate:=0.1', '-p', 'expected_subscribers:=1', '-p',
                     'ack_timeout_s:=1.0')
        assert wait_for_text(log, 'recording /force_plate/wrench', 30.0)
        time.sleep(1.5)                  # the replay (2.5 s at 0.1x) is under way
        recorder.kill()                  # no chance to finalise
        recorder.wait(timeout=10)
        out, _ = player.communicate(timeout=60)
        assert player.returncode in (0, 1), out   # 1: the recorder vanished before acking
    finally:
        for p in (recorder, player):
            if p is not None and p.poll() is None:
                p.kill()
    assert not (record / 'metadata.yaml').exists()
    info = reindex(record)               # `nmt bag reindex`: complete chunks are kept
    counts = {t.name: t.message_count for t in info.topics}
    assert counts.get('/force_plate/wrench', 0) > 0
    assert bag_info(record).message_count == info.message_count
