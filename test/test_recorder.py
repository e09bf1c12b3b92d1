"""Lossless recording: split bags read by independent readers (rosbags, mcap), the writer
thread's bounded queue, a recorder stopped by SIGTERM mid-stream, every message of a 4x replay
recorded beside a CPU hog (counts, not timing), and the pieces (looped bags, header stamp
rewriting, replay read-ahead, lateness percentiles, node environment)."""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from typescript_reader import read_with_typescript
import yaml

from msg_adapters.cdr_header import header_stamp_ns, header_stamps_ns, with_header_stamp
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros.io import bags
from nmt_ros.io.background_writer import BackgroundBagWriter
from nmt_ros.io.bag_loop import loop_bag
from nmt_ros.io.replay import Lateness, ReadAhead
from nmt_ros.topics import FORCE_PLATE_WRENCH, MOCAP_SEGMENT_ANGLES, OBSERVATIONS

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'reference_jump'
NMT = [sys.executable, '-m', 'nmt_ros.cli.main']
WS = 'geometry_msgs/msg/WrenchStamped'
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 925_926   # 1080 Hz


def wrench_blobs(n: int) -> tuple[np.ndarray, list[bytes]]:
    from rclpy.serialization import serialize_message

    t = T0 + np.arange(n, dtype=np.int64) * PERIOD_NS
    force = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    msgs = wrenches_from_arrays(t, 'plate', force, np.zeros((n, 3)))
    return t, [serialize_message(m) for m in msgs]


def rosbags_force_x(path: Path) -> np.ndarray:
    with AnyReader([path]) as reader:
        return np.array([reader.deserialize(raw, c.msgtype).wrench.force.x
                         for c, _, raw in reader.messages()])


def mcap_count(path: Path) -> int:
    with open(path, 'rb') as f:
        return sum(1 for _ in make_reader(f).iter_messages())


# --------------------------------------------------------------------------- splitting

@pytest.mark.parametrize('split', ['size', 'duration'])
def test_split_bag_is_one_bag_for_every_reader(tmp_bag, split):
    n = 5400                                   # 5 s at 1080 Hz
    t, blobs = wrench_blobs(n)
    path = tmp_bag(split)
    limits = ({'max_bag_size': 40_000, 'chunk_size': 8_192} if split == 'size'
              else {'max_bag_duration_s': 1.0})
    with bags.BagWriter(path, **limits) as bag:
        bag.add_topic('/w', WS)
        for ti, blob in zip(t.tolist(), blobs):
            bag.write('/w', blob, ti, ti)
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    files = meta['relative_file_paths']
    assert len(files) >= 4, files
    assert files == [f'{path.name}_{i}.mcap' for i in range(len(files))]
    assert [f['path'] for f in meta['files']] == files
    assert sum(f['message_count'] for f in meta['files']) == meta['message_count'] == n
    for f in meta['files']:
        assert mcap_count(path / f['path']) == f['message_count']   # the mcap reader, per file
        if split == 'duration':
            assert f['duration']['nanoseconds'] <= 1_000_000_000
    if split == 'size':   # a file ends at the first chunk that reaches the limit
        sizes = [(path / f).stat().st_size for f in files]
        assert all(s >= 40_000 for s in sizes[:-1]) and max(sizes) < 40_000 + 3 * 8_192
    # every message once, in order, from rosbags and from our reader
    np.testing.assert_array_equal(rosbags_force_x(path), np.arange(n))
    raw = list(bags.read_raw(path))
    assert [r.log_time_ns for r in raw] == t.tolist()
    info = bags.bag_info(path)
    assert info.message_count == n and info.topic('/w').message_count == n
    assert info.start_ns == t[0] and info.duration_ns == t[-1] - t[0]


def test_split_files_are_complete_and_reindex_keeps_them(tmp_bag):
    """A recording killed after a split: the finished files are complete MCAPs, the last one
    is salvaged, and reindex lists them all."""
    t, blobs = wrench_blobs(3000)
    path = tmp_bag('killed_split')
    bag = bags.BagWriter(path, max_bag_duration_s=1.0, flush_period_s=None)
    bag.add_topic('/w', WS)
    for ti, blob in zip(t.tolist(), blobs):
        bag.write('/w', blob, ti, ti)
    bag.flush()
    done = list(bag.file_names[:-1])  # the writer is abandoned (no close), as by a SIGKILL
    assert not (path / 'metadata.yaml').exists()
    assert all(mcap_count(path / f) > 0 for f in done)
    info = bags.reindex(path)
    assert list(info.relative_file_paths) == list(bag.file_names)
    assert info.message_count == 3000
    np.testing.assert_array_equal(rosbags_force_x(path), np.arange(3000))


