"""Our bags read by an independent TypeScript reader, as the acceptance checks read them.

``test/ts_reader`` (built by ``make ts-reader``, part of ``make test``) reads a bag folder with
the MCAP project's ``@mcap/core`` (indexed reading, ``@mcap/support``'s decompressors) and
Foxglove's ``@foxglove/rosmsg2-serialization`` (CDR decoded with the definition each file
carries): the files ``metadata.yaml`` lists, every message decoded. Compared here with what
was written (a synthetic bag: every compression, split over several files) and with rosbags'
decoding (the shipped bags): counts, header stamps (exact sums), every numeric field (sums)
and the first message of each topic.
"""
from __future__ import annotations

import math
from pathlib import Path
import signal

from bag_writer_child import run_child_until_ready
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from typescript_reader import read_with_typescript
import yaml

from msg_adapters.diagnostics import StatusRecord, to_diagnostic_array
from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros.io import bags

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000_000_000_000
JOINTS = ('ankle', 'knee', 'hip')


def _number(value: float | str) -> float:
    return float(value)        # the reader writes non-finite numbers as strings ('NaN')


def _same_sum(ts: float | str, values: np.ndarray) -> bool:
    """A sum in the reader's order against math.fsum of the same values (exact): within
    rounding, or both NaN."""
    ts, ref = _number(ts), math.fsum(np.asarray(values, dtype=float).ravel())
    if math.isnan(ref) or math.isnan(ts):
        return math.isnan(ref) and math.isnan(ts)
    scale = float(np.abs(values).sum()) + 1e-300
    return abs(ts - ref) <= 1e-12 * scale


@pytest.fixture(scope='module', params=['zstd', 'lz4', 'none'])
def written(request, tmp_path_factory) -> tuple[Path, dict]:
    """2 s of joint torques (1080 Hz, efforts and angles), ground wrenches (1080 Hz) and
    statuses (2 Hz), split over several files by size; with what was written."""
    rng = np.random.default_rng(11)
    t = T0 + (np.arange(2160) * 1_000_000_000) // 1080
    theta, rate, tau = (rng.normal(size=(t.size, 3)) * s for s in (1.0, 5.0, 200.0))
    force, torque = rng.normal(size=(t.size, 3)) * 500.0, rng.normal(size=(t.size, 3)) * 50.0
    t_status = t[::540]
    levels = rng.integers(0, 3, size=(t_status.size, 2))
    js = joint_states_from_arrays(t, JOINTS, position=theta, velocity=rate, effort=tau)
    ws = wrenches_from_arrays(t, 'foot_com', force, torque)
    st = [to_diagnostic_array(int(ts), [StatusRecord(int(a), 'skeletal_tracker', 'tracking',
                                                     {'lag_ms': 50.0}),
                                        StatusRecord(int(b), 'muscle_tracker', 'ok')])
          for ts, (a, b) in zip(t_status, levels)]
    path = tmp_path_factory.mktemp('ts') / f'bag_{request.param}'
    stream = sorted([(int(s), '/nmt/skeletal/joint_torques', m) for s, m in zip(t, js)]
                    + [(int(s), '/nmt/skeletal/ground_wrench', m) for s, m in zip(t, ws)]
                    + [(int(s), '/nmt/status', m) for s, m in zip(t_status, st)],
                    key=lambda x: x[0])
    with bags.BagWriter(path, compression=request.param, chunk_size=64 * 1024,
                        max_bag_size=100 * 1024) as bag:
        bag.add_topic('/nmt/skeletal/joint_torques', 'sensor_msgs/msg/JointState')
        bag.add_topic('/nmt/skeletal/ground_wrench', 'geometry_msgs/msg/WrenchStamped')
        bag.add_topic('/nmt/status', 'diagnostic_msgs/msg/DiagnosticArray')
        for stamp, topic, msg in stream:
            bag.write(topic, msg, log_time_ns=stamp + 1_000_000)
    return path, {'compression': request.param, 't': t, 't_status': t_status,
                  'theta': theta, 'rate': rate, 'tau': tau, 'force': force, 'torque': torque,
                  'levels': levels}


