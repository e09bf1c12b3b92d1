"""Bags written by nmt_ros.io.bags, checked with independent readers (rosbags, mcap_ros2,
rclpy), plus crash recovery, `nmt bag info` formatting, replay timing and the player."""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import signal
import threading
import time

from bag_writer_child import run_child_until_ready
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
import yaml

from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.wrench import wrenches_from_arrays
from nmt_ros.cli.bag import format_bag_info, format_size
from nmt_ros.io import bags, msgdefs
from nmt_ros.io.qos import OfferedQos
from nmt_ros.io.replay import CLOCK, MESSAGE, ReplayScheduler

T0 = 1_700_000_000_000_000_000
ANGLES, WRENCH = '/mocap/segment_angles', '/force_plate/wrench'
SEGMENTS = ('foot', 'shank', 'thigh', 'hat')
JS, WS = 'sensor_msgs/msg/JointState', 'geometry_msgs/msg/WrenchStamped'
RECV_DELAY_NS = 1_000_000


@dataclass
class Recording:
    path: Path
    angle_t: np.ndarray   # [120] ns
    angles: np.ndarray    # [120, 4]
    wrench_t: np.ndarray  # [1080] ns
    force: np.ndarray     # [1080, 3]
    torque: np.ndarray    # [1080, 3]


def write_observations(path: Path, compression: str = 'zstd') -> Recording:
    """1 s of JointState at 120 Hz and WrenchStamped at 1080 Hz, interleaved in time."""
    rng = np.random.default_rng(7)
    angle_t = T0 + (np.arange(120) * 1_000_000_000) // 120
    wrench_t = T0 + (np.arange(1080) * 1_000_000_000) // 1080
    angles = rng.normal(size=(120, 4))
    force, torque = rng.normal(size=(1080, 3)) * 100, rng.normal(size=(1080, 3))
    js = joint_states_from_arrays(angle_t, SEGMENTS, position=angles)
    ws = wrenches_from_arrays(wrench_t, 'plate', force, torque)
    stream = sorted([(t, ANGLES, m) for t, m in zip(angle_t.tolist(), js)]
                    + [(t, WRENCH, m) for t, m in zip(wrench_t.tolist(), ws)],
                    key=lambda x: x[0])
    with bags.BagWriter(path, compression=compression) as bag:
        bag.add_topic(ANGLES, JS)
        bag.add_topic(WRENCH, WS, OfferedQos(reliability='best_effort', depth=5))
        for t, topic, msg in stream:
            bag.write(topic, msg, log_time_ns=t + RECV_DELAY_NS, publish_time_ns=t)
    return Recording(path, angle_t, angles, wrench_t, force, torque)


@pytest.fixture(scope='module')
def rec(tmp_path_factory) -> Recording:
    return write_observations(tmp_path_factory.mktemp('bags') / 'observations')


# --------------------------------------------------------------------------- layout

V9_KEYS = ['version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
           'topics_with_message_count', 'compression_format', 'compression_mode',
           'relative_file_paths', 'files', 'custom_data', 'ros_distro']
QOS_KEYS = ['history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions']