def test_split_limits_are_checked(tmp_bag):
    with pytest.raises(ValueError, match='max_bag_size'):
        bags.BagWriter(tmp_bag(), max_bag_size=-1)


# --------------------------------------------------------------------------- writer thread

def test_background_writer_queue_is_bounded_and_loses_nothing(tmp_bag, monkeypatch):
    t, blobs = wrench_blobs(2000)
    size = len(blobs[0])
    gate = threading.Event()
    writer = bags.BagWriter(tmp_bag('queued'))
    real_write = writer.write

    def slow_write(*args, **kwargs):
        gate.wait()
        real_write(*args, **kwargs)

    monkeypatch.setattr(writer, 'write', slow_write)
    background = BackgroundBagWriter(writer, max_queue_bytes=100 * size)
    background.add_topic('/w', WS)
    batches = [[('/w', b, int(ti), int(ti)) for ti, b in zip(t[i:i + 50], blobs[i:i + 50])]
               for i in range(0, 2000, 50)]
    done = threading.Event()

    def produce():
        for batch in batches:
            background.put(batch)
        done.set()

    producer = threading.Thread(target=produce)
    producer.start()
    assert not done.wait(0.5)          # the queue is full and the writer is held: put blocks
    assert background.queued_bytes <= 100 * size
    gate.set()
    assert done.wait(20.0)
    producer.join()
    info = background.close()
    assert info.message_count == 2000
    assert background.stats.max_bytes <= 100 * size and background.stats.blocked_s > 0.3
    np.testing.assert_array_equal(rosbags_force_x(writer.path), np.arange(2000))


def test_background_writer_reports_a_failed_write(tmp_bag, monkeypatch):
    _, blobs = wrench_blobs(10)
    writer = bags.BagWriter(tmp_bag('failing'))
    background = BackgroundBagWriter(writer)
    background.add_topic('/w', WS)

    def broken(*_args, **_kwargs):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(writer, 'write', broken)
    background.put([('/w', blobs[0], T0, T0)])
    deadline = time.monotonic() + 10
    while background._error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(bags.BagError, match='No space left'):
        background.put([('/w', blobs[1], T0 + 1, T0 + 1)])
    with pytest.raises(bags.BagError, match='No space left'):
        background.close()


# --------------------------------------------------------------------------- pieces

def test_with_header_stamp_round_trips_in_both_byte_orders():
    _, (blob,) = wrench_blobs(1)
    assert header_stamp_ns(with_header_stamp(blob, T0 + 123_456_789)) == T0 + 123_456_789
    big = bytes([0, 0, 0, 0]) + (5).to_bytes(4, 'big') + (7).to_bytes(4, 'big') + blob[12:]
    moved = with_header_stamp(big, 9_000_000_011)
    assert moved[4:12] == (9).to_bytes(4, 'big') + (11).to_bytes(4, 'big')
    assert moved[12:] == big[12:] and header_stamp_ns(moved) == 9_000_000_011
    with pytest.raises(ValueError, match='too short'):
        with_header_stamp(b'\x00\x01\x00\x00', 0)


def test_loop_bag_repeats_the_stream_without_a_gap(tmp_bag):
    out = tmp_bag('looped')
    info, plan = loop_bag(BAG, out, 1.0, OBSERVATIONS)
    source = {t.name: t.message_count for t in bags.bag_info(BAG).topics}
    assert plan.copies == 5   # 0.249 s per copy
    assert {t.name: t.message_count for t in info.topics} == {
        t: source[t] * plan.copies for t in OBSERVATIONS} == plan.counts()
    raw = list(bags.read_raw(out, [FORCE_PLATE_WRENCH]))
    stamps = header_stamps_ns([r.data for r in raw])
    spacing = np.diff(stamps)
    assert spacing.min() >= PERIOD_NS - 1 and spacing.max() <= PERIOD_NS   # 1080 Hz throughout
    np.testing.assert_array_equal(np.array([r.log_time_ns for r in raw]) - stamps,
                                  raw[0].log_time_ns - stamps[0])
    n = source[FORCE_PLATE_WRENCH]
    original = list(bags.read_raw(BAG, [FORCE_PLATE_WRENCH]))
    assert [r.data[12:] for r in raw[n:2 * n]] == [r.data[12:] for r in original]
    angles = header_stamps_ns([r.data for r in bags.read_raw(out, [MOCAP_SEGMENT_ANGLES])])
    assert (np.diff(angles) > 0).all()