def test_a_written_bag_reads_back_in_typescript_message_for_message(written):
    path, w = written
    out = read_with_typescript(path)
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    # the files metadata.yaml lists, all of them read (split by size), every message once
    assert list(out['files']) == meta['relative_file_paths']
    assert len(out['files']) >= 3, out['files']
    assert sum(out['files'].values()) == meta['message_count'] == 2 * w['t'].size + w[
        't_status'].size
    assert out['compression'] == [w['compression']]
    assert out['metadata']['topics'] == {t: out['topics'][t]['count'] for t in out['topics']}
    torques = out['topics']['/nmt/skeletal/joint_torques']
    wrench = out['topics']['/nmt/skeletal/ground_wrench']
    status = out['topics']['/nmt/status']
    assert (torques['type'], wrench['type'], status['type']) == (
        'sensor_msgs/msg/JointState', 'geometry_msgs/msg/WrenchStamped',
        'diagnostic_msgs/msg/DiagnosticArray')
    assert torques['count'] == wrench['count'] == w['t'].size
    assert status['count'] == w['t_status'].size
    # header stamps exact, the log times as written
    assert int(torques['stamp_ns_sum']) == int(w['t'].astype(object).sum())
    assert int(wrench['stamp_ns_sum']) == int(w['t'].astype(object).sum())
    assert int(status['stamp_ns_sum']) == int(w['t_status'].astype(object).sum())
    assert int(torques['log_ns_first']) == int(w['t'][0]) + 1_000_000
    assert int(torques['log_ns_last']) == int(w['t'][-1]) + 1_000_000
    # every value: sums over the whole topic, and the first message field by field
    for field, key in (('position', 'theta'), ('velocity', 'rate'), ('effort', 'tau')):
        assert _same_sum(torques['sums'][field], w[key]), field
    assert _same_sum(wrench['sums']['force'], w['force'])
    assert _same_sum(wrench['sums']['torque'], w['torque'])
    assert int(status['sums']['level']) == int(w['levels'].sum())
    first = torques['first']
    assert first['name'] == list(JOINTS)
    assert first['position'] == w['theta'][0].tolist()
    assert first['effort'] == w['tau'][0].tolist()
    assert first['header']['stamp'] == {'sec': int(w['t'][0]) // 10**9,
                                        'nanosec': int(w['t'][0]) % 10**9}
    f = wrench['first']
    assert f['header']['frame_id'] == 'foot_com'
    assert [f['wrench']['force'][k] for k in 'xyz'] == w['force'][0].tolist()
    assert [f['wrench']['torque'][k] for k in 'xyz'] == w['torque'][0].tolist()
    s = status['first']['status']
    assert [(x['level'], x['name'], x['message']) for x in s] == [
        (int(w['levels'][0, 0]), 'skeletal_tracker', 'tracking'),
        (int(w['levels'][0, 1]), 'muscle_tracker', 'ok')]
    assert s[0]['values'] == [{'key': 'lag_ms', 'value': '50.0'}]


def _rosbags_summary(bag: Path) -> dict:
    """Per topic, with rosbags (independent of both our code and the TypeScript reader):
    count, exact stamp sum, the numeric fields' values and the first message's."""
    out: dict = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            row = out.setdefault(conn.topic, {'type': conn.msgtype, 'count': 0, 'stamps': 0,
                                             'values': {}, 'first': msg})
            row['count'] += 1
            header = getattr(msg, 'header', None)
            if header is not None:
                row['stamps'] += header.stamp.sec * 10**9 + header.stamp.nanosec
            if conn.msgtype == 'sensor_msgs/msg/JointState':
                fields = {f: getattr(msg, f) for f in ('position', 'velocity', 'effort')}
            elif conn.msgtype == 'geometry_msgs/msg/WrenchStamped':
                fo, to = msg.wrench.force, msg.wrench.torque
                fields = {'force': [fo.x, fo.y, fo.z], 'torque': [to.x, to.y, to.z]}
            else:
                fields = {}
            for f, v in fields.items():
                row['values'].setdefault(f, []).append(np.asarray(v, dtype=float))
    return out


@pytest.mark.parametrize('name', ['reference_jump', 'real_dropjump'])
def test_the_shipped_bags_read_the_same_in_typescript_and_rosbags(name):
    bag = ROOT / 'bags' / name
    ts = read_with_typescript(bag)
    ref = _rosbags_summary(bag)
    assert set(ts['topics']) == set(ref)
    for topic, r in ref.items():
        t = ts['topics'][topic]
        assert (t['type'], t['count']) == (r['type'], r['count']), topic
        if r['stamps']:
            assert int(t['stamp_ns_sum']) == r['stamps'], topic
        for field, values in r['values'].items():
            assert _same_sum(t['sums'][field], np.concatenate(values)), (topic, field)
        if r['type'] == 'sensor_msgs/msg/JointState':
            first = r['first']
            assert t['first']['name'] == list(first.name), topic
            assert np.array_equal(np.asarray(t['first']['position'], dtype=float),
                                  first.position, equal_nan=True), topic


def test_the_shipped_routine_reads_in_typescript_with_metadata_counts():
    """The demo's 60 s routine (252,024 messages): every topic's count as metadata.yaml says,
    stamps of every force-plate instant, and no value lost to a decoding error (the sums are
    finite where the bag has finite values)."""
    bag = ROOT / 'bags' / 'routine'
    ts = read_with_typescript(bag)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {e['topic_metadata']['name']: e['message_count']
              for e in meta['topics_with_message_count']}
    assert {t: v['count'] for t, v in ts['topics'].items()} == counts
    assert sum(ts['files'].values()) == meta['message_count']
    plate = ts['topics']['/force_plate/wrench']
    assert plate['count'] == 64801
    assert math.isfinite(_number(plate['sums']['force']))


@pytest.mark.parametrize('how', ['SIGKILL, then reindex', 'SIGTERM'])
def test_an_interrupted_recording_reads_in_typescript(tmp_path, how):
    """A writer killed mid-recording and repaired by ``bags.reindex`` (every file rewritten
    with its summary), or stopped by SIGTERM (closed by its handler): the TypeScript reader
    reads every message the repaired or closed bag lists, in order (force.x = index)."""
    path = tmp_path / 'interrupted'
    child = run_child_until_ready(path)
    child.send_signal(signal.SIGKILL if how.startswith('SIGKILL') else signal.SIGTERM)
    child.wait(timeout=10)
    info = bags.reindex(path) if how.startswith('SIGKILL') else bags.bag_info(path)
    out = read_with_typescript(path)
    w = out['topics']['/w']
    n = info.message_count
    assert n >= 1000 and w['count'] == n == sum(out['files'].values())
    assert _number(w['sums']['force']) == n * (n - 1) / 2      # 0 + 1 + ... + n - 1, exact
    assert w['first']['wrench']['force']['x'] == 0.0
    assert int(w['stamp_ns_sum']) == 925926 * n * (n - 1) // 2