def test_metadata_yaml_has_every_v9_field(rec):
    meta = yaml.safe_load((rec.path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert list(meta) == V9_KEYS
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['ros_distro'] == 'jazzy' and meta['custom_data'] is None
    assert meta['compression_format'] == '' and meta['compression_mode'] == ''
    assert meta['relative_file_paths'] == ['observations_0.mcap']
    assert (rec.path / 'observations_0.mcap').is_file()
    assert meta['message_count'] == 1200
    assert meta['starting_time'] == {'nanoseconds_since_epoch': T0 + RECV_DELAY_NS}
    assert meta['duration'] == {'nanoseconds': int(rec.wrench_t[-1] - T0)}
    assert meta['files'] == [{'path': 'observations_0.mcap',
                              'starting_time': {'nanoseconds_since_epoch': T0 + RECV_DELAY_NS},
                              'duration': {'nanoseconds': int(rec.wrench_t[-1] - T0)},
                              'message_count': 1200}]
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert {k: v['message_count'] for k, v in topics.items()} == {ANGLES: 120, WRENCH: 1080}
    angles = topics[ANGLES]['topic_metadata']
    assert list(angles) == ['name', 'type', 'serialization_format', 'offered_qos_profiles',
                            'type_description_hash']
    assert angles['type'] == JS and angles['serialization_format'] == 'cdr'
    assert angles['type_description_hash'] == msgdefs.type_hash(JS)
    assert angles['type_description_hash'].startswith('RIHS01_')
    (qos,) = angles['offered_qos_profiles']
    assert list(qos) == QOS_KEYS
    assert (qos['reliability'], qos['history'], qos['depth']) == ('reliable', 'keep_last', 1000)
    assert topics[WRENCH]['topic_metadata']['offered_qos_profiles'][0]['reliability'] == (
        'best_effort')


def test_mcap_records_follow_rosbag2(rec):
    with open(rec.path / 'observations_0.mcap', 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        stats = summary.statistics
        assert stats.message_count == 1200 and stats.chunk_count >= 1
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {JS, WS}
        assert {s.encoding for s in schemas.values()} == {'ros2msg'}
        text = schemas[WS].data.decode()
        assert text == msgdefs.full_definition(WS)
        assert [line for line in text.splitlines() if line.startswith('MSG: ')] == [
            'MSG: geometry_msgs/Wrench', 'MSG: geometry_msgs/Vector3', 'MSG: std_msgs/Header',
            'MSG: builtin_interfaces/Time']
        assert text.startswith(msgdefs.msg_text(WS))
        channels = {c.topic: c for c in summary.channels.values()}
        assert {c.message_encoding for c in channels.values()} == {'cdr'}
        for topic, msgtype in ((ANGLES, JS), (WRENCH, WS)):
            meta = channels[topic].metadata
            assert meta['topic_type_hash'] == msgdefs.type_hash(msgtype)
            parsed = yaml.safe_load(meta['offered_qos_profiles'])
            assert isinstance(parsed, list) and list(parsed[0]) == QOS_KEYS
        records = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        assert len(records) == 2  # at open and at close
        final = yaml.safe_load(records[-1].metadata['serialized_metadata'])
        assert final['message_count'] == 1200 and final['ros_distro'] == 'jazzy'
        assert list(final) == V9_KEYS


# --------------------------------------------------------------------------- independent readers

def check_angles(stamp_ns, positions, rec):
    np.testing.assert_array_equal(stamp_ns, rec.angle_t)
    np.testing.assert_array_equal(np.asarray(positions), rec.angles)


def check_wrench(stamp_ns, values, rec):
    np.testing.assert_array_equal(stamp_ns, rec.wrench_t)
    np.testing.assert_array_equal(np.asarray(values), np.hstack([rec.force, rec.torque]))


def test_rosbags_anyreader_reads_everything(rec):
    data = {ANGLES: [], WRENCH: []}
    with AnyReader([rec.path]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {ANGLES: 120, WRENCH: 1080}
        for conn, timestamp, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            assert timestamp == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec + (
                RECV_DELAY_NS)
            data[conn.topic].append(msg)
    js, ws = data[ANGLES], data[WRENCH]
    assert [tuple(m.name) for m in js] == [SEGMENTS] * 120
    check_angles([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in js],
                 [m.position for m in js], rec)
    assert all(np.isnan(m.velocity).all() and np.isnan(m.effort).all() for m in js)
    check_wrench([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in ws],
                 [[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x,
                   m.wrench.torque.y, m.wrench.torque.z] for m in ws], rec)
    assert {m.header.frame_id for m in ws} == {'plate'}


def test_rosbags_rosbag2_reader_metadata(rec):
    with Rosbag2Reader(rec.path) as reader:
        assert reader.message_count == 1200
        assert reader.duration == int(rec.wrench_t[-1] - T0) + 1
        assert reader.ros_distro == 'jazzy'
        conns = {c.topic: c for c in reader.connections}
        assert conns[ANGLES].digest == msgdefs.type_hash(JS)
        (qos,) = conns[WRENCH].ext.offered_qos_profiles
        assert (qos.reliability.name, qos.depth) == ('BEST_EFFORT', 5)


def test_mcap_ros2_decoder_reads_everything(rec):
    js, ws = [], []
    with open(rec.path / 'observations_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
            (js if channel.topic == ANGLES else ws).append((message.log_time, ros_msg))
    assert (len(js), len(ws)) == (120, 1080)
    assert [t for t, _ in js] == (rec.angle_t + RECV_DELAY_NS).tolist()
    check_angles([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in js],
                 [m.position for _, m in js], rec)
    check_wrench([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in ws],
                 [[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x,
                   m.wrench.torque.y, m.wrench.torque.z] for _, m in ws], rec)


def test_read_bag_rclpy_and_read_arrays(rec):
    msgs = list(bags.read_bag(rec.path))
    assert len(msgs) == 1200
    assert [m.log_time_ns for m in msgs] == sorted(m.log_time_ns for m in msgs)
    js = [m.msg for m in msgs if m.topic == ANGLES]
    assert {m.msgtype for m in msgs if m.topic == ANGLES} == {JS}
    check_angles([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in js],
                 [m.position for m in js], rec)
    angles = bags.read_arrays(rec.path, ANGLES)
    assert angles.names == SEGMENTS
    check_angles(angles.stamp_ns, angles.position, rec)
    np.testing.assert_array_equal(angles.log_time_ns, rec.angle_t + RECV_DELAY_NS)
    assert np.isnan(angles.velocity).all()
    wrench = bags.read_arrays(rec.path / 'observations_0.mcap', WRENCH)  # bare file too
    check_wrench(wrench.stamp_ns, np.hstack([wrench.force, wrench.torque]), rec)
    assert wrench.frame_id == 'plate'
    with pytest.raises(KeyError, match='/nope'):
        bags.read_arrays(rec.path, '/nope')


def test_bare_mcap_info_matches_folder(rec):
    folder = bags.bag_info(rec.path)
    bare = bags.bag_info(rec.path / 'observations_0.mcap')
    for field in ('start_ns', 'duration_ns', 'message_count', 'ros_distro'):
        assert getattr(bare, field) == getattr(folder, field)
    assert sorted(bare.topics, key=lambda t: t.name) == sorted(folder.topics,
                                                               key=lambda t: t.name)
    assert bare.bag_size == (rec.path / 'observations_0.mcap').stat().st_size
    assert folder.bag_size == sum(p.stat().st_size for p in rec.path.iterdir())


@pytest.mark.parametrize('compression', ['lz4', 'none'])
def test_other_compressions_read_back(tmp_bag, compression):
    rec = write_observations(tmp_bag(compression), compression)
    with AnyReader([rec.path]) as reader:
        ws = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
              if c.topic == WRENCH]
    assert [m.wrench.force.x for m in ws] == rec.force[:, 0].tolist()
    angles = bags.read_arrays(rec.path, ANGLES)
    check_angles(angles.stamp_ns, angles.position, rec)


def _foreign_mcap(path: Path, channel_metadata: dict, rosbag2_record: dict | None = None,
                  ) -> Path:
    """A one-message MCAP written by the mcap library alone (a writer other than ours)."""
    from mcap.writer import Writer

    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema(JS, 'ros2msg', msgdefs.full_definition(JS).encode())
        channel = writer.register_channel(ANGLES, 'cdr', schema, channel_metadata)
        writer.add_message(channel, log_time=T0, data=b'', publish_time=T0)
        if rosbag2_record is not None:
            writer.add_metadata('rosbag2', rosbag2_record)
        writer.finish()
    return path


def test_foreign_mcap_without_channel_metadata_reads_as_no_qos_and_no_hash(tmp_path):
    info = bags.bag_info(_foreign_mcap(tmp_path / 'plain.mcap', {}))
    (topic,) = info.topics
    assert (topic.name, topic.type, topic.offered_qos, topic.type_hash) == (ANGLES, JS, (), '')
    assert (info.ros_distro, info.custom_data) == ('', {})


def test_unreadable_channel_qos_or_bag_metadata_is_an_error_naming_it(tmp_path):
    bad_qos = _foreign_mcap(tmp_path / 'qos.mcap', {'offered_qos_profiles': '- [unclosed'})
    with pytest.raises(bags.BagError, match=f'topic {ANGLES}: unreadable offered_qos'):
        bags.bag_info(bad_qos)
    bad_meta = _foreign_mcap(tmp_path / 'meta.mcap', {},
                             {'serialized_metadata': 'custom_data: [unclosed'})
    with pytest.raises(bags.BagError, match='unreadable serialized_metadata'):
        bags.bag_info(bad_meta)


def test_type_hash_missing_description_is_empty_unreadable_one_an_error(tmp_path, monkeypatch):
    broken = tmp_path / 'Broken.json'
    broken.write_text('{"type_hashes": [')
    other = tmp_path / 'Other.json'
    other.write_text('{"type_hashes": [{"type_name": "x_msgs/msg/Y", "hash_string": "h"}]}')
    files = {'nmt_test_msgs/msg/Missing': None, 'nmt_test_msgs/msg/Broken': broken,
             'nmt_test_msgs/msg/Other': other}
    monkeypatch.setattr(msgdefs, '_find_share_file', lambda name, suffix: files[name])
    assert msgdefs.type_hash('nmt_test_msgs/msg/Missing') == ''
    with pytest.raises(ValueError, match='unreadable type description'):
        msgdefs.type_hash('nmt_test_msgs/msg/Broken')
    with pytest.raises(ValueError, match='has no hash for nmt_test_msgs/msg/Other'):
        msgdefs.type_hash('nmt_test_msgs/msg/Other')


def test_writer_refuses_existing_nonempty_path(tmp_bag):
    path = tmp_bag()
    path.mkdir()
    bags.BagWriter(path).close()  # an empty folder is fine
    with pytest.raises(FileExistsError, match='already exists'):
        bags.BagWriter(path)
    with pytest.raises(bags.BagError, match='Could not find metadata'):
        bags.bag_info(path.parent)


# --------------------------------------------------------------------------- crash safety

def recovered_force(path: Path) -> np.ndarray:
    with AnyReader([path]) as reader:
        return np.array([reader.deserialize(raw, c.msgtype).wrench.force.x
                         for c, _, raw in reader.messages()])


def test_sigkilled_writer_is_recovered_by_reindex(tmp_bag):
    path = tmp_bag('killed')
    child = run_child_until_ready(path)
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=10)
    assert not (path / 'metadata.yaml').exists()
    with pytest.raises(bags.BagError, match='reindex'):
        list(bags.read_raw(path))
    info = bags.reindex(path)
    assert (path / 'metadata.yaml').is_file()
    force = recovered_force(path)  # rosbags reads the repaired folder
    assert 1000 <= force.size == info.message_count  # periodic flushes kept all but the tail
    np.testing.assert_array_equal(force, np.arange(force.size))
    assert info.topic('/w').type == WS and info.ros_distro == 'jazzy'
    assert bags.bag_info(path).message_count == force.size


def test_sigterm_closes_the_bag(tmp_bag):
    path = tmp_bag('terminated')
    child = run_child_until_ready(path)
    child.send_signal(signal.SIGTERM)
    assert child.wait(timeout=10) == 128 + signal.SIGTERM
    info = bags.bag_info(path)  # metadata.yaml written by close()
    force = recovered_force(path)
    assert force.size == info.message_count >= 1500
    np.testing.assert_array_equal(force, np.arange(force.size))


# --------------------------------------------------------------------------- nmt bag info

@pytest.fixture
def utc(monkeypatch):
    monkeypatch.setenv('TZ', 'UTC')
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def test_bag_info_output_format(tmp_path, utc, capsys):
    from nmt_ros.cli.main import main
    start = 1_713_995_957_676_000_000
    path = tmp_path / 'info'
    with bags.BagWriter(path) as bag:
        js = joint_states_from_arrays([start, start + 5], ['a'], position=[[1.0], [2.0]])
        bag.write('/b', js[0], start)
        bag.write('/a', wrenches_from_arrays([0], 'p', [[1.0, 2.0, 3.0]])[0],
                  start + 9_211_000_000)
        bag.write('/b', js[1], start + 5)
    size = sum(p.stat().st_size for p in path.iterdir())
    assert 1024 <= size < 1024**2
    expected = f'''
Files:             info_0.mcap
Bag size:          {size / 1024:.1f} KiB
Storage id:        mcap
ROS Distro:        jazzy
Duration:          9.211000000s
Start:             Apr 24 2024 21:59:17.676000000 (1713995957.676000000)
End:               Apr 24 2024 21:59:26.887000000 (1713995966.887000000)
Messages:          3
Topic information: Topic: /a | Type: geometry_msgs/msg/WrenchStamped | Count: 1 | Serialization Format: cdr
                   Topic: /b | Type: sensor_msgs/msg/JointState | Count: 2 | Serialization Format: cdr
Service:           0
Service information: 
'''  # noqa: E501, W291
    assert main(['bag', 'info', str(path)]) == 0
    assert capsys.readouterr().out == expected
    mcap = str(path / 'info_0.mcap')
    assert main(['bag', 'info', mcap]) == 0
    out = capsys.readouterr().out
    size = (path / 'info_0.mcap').stat().st_size
    assert out.startswith(f'\nFiles:             {mcap}\nBag size:          '
                          f'{size / 1024:.1f} KiB\n')
    assert out.splitlines()[3:] == expected.splitlines()[3:]
    assert main(['bag', 'info', '-t', str(path)]) == 0
    assert capsys.readouterr().out == '/a\n/b\n'


def test_bag_info_sizes_dates_services(utc):
    assert [format_size(s) for s in (0, 1023, 1024, 15462, 5 * 1024**2 + 1, 3 * 1024**5)] == [
        '0 B', '1023 B', '1.0 KiB', '15.1 KiB', '5.0 MiB', '3072.0 TiB']
    info = bags.BagInfo(
        path=Path('x'), relative_file_paths=('x_0.mcap', 'x_1.mcap'), files=(), bag_size=10,
        start_ns=1_704_430_000_000_000_001, duration_ns=0, message_count=7, ros_distro='',
        topics=(bags.TopicInfo('/srv/_service_event', 'pkg/srv/Add_Event', message_count=4),
                bags.TopicInfo('/z', 'std_msgs/msg/String', message_count=3),
                bags.TopicInfo('/q/_service_event', 'pkg/srv/Mul_Event', message_count=0)))
    assert format_bag_info(info) == '''
Files:             x_0.mcap
                   x_1.mcap
Bag size:          10 B
Storage id:        mcap
ROS Distro:        unknown
Duration:          0.000000000s
Start:             Jan  5 2024 04:46:40.000000001 (1704430000.000000001)
End:               Jan  5 2024 04:46:40.000000001 (1704430000.000000001)
Messages:          7
Topic information: Topic: /z | Type: std_msgs/msg/String | Count: 3 | Serialization Format: cdr
Service:           2
Service information: Service: /q | Type: pkg/srv/Mul | Event Count: 0 | Serialization Format: cdr
                     Service: /srv | Type: pkg/srv/Add | Event Count: 4 | Serialization Format: cdr
'''  # noqa: E501


# --------------------------------------------------------------------------- replay timing

class FakeClock:
    def __init__(self) -> None:
        self.t = 1_000_000

    def now(self) -> int:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += int(round(seconds * 1e9))


@dataclass
class Item:
    log_time_ns: int


def test_replay_scheduler_paces_by_bag_time():
    fake = FakeClock()
    sched = ReplayScheduler(rate=2.0, clock_hz=10.0, now_ns=fake.now, sleep=fake.sleep)
    items = [Item(5_000_000_000), Item(5_000_000_000), Item(5_300_000_000),
             Item(5_400_000_000)]
    emitted = [(e.kind, e.bag_time_ns, fake.now() - 1_000_000, e.late_ns)
               for e in sched.run(items)]
    # messages are due at (t - t0) / 2 of wall time; clock ticks come every 100 ms of wall
    # time and carry the bag time reached then, t0 + 2 * wall
    assert [late for *_, late in emitted] == [0] * 7
    kinds = [(k, b, w) for k, b, w, _ in emitted]
    assert kinds == [(CLOCK, 5_000_000_000, 0), (MESSAGE, 5_000_000_000, 0),
                     (MESSAGE, 5_000_000_000, 0), (CLOCK, 5_200_000_000, 100_000_000),
                     (MESSAGE, 5_300_000_000, 150_000_000),
                     (CLOCK, 5_400_000_000, 200_000_000),
                     (MESSAGE, 5_400_000_000, 200_000_000)]


def test_replay_scheduler_late_consumer_and_stop():
    fake = FakeClock()
    sched = ReplayScheduler(rate=1.0, now_ns=fake.now, sleep=fake.sleep)
    items = [Item(i * 1_000_000) for i in range(5)]  # 1 kHz
    seen = []
    for event in sched.run(items):
        seen.append(event)
        fake.t += 3_000_000  # the consumer needs 3 ms per message: nothing is dropped
    assert [e.bag_time_ns for e in seen] == [i * 1_000_000 for i in range(5)]
    assert [e.late_ns for e in seen] == [0, 2_000_000, 4_000_000, 6_000_000, 8_000_000]
    stop = threading.Event()
    out = []
    for event in ReplayScheduler(now_ns=fake.now, sleep=fake.sleep).run(items, stop=stop):
        out.append(event)
        stop.set()
    assert len(out) == 1
    with pytest.raises(ValueError, match='rate must be > 0'):
        ReplayScheduler(rate=0)


# --------------------------------------------------------------------------- player (rclpy)

@pytest.mark.ros
def _replay_to_probe(rec, ros_context, qos_override=None, node_suffix='', rate=4.0):
    """Play ``rec`` at ``rate`` with /clock to a probe (reliable angles subscription; the
    wrench subscription matches the player's wrench QoS); returns (stats, received)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    from nmt_ros.nodes.bag_player import BagPlayer

    info = bags.bag_info(rec.path)
    player_node = rclpy.create_node('test_player' + node_suffix, context=ros_context)
    probe = rclpy.create_node('test_probe' + node_suffix, context=ros_context)
    got = {ANGLES: [], WRENCH: [], '/clock': []}
    reliable = QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE)
    best_effort = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)
    player = BagPlayer(player_node, info.topics, publish_clock=True, qos_override=qos_override)
    wrench_reliable = (player.publishers[WRENCH].qos_profile.reliability
                       == ReliabilityPolicy.RELIABLE)
    probe.create_subscription(bags.msgdefs.get_message_class(JS), ANGLES, got[ANGLES].append,
                              reliable)
    probe.create_subscription(bags.msgdefs.get_message_class(WS), WRENCH, got[WRENCH].append,
                              reliable if wrench_reliable else best_effort)
    probe.create_subscription(Clock, '/clock', got['/clock'].append, best_effort)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    try:
        player.wait_for_subscribers(min_count=1, timeout_s=10.0)
        with pytest.raises(TimeoutError, match=r'/force_plate/wrench \(1\)'):
            player.wait_for_subscribers(min_count=2, timeout_s=0.2)
        result = {}
        thread = threading.Thread(target=lambda: result.update(stats=player.play(
            bags.read_raw(rec.path), rate=rate, clock_hz=40.0)))
        thread.start()
        deadline = time.monotonic() + 15.0 / rate
        while (thread.is_alive() or len(got[ANGLES]) < 120
               or (wrench_reliable and len(got[WRENCH]) < 1080)) \
                and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        thread.join()
        # take what is still queued (best effort: whatever arrived)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.01)
        return result['stats'], got, wrench_reliable
    finally:
        player.destroy()
        executor.shutdown()
        probe.destroy_node()
        player_node.destroy_node()


def _check_wrench_subset(rec, got):
    """Received wrenches are recorded ones, in order, with exact values."""
    from msg_adapters.wrench import wrenches_to_arrays

    wrench = wrenches_to_arrays(got[WRENCH])
    index = np.searchsorted(rec.wrench_t, wrench.stamp_ns)
    assert (index < rec.wrench_t.size).all()
    np.testing.assert_array_equal(rec.wrench_t[index], wrench.stamp_ns)
    assert (np.diff(index) > 0).all()
    np.testing.assert_array_equal(wrench.force, rec.force[index])
    return wrench


def test_bag_player_reliable_replay_is_lossless(rec, ros_context):
    """With a RELIABLE deep queue (how the graph replays), every message arrives, in order."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from msg_adapters.joint_state import joint_states_to_arrays

    stats, got, wrench_reliable = _replay_to_probe(
        rec, ros_context, QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE), '_r')
    assert wrench_reliable
    assert stats.per_topic == {ANGLES: 120, WRENCH: 1080}
    assert stats.all_acked
    assert 0.2 < stats.wall_s < 5.0  # 1 s of data at rate 4
    angles = joint_states_to_arrays(got[ANGLES])
    check_angles(angles.stamp_ns, angles.position, rec)
    wrench = _check_wrench_subset(rec, got)
    assert len(wrench) == 1080
    np.testing.assert_array_equal(wrench.torque, rec.torque)
    clock_ns = [c.clock.sec * 10**9 + c.clock.nanosec for c in got['/clock']]
    assert len(clock_ns) >= 5 and clock_ns[0] == T0 + RECV_DELAY_NS
    assert clock_ns == sorted(clock_ns)


def test_bag_player_best_effort_replay_keeps_recorded_qos(rec, ros_context):
    """The recorded best-effort wrench QoS is reused (as ros2 bag play does). Best effort may
    legitimately drop samples under load, so only what arrived is checked: real recorded
    samples, in order, exact values, and a substantial part of the stream (replayed at a
    quarter of real time, 270 samples/s, so that a probe on a loaded machine keeps up)."""
    from msg_adapters.joint_state import joint_states_to_arrays

    stats, got, wrench_reliable = _replay_to_probe(rec, ros_context, None, '_be', rate=0.25)
    assert not wrench_reliable  # the recorded offer (best effort) is what the player offers
    assert stats.per_topic == {ANGLES: 120, WRENCH: 1080}
    angles = joint_states_to_arrays(got[ANGLES])   # the angles topic is recorded reliable
    check_angles(angles.stamp_ns, angles.position, rec)
    wrench = _check_wrench_subset(rec, got)
    assert len(wrench) >= 1080 // 4, f'only {len(wrench)} of 1080 best-effort samples arrived'


def test_environment_is_loopback_only():
    assert os.environ['ROS_LOCALHOST_ONLY'] == '1'
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 1 <= int(os.environ['ROS_DOMAIN_ID']) <= 100