def test_read_ahead_keeps_order_and_raises_where_the_reader_failed():
    assert list(ReadAhead(iter(range(10_000)), batch=7, max_batches=3)) == list(range(10_000))

    def failing():
        yield from range(20)
        raise OSError('disk gone')

    got = []
    with pytest.raises(OSError, match='disk gone'):
        for x in ReadAhead(failing(), batch=8):
            got.append(x)
    assert got == list(range(20))


def test_read_ahead_reads_before_anyone_iterates_and_stops_on_close():
    # the replay makes it before waiting for its subscribers: the first chunks are read then
    produced = []
    started = threading.Event()

    def items():
        for i in range(100_000):
            produced.append(i)
            started.set()
            yield i

    ahead = ReadAhead(items(), batch=10, max_batches=4)
    assert started.wait(5.0)
    deadline = time.monotonic() + 5.0
    while len(produced) < 40 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(produced) >= 40                 # the queue filled without a consumer...
    time.sleep(0.2)
    assert len(produced) <= 4 * 10 + 10 + 1    # ...and no further (bounded)
    it = iter(ahead)
    assert [next(it) for _ in range(25)] == list(range(25))
    ahead.close()
    ahead._thread.join(timeout=10.0)
    assert not ahead._thread.is_alive()        # the reader stopped
    n = len(produced)
    time.sleep(0.1)
    assert len(produced) == n


def test_lateness_percentiles_within_a_bin():
    rng = np.random.default_rng(3)
    values = rng.lognormal(np.log(2e5), 1.0, 20_000).astype(np.int64)   # around 0.2 ms
    late = Lateness()
    for v in values.tolist():
        late.add(v)
    for q in (50, 99):
        exact = np.percentile(values, q)
        assert exact <= late.percentile_ns(q) <= exact * 1.021
    assert late.max_ns == values.max() and late.n == values.size
    assert np.isnan(Lateness().percentile_ns(50))


def test_node_environment_single_threaded_blas(monkeypatch):
    from nmt_ros.cli.launch import ros_environment

    for key in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
        monkeypatch.delenv(key, raising=False)
    env = ros_environment()
    assert env['OPENBLAS_NUM_THREADS'] == env['OMP_NUM_THREADS'] == '1'
    monkeypatch.setenv('OPENBLAS_NUM_THREADS', '2')
    assert ros_environment()['OPENBLAS_NUM_THREADS'] == '2'   # the user's choice stays


# --------------------------------------------------------------------------- the recorder node

def start(args, log: Path) -> subprocess.Popen:
    return subprocess.Popen([*NMT, *map(str, args)], stdout=open(log, 'w'),  # noqa: SIM115
                            stderr=subprocess.STDOUT, env=dict(os.environ))


def wait_for_text(path: Path, text: str, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors='replace'):
            return True
        time.sleep(0.05)
    return False


def announced_and_recorded(record: Path) -> tuple[dict[str, int], dict[str, int]]:
    from nmt_ros.study.recording_evaluation import final_statuses

    status = final_statuses(record)['observation_publisher']
    announced = {k[len('published.'):]: int(v) for k, v in status.items()
                 if k.startswith('published.')}
    return announced, {t.name: t.message_count for t in bags.bag_info(record).topics}


def stop_all(*procs):
    for p in procs:
        if p is not None and p.poll() is None:
            p.kill()
            p.wait()


@pytest.mark.ros
@pytest.mark.slow
def test_recorder_at_4x_beside_a_cpu_hog_records_every_message(tmp_path, tmp_bag):
    """Robust, not a timing assertion: whatever the load, the recorded counts equal the
    publisher's announced counts (a 12 s stream replayed at 4x, split by size on the way)."""
    looped, _ = loop_bag(BAG, tmp_bag('looped'), 12.0, OBSERVATIONS)
    record = tmp_path / 'rec'
    hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    recorder = publisher = None
    try:
        recorder = start(['run', 'recorder', '--ros-args', '-p', f'output:={record}', '-p',
                          'max_bag_size:=200000'], tmp_path / 'recorder.log')
        publisher = start(['run', 'observation_publisher', '--ros-args', '-p',
                           f'bag:={looped.path}', '-p', 'rate:=4.0', '-p',
                           'expected_subscribers:=1'], tmp_path / 'publisher.log')
        assert publisher.wait(timeout=120) == 0, (tmp_path / 'publisher.log').read_text()
        recorder.send_signal(signal.SIGINT)
        assert recorder.wait(timeout=60) == 0, (tmp_path / 'recorder.log').read_text()
    finally:
        stop_all(hog, recorder, publisher)
    announced, recorded = announced_and_recorded(record)
    assert announced == {t.name: t.message_count for t in looped.topics}
    assert {t: recorded[t] for t in announced} == announced
    info = bags.bag_info(record)
    assert len(info.relative_file_paths) >= 2      # split by size
    with AnyReader([record]) as reader:
        counts = {}
        for conn, _, _ in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert {t: counts[t] for t in announced} == announced
    ts = read_with_typescript(record)            # the split recording, read in TypeScript
    assert tuple(ts['files']) == info.relative_file_paths
    assert {t: ts['topics'][t]['count'] for t in announced} == announced


