"""msg_adapters: arrays <-> messages, validation, and serialisation round trips checked with
rclpy and with rosbags (the independent CDR reader our bags must satisfy)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore

from msg_adapters import clock, diagnostics, joint_state, stamps, wrench
from msg_adapters.cdr_arrays import decode_joint_states, decode_wrenches

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
NAMES = ('foot', 'shank', 'thigh', 'hat')


def rosbags_decode(msg):
    """Serialise with rclpy, deserialise with rosbags."""
    from nmt_ros.io.msgdefs import message_type_name
    return TYPESTORE.deserialize_cdr(serialize_message(msg), message_type_name(msg))


# --------------------------------------------------------------------------- stamps

@pytest.mark.parametrize('stamp, sec, nanosec', [
    (1_713_995_957_676_000_001, 1_713_995_957, 676_000_001),
    (0, 0, 0),
    (1.5, 1, 500_000_000),
    (-1.7, -2, 300_000_000),
    (-1, -1, 999_999_999),
    (np.int64(8_333_333), 0, 8_333_333),
])
def test_to_time_splits_and_floors(stamp, sec, nanosec):
    t = stamps.to_time(stamp)
    assert (t.sec, t.nanosec) == (sec, nanosec)
    assert stamps.time_to_ns(t) == sec * 1_000_000_000 + nanosec


def test_stamp_rejections():
    with pytest.raises(ValueError, match='not finite'):
        stamps.to_ns(float('nan'))
    with pytest.raises(ValueError, match='int32'):
        stamps.to_time(2**31 * 1_000_000_000)
    with pytest.raises(ValueError, match='index 2'):
        stamps.stamps_to_ns(np.array([0.0, 1.0, np.inf]))


def test_stamps_to_ns_int_is_ns_float_is_seconds():
    assert stamps.stamps_to_ns(np.array([1, 2])).tolist() == [1, 2]
    assert stamps.stamps_to_ns(np.arange(3) / 120).tolist() == [0, 8_333_333, 16_666_667]
    sec, nanosec = stamps.split_ns(np.array([-1, 1_000_000_001]))
    assert sec.tolist() == [-1, 1] and nanosec.tolist() == [999_999_999, 1]


# --------------------------------------------------------------------------- JointState

def test_joint_state_fills_unused_arrays_with_nan():
    msg = joint_state.to_joint_state(10**9 + 5, ['ankle', 'knee', 'hip'], effort=[1.0, -2.0, 3.5])
    assert list(msg.name) == ['ankle', 'knee', 'hip']
    assert list(msg.effort) == [1.0, -2.0, 3.5]
    assert len(msg.position) == len(msg.velocity) == 3
    assert np.isnan(msg.position).all() and np.isnan(msg.velocity).all()
    sample = joint_state.from_joint_state(msg, require=('effort',))
    assert sample.stamp_ns == 10**9 + 5
    np.testing.assert_array_equal(sample.effort, [1.0, -2.0, 3.5])
    with pytest.raises(ValueError, match=r'JointState position has a non-finite value nan at '
                                         r'index 0 \(ankle\)'):
        joint_state.from_joint_state(msg, require=('position',))


def test_joint_state_rclpy_and_rosbags_round_trip():
    msg = joint_state.to_joint_state(1.25, NAMES, position=[0.1, -0.25, 0.5, 1.0],
                                     frame_id='sagittal')
    back = deserialize_message(serialize_message(msg), type(msg))
    assert list(back.name) == list(NAMES) and list(back.position) == [0.1, -0.25, 0.5, 1.0]
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (1, 250_000_000)
    assert back.header.frame_id == 'sagittal'
    theirs = rosbags_decode(msg)  # would raise 'CDR message size mismatch' with empty arrays
    assert list(theirs.name) == list(NAMES)
    np.testing.assert_array_equal(theirs.position, [0.1, -0.25, 0.5, 1.0])
    assert np.isnan(theirs.velocity).all() and np.isnan(theirs.effort).all()


def test_empty_joint_state_arrays_are_what_rosbags_rejects():
    """The reason for NaN filling (see msg_adapters.joint_state): keep as a guard."""
    from sensor_msgs.msg import JointState
    msg = JointState(name=['a', 'b'], position=[1.0, 2.0])
    with pytest.raises(Exception, match='size mismatch'):
        TYPESTORE.deserialize_cdr(serialize_message(msg), 'sensor_msgs/msg/JointState')


@pytest.mark.parametrize('kwargs, message', [
    ({'names': ['a', 'b'], 'position': [1.0, float('inf')]}, r'position .* inf at index 1 \(b\)'),
    ({'names': ['a', 'b'], 'position': [1.0]}, r'position must have length 2'),
    ({'names': ['a', 'a'], 'position': [1.0, 2.0]}, r"duplicates: \['a'\]"),
    ({'names': [], 'position': []}, r'names is empty'),
    ({'names': 'ab', 'position': [1.0, 2.0]}, r'not one string'),
    ({'names': ['a', 'b']}, r'at least one of position, velocity, effort'),
])
def test_joint_state_validation_messages(kwargs, message):
    with pytest.raises(ValueError, match=message):
        joint_state.to_joint_state(0, **kwargs)


def test_from_joint_state_reorders_and_reports_missing_names():
    msg = joint_state.to_joint_state(0, ['hip', 'knee', 'ankle'], effort=[3.0, 2.0, 1.0])
    sample = joint_state.from_joint_state(msg, ['ankle', 'knee', 'hip'])
    np.testing.assert_array_equal(sample.effort, [1.0, 2.0, 3.0])
    assert sample.names == ('ankle', 'knee', 'hip')
    with pytest.raises(ValueError, match=r"missing \['toe'\]"):
        joint_state.from_joint_state(msg, ['ankle', 'toe'])


def test_joint_state_batch_round_trip_and_cdr_decoder():
    rng = np.random.default_rng(1)
    n = 240
    t_ns = 1_700_000_000_000_000_000 + np.arange(n) * 8_333_333
    pos, vel = rng.normal(size=(n, 4)), rng.normal(size=(n, 4))
    msgs = joint_state.joint_states_from_arrays(t_ns, NAMES, position=pos, velocity=vel)
    assert len(msgs) == n
    series = joint_state.joint_states_to_arrays(msgs, require=('position', 'velocity'))
    np.testing.assert_array_equal(series.stamp_ns, t_ns)
    np.testing.assert_array_equal(series.position, pos)
    np.testing.assert_array_equal(series.velocity, vel)
    assert np.isnan(series.effort).all() and series.names == NAMES
    # through CDR: rclpy bytes decoded by the vectorised decoder and by rosbags
    blobs = [serialize_message(m) for m in msgs]
    decoded = decode_joint_states(blobs)
    np.testing.assert_array_equal(decoded.stamp_ns, t_ns)
    np.testing.assert_array_equal(decoded.position, pos)
    np.testing.assert_array_equal(decoded.velocity, vel)
    theirs = TYPESTORE.deserialize_cdr(blobs[17], 'sensor_msgs/msg/JointState')
    np.testing.assert_array_equal(theirs.velocity, vel[17])
    # back to messages from the series
    again = joint_state.series_to_joint_states(series)
    np.testing.assert_array_equal(joint_state.joint_states_to_arrays(again).position, pos)


def test_joint_state_batch_reorder_and_name_errors():
    msgs = joint_state.joint_states_from_arrays(np.arange(3), ['b', 'a'],
                                                effort=[[2.0, 1.0]] * 3)
    series = joint_state.joint_states_to_arrays(msgs, names=['a', 'b'])
    np.testing.assert_array_equal(series.effort, [[1.0, 2.0]] * 3)
    msgs[1].name = ['b', 'c']
    with pytest.raises(ValueError, match=r"message 1 has names \['b', 'c'\]"):
        joint_state.joint_states_to_arrays(msgs)
    with pytest.raises(ValueError, match=r'effort must have shape \(3, 2\)'):
        joint_state.joint_states_from_arrays(np.arange(3), ['b', 'a'], effort=np.ones((3, 3)))
    with pytest.raises(ValueError, match=r'effort has a non-finite value nan at index \(2, 1\)'):
        joint_state.joint_states_from_arrays(
            np.arange(3), ['b', 'a'], effort=[[1, 2], [3, 4], [5, np.nan]])


def test_cdr_decoder_handles_mixed_layouts():
    from sensor_msgs.msg import JointState
    msgs = joint_state.joint_states_from_arrays(np.arange(4), ['a', 'b'],
                                                position=np.arange(8.0).reshape(4, 2))
    odd = JointState(header=msgs[2].header, name=['a', 'b'], position=[4.0, 5.0])  # empties
    blobs = [serialize_message(m) for m in msgs]
    blobs[2] = serialize_message(odd)
    decoded = decode_joint_states(blobs)
    np.testing.assert_array_equal(decoded.position, np.arange(8.0).reshape(4, 2))
    assert np.isnan(decoded.velocity).all()
    blobs[3] = serialize_message(joint_state.to_joint_state(3, ['a', 'c'], position=[6, 7]))
    with pytest.raises(ValueError, match=r"message 3 has names \['a', 'c'\]"):
        decode_joint_states(blobs)


# --------------------------------------------------------------------------- WrenchStamped

def test_wrench_round_trips():
    msg = wrench.to_wrench_stamped(2_000_000_001, 'plate_origin', [10.0, 700.5, -0.25],
                                   [0.0, 0.0, 12.5])
    back = deserialize_message(serialize_message(msg), type(msg))
    assert back == msg
    sample = wrench.from_wrench_stamped(back, frame_id='plate_origin')
    assert sample.stamp_ns == 2_000_000_001
    np.testing.assert_array_equal(sample.force, [10.0, 700.5, -0.25])
    np.testing.assert_array_equal(sample.torque, [0.0, 0.0, 12.5])
    theirs = rosbags_decode(msg)
    assert (theirs.wrench.force.y, theirs.wrench.torque.z) == (700.5, 12.5)
    with pytest.raises(ValueError, match="frame_id is 'plate_origin', expected 'cop'"):
        wrench.from_wrench_stamped(back, frame_id='cop')
    with pytest.raises(ValueError, match=r'force has a non-finite value nan at index 1 \(y\)'):
        wrench.to_wrench_stamped(0, 'p', [0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match='torque must have length 3'):
        wrench.to_wrench_stamped(0, 'p', [0.0, 0.0, 0.0], [1.0])


def test_wrench_batch_round_trip():
    rng = np.random.default_rng(2)
    n = 1080
    t_ns = np.arange(n) * 925_926
    force, torque = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    msgs = wrench.wrenches_from_arrays(t_ns, 'plate', force, torque)
    series = wrench.wrenches_to_arrays(msgs, frame_id='plate')
    np.testing.assert_array_equal(series.stamp_ns, t_ns)
    np.testing.assert_array_equal(series.force, force)
    np.testing.assert_array_equal(series.torque, torque)
    decoded = decode_wrenches([serialize_message(m) for m in msgs])
    np.testing.assert_array_equal(decoded.force, force)
    np.testing.assert_array_equal(decoded.torque, torque)
    assert decoded.frame_id == 'plate'
    msgs[5].header.frame_id = 'other'
    with pytest.raises(ValueError, match="message 5 has frame_id 'other'"):
        wrench.wrenches_to_arrays(msgs)


# --------------------------------------------------------------------------- diagnostics, clock

def test_diagnostics_round_trip():
    records = [
        diagnostics.StatusRecord('OK', 'skeletal_tracker', 'tracking',
                                 {'lag_ms': 4.25, 'samples': np.int64(120), 'converged': True}),
        diagnostics.StatusRecord(diagnostics.WARN, 'observation_publisher', 'rejected sample',
                                 {'reason': 'position has a non-finite value nan at index 1'},
                                 hardware_id='mocap'),
    ]
    msg = diagnostics.to_diagnostic_array(3_000_000_000, records)
    back = deserialize_message(serialize_message(msg), type(msg))
    stamp, out = diagnostics.from_diagnostic_array(back)
    assert stamp == 3_000_000_000
    assert [(r.level, r.name, r.message, r.hardware_id) for r in out] == [
        (0, 'skeletal_tracker', 'tracking', ''),
        (1, 'observation_publisher', 'rejected sample', 'mocap')]
    assert out[0].values == {'lag_ms': '4.25', 'samples': '120', 'converged': 'true'}
    theirs = rosbags_decode(msg)
    assert [s.level for s in theirs.status] == [0, 1]
    as_tuple = diagnostics.to_diagnostic_array(0, [('ERROR', 'muscle_tracker', 'lost control')])
    assert (as_tuple.status[0].level, as_tuple.status[0].message) == (b'\x02', 'lost control')
    with pytest.raises(ValueError, match='unknown diagnostic level'):
        diagnostics.to_status(diagnostics.StatusRecord('FATAL', 'x'))
    assert diagnostics.format_value(math.inf) == 'inf'


def test_clock_round_trip():
    msg = clock.to_clock(5.000000001)
    back = deserialize_message(serialize_message(msg), type(msg))
    assert clock.clock_to_ns(back) == 5_000_000_001
    assert rosbags_decode(msg).clock.nanosec == 1


def test_cdr_padding_is_zeroed_without_changing_the_message():
    """rclpy leaves CDR alignment padding uninitialised; zero_padding makes the bytes a
    function of the values (same data, same bag): equal to an independent serializer's
    (rosbags, pure Python, zero padding), and the message decodes the same."""
    import numpy as np
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import JointState

    from msg_adapters.cdr_padding import zero_padding

    ts = get_typestore(Stores.LATEST)
    T, H = ts.types['builtin_interfaces/msg/Time'], ts.types['std_msgs/msg/Header']
    JS, WS = ts.types['sensor_msgs/msg/JointState'], ts.types['geometry_msgs/msg/WrenchStamped']
    W, V = ts.types['geometry_msgs/msg/Wrench'], ts.types['geometry_msgs/msg/Vector3']
    js = JointState()
    js.header.stamp.sec, js.header.stamp.nanosec = 3, 5
    js.header.frame_id = 'ab'                   # 3 bytes + length: padding follows
    js.name = ['foot', 'shank', 'hat']
    js.position = [0.1, -0.2, 0.3]
    js.effort = [1.0, 2.0, 3.0]
    other = JS(header=H(stamp=T(sec=3, nanosec=5), frame_id='ab'),
               name=['foot', 'shank', 'hat'], position=np.array([0.1, -0.2, 0.3]),
               velocity=np.zeros(0), effort=np.array([1.0, 2.0, 3.0]))
    from geometry_msgs.msg import WrenchStamped

    ws = WrenchStamped()
    ws.header.frame_id = 'foot_com'
    ws.wrench.force.y = 700.0
    ws.wrench.torque.z = -3.5
    other_ws = WS(header=H(stamp=T(sec=0, nanosec=0), frame_id='foot_com'),
                  wrench=W(force=V(x=0.0, y=700.0, z=0.0), torque=V(x=0.0, y=0.0, z=-3.5)))
    for msg, ref, kind in ((js, other, 'sensor_msgs/msg/JointState'),
                           (ws, other_ws, 'geometry_msgs/msg/WrenchStamped')):
        raw = serialize_message(msg)
        clean = zero_padding(raw, kind)
        expected = bytes(ts.serialize_cdr(ref, kind))
        # rclpy's buffer may end in alignment bytes the other leaves out: zero too
        assert clean[:len(expected)] == expected and not any(clean[len(expected):])
        assert deserialize_message(clean, type(msg)) == msg
        assert all(c == 0 for r, c in zip(raw, clean) if r != c)   # only padding changed
    assert zero_padding(b'\x00\x01\x00\x00abc', 'std_msgs/msg/String') == \
        b'\x00\x01\x00\x00abc'


def test_serialised_messages_equal_rclpy_and_rosbags():
    """``joint_state_blobs`` / ``wrench_blobs`` / ``planar_wrench_blobs`` (the bytes a node
    publishes without building message objects) equal rclpy's serialisation of the message
    functions' output with its padding zeroed, deserialise with rclpy to the same messages,
    and decode with rosbags (an independent CDR reader) to the same values; they check their
    input as the message functions do."""
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    from msg_adapters.cdr_padding import zero_padding
    from msg_adapters.planar import planar_wrench_blobs, planar_wrenches_from_arrays

    rng = np.random.default_rng(3)
    stamp = np.array([0, 1_700_000_000_123_456_789, 1_700_000_001_999_999_999], dtype=np.int64)
    pos, eff = rng.normal(size=(3, 4)), 100 * rng.normal(size=(3, 4))
    for frame in ('', 'ab', 'lab_frame'):      # string lengths that need padding or none
        blobs = joint_state.joint_state_blobs(stamp, NAMES, position=pos, effort=eff,
                                              frame_id=frame)
        msgs = joint_state.joint_states_from_arrays(stamp, NAMES, position=pos, effort=eff,
                                                    frame_id=frame)
        for b, m in zip(blobs, msgs):
            assert b == zero_padding(serialize_message(m), 'sensor_msgs/msg/JointState')
            back = deserialize_message(b, JointState)       # (NaN != NaN: fields compared)
            assert back.header == m.header and back.name == m.name
            for field in ('position', 'velocity', 'effort'):
                np.testing.assert_array_equal(getattr(back, field), getattr(m, field))
            theirs = TYPESTORE.deserialize_cdr(b, 'sensor_msgs/msg/JointState')
            assert theirs.name == list(NAMES) and theirs.header.frame_id == frame
            np.testing.assert_array_equal(theirs.position, m.position)
            assert np.isnan(theirs.velocity).all()
        s = rng.normal(size=(3, 3))
        blobs = planar_wrench_blobs(stamp, frame, s)
        for b, m in zip(blobs, planar_wrenches_from_arrays(stamp, frame, s)):
            assert b == zero_padding(serialize_message(m), 'geometry_msgs/msg/WrenchStamped')
            assert deserialize_message(b, WrenchStamped) == m
        f = rng.normal(size=(3, 3))
        for b, m in zip(wrench.wrench_blobs(stamp, frame, f),
                        wrench.wrenches_from_arrays(stamp, frame, f)):
            assert b == zero_padding(serialize_message(m), 'geometry_msgs/msg/WrenchStamped')
            theirs = TYPESTORE.deserialize_cdr(b, 'geometry_msgs/msg/WrenchStamped')
            assert theirs.wrench.force.x == m.wrench.force.x
            assert theirs.header.stamp.nanosec == m.header.stamp.nanosec
    assert joint_state.joint_state_blobs(np.zeros(0, dtype=np.int64), NAMES,
                                         position=np.zeros((0, 4))) == []
    bad = pos.copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match='position'):
        joint_state.joint_state_blobs(stamp, NAMES, position=bad)
    with pytest.raises(ValueError):
        wrench.wrench_blobs(stamp, 'x', np.full((3, 3), np.inf))