@pytest.mark.ros
@pytest.mark.slow
def test_sigterm_mid_recording_leaves_a_finalised_bag(tmp_path, tmp_bag):
    looped, _ = loop_bag(BAG, tmp_bag('looped'), 20.0, OBSERVATIONS)
    record, log = tmp_path / 'rec', tmp_path / 'recorder.log'
    recorder = start(['run', 'recorder', '--ros-args', '-p', f'output:={record}', '-p',
                      'max_bag_duration:=1.0'], log)
    publisher = None
    try:
        publisher = start(['run', 'observation_publisher', '--ros-args', '-p',
                           f'bag:={looped.path}', '-p', 'expected_subscribers:=1'],
                          tmp_path / 'publisher.log')
        assert wait_for_text(log, f'recording {FORCE_PLATE_WRENCH}', 60.0)
        deadline = time.monotonic() + 60
        while len(list(record.glob('*.mcap'))) < 3 and time.monotonic() < deadline:
            time.sleep(0.1)                # two splits done: well into the 20 s stream
        recorder.send_signal(signal.SIGTERM)
        assert recorder.wait(timeout=60) == 0, log.read_text()
    finally:
        stop_all(recorder, publisher)
    meta = yaml.safe_load((record / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert len(meta['relative_file_paths']) >= 3
    info = bags.bag_info(record)
    wrench = info.topic(FORCE_PLATE_WRENCH).message_count
    assert 0 < wrench < looped.topic(FORCE_PLATE_WRENCH).message_count
    stamps = header_stamps_ns([r.data for r in bags.read_raw(record, [FORCE_PLATE_WRENCH])])
    assert stamps.size == wrench and (np.diff(stamps) > 0).all()   # a gap-free prefix
    assert np.all(np.diff(stamps) < 2 * PERIOD_NS)
    with AnyReader([record]) as reader:
        assert sum(1 for c, _, _ in reader.messages() if c.topic == FORCE_PLATE_WRENCH) == wrench


BUSY_CHILD = r'''
import sys
from msg_adapters.wrench import to_wrench_stamped
from nmt_ros.io.bags import BagWriter, close_bags_on_sigterm
close_bags_on_sigterm()
with BagWriter(sys.argv[1], flush_period_s=0.0, chunk_size=2048) as bag:
    bag.add_topic('/w', 'geometry_msgs/msg/WrenchStamped')
    i = 0
    while True:    # no pause: a signal lands inside write() or a chunk flush
        bag.write('/w', to_wrench_stamped(i * 925926, 'plate', [float(i), 0.0, 0.0]),
                  i * 925926)
        i += 1
        if i == 2000:
            print('ready', flush=True)
'''


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT])
def test_a_signal_never_leaves_a_half_written_chunk(tmp_bag, signum):
    """The bag's summary and metadata.yaml count exactly the messages the file holds."""
    for attempt in range(3):
        path = tmp_bag('busy')
        child = subprocess.Popen([sys.executable, '-c', BUSY_CHILD, str(path)],
                                 stdout=subprocess.PIPE, text=True)
        assert child.stdout.readline().strip() == 'ready'
        time.sleep(0.05 * attempt)
        child.send_signal(signum)
        child.wait(timeout=30)
        info = bags.bag_info(path)
        force = rosbags_force_x(path)
        assert force.size == info.message_count >= 2000
        np.testing.assert_array_equal(force, np.arange(force.size))


def test_latency_is_measured_between_receive_times_or_publish_times():
    """The report's latency: the estimate's time minus the same-stamped observation's, on the
    recorder's receive clock (default) or the publishers' clock; stamps without an
    observation are not scored."""
    from nmt_ros.study.recording_evaluation import TopicTimes, latency_ms

    stamps = np.array([10, 20, 30], dtype=np.int64)
    obs = TopicTimes(stamps, publish_ns=np.array([100, 200, 300]) * 1_000_000,
                     log_ns=np.array([101, 201, 301]) * 1_000_000)
    est = TopicTimes(np.array([30, 10, 25], dtype=np.int64),
                     publish_ns=np.array([340, 150, 999]) * 1_000_000,
                     log_ns=np.array([346, 155, 999]) * 1_000_000)
    received = latency_ms(est, obs)
    published = latency_ms(est, obs, clock='publish')
    assert received['n'] == published['n'] == 2
    assert (received['min_ms'], received['max_ms']) == (45.0, 54.0)
    assert (published['min_ms'], published['max_ms']) == (40.0, 50.0)
    with pytest.raises(ValueError, match='clock'):
        latency_ms(est, obs, clock='wall')
    # from a time after the first observation on: only the instants at or after it count
    late = latency_ms(est, obs, after_s=15e-9)
    assert (late['n'], late['min_ms'], late['max_ms']) == (1, 45.0, 45.0)
    assert latency_ms(est, obs, after_s=25e-9)['n'] == 0


def test_latency_by_phase_puts_each_estimate_in_its_truth_phase():
    """Each estimate's delay lands in the phase of the truth at its stamp: delays made to
    depend on the phase come back as each phase's percentiles."""
    from nmt_ros.io.trial_bag import read_truth
    from nmt_ros.study.phase_scores import truth_phases
    from nmt_ros.study.recording_evaluation import TopicTimes, latency_by_phase

    truth = read_truth(ROOT / 'bags' / 'routine')
    masks = truth_phases(truth)
    epoch = 5_000_000_000
    stamps = epoch + np.rint(truth.t * 1e9).astype(np.int64)
    delay_ms = {'quiet': 80.0, 'moving': 90.0, 'flight': 300.0, 'landing': 500.0}
    delay = np.zeros(truth.t.size)
    for name, d in delay_ms.items():
        delay[masks[name]] = d
    assert (delay > 0).all()                  # every instant is in one of the four
    obs = TopicTimes(stamps, publish_ns=stamps + 1000, log_ns=stamps + 2000)
    est = TopicTimes(stamps, publish_ns=stamps, log_ns=stamps + 2000
                     + np.rint(delay * 1e6).astype(np.int64))
    got = latency_by_phase(est, obs, truth, epoch)
    for name, d in delay_ms.items():
        assert got[name]['n'] == masks[name].sum() > 0
        assert got[name]['p50_ms'] == pytest.approx(d) and got[name]['max_ms'] == pytest.approx(d)
    assert got['all']['n'] == truth.t.size


def test_truth_between_keeps_the_replayed_span():
    """A demo replaying the first seconds of a long record is scored on those seconds."""
    from nmt_ros.io.trial_bag import read_truth

    truth = read_truth(BAG)
    part = truth.between(0.05, 0.1)
    assert part.t.min() >= 0.05 and part.t.max() <= 0.1
    assert part.t.size == ((truth.t >= 0.05) & (truth.t <= 0.1)).sum() > 0
    np.testing.assert_array_equal(part.tau, truth.tau[(truth.t >= 0.05) & (truth.t <= 0.1)])
    assert part.f.shape[1] == truth.f.shape[1] and part.liftoff_s == truth.liftoff_s


def test_the_demo_summary_of_a_bag_without_truth_says_so_instead_of_printing_nan():
    """A lab bag has no truth: the jump line gives the tracked height and says why there
    is nothing to compare it with (it printed 'actual (truth) nan m')."""
    from nmt_ros.study.recording_evaluation import format_summary

    lab = format_summary({'tracked': {'jump_height_m': 0.368}})
    assert 'jump height: tracked motion 0.368 m (the bag has no truth)' in lab
    assert 'nan' not in lab
    synthetic = format_summary({'tracked': {'jump_height_m': 0.25},
                                'actual': {'jump_height_m': 0.2}})
    assert 'actual (truth) 0.200 m (difference +5.0 cm)' in synthetic
    # the skeletal tracker's losses of control (its final status's restart count) are said,
    # also when there were none
    assert 'skeletal tracker losses of control: none' in format_summary(
        {'losses_of_control': 0})
    assert 'skeletal tracker losses of control: 2 (each re-initialised' in format_summary(
        {'losses_of_control': 2})
