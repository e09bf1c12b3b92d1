"""A live node's raw input batch decoded at once (``joint_states_from_blobs``,
``planar_wrenches_from_blobs``) must say exactly what decoding and checking each message alone
says: rclpy's own deserialisation followed by ``from_joint_state`` / ``from_planar_wrench`` is
the reference, message by message (values, stamps, the reason of every refusal)."""
from __future__ import annotations

from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from msg_adapters.joint_state import from_joint_state, joint_states_from_blobs
from msg_adapters.planar import from_planar_wrench, planar_wrenches_from_blobs
from msg_adapters.stamps import to_time

NAMES = ('foot', 'shank', 'thigh', 'hat')


def joint_state(stamp_ns, names=NAMES, position=None, velocity=None, effort=None, frame=''):
    k = len(names)
    rng = np.random.default_rng(stamp_ns % 1000)

    def field(v):
        return list(rng.normal(size=k)) if v is None else list(v)

    return JointState(header=Header(stamp=to_time(int(stamp_ns)), frame_id=frame),
                      name=list(names), position=field(position), velocity=field(velocity),
                      effort=field(effort))


def wrench_stamped(stamp_ns, values, frame='foot_com'):
    f, t = values[:3], values[3:]
    return WrenchStamped(header=Header(stamp=to_time(int(stamp_ns)), frame_id=frame),
                         wrench=Wrench(force=Vector3(x=f[0], y=f[1], z=f[2]),
                                       torque=Vector3(x=t[0], y=t[1], z=t[2])))


def reference(blobs, msg_type, parse):
    """(stamp, values) or the refusal's text per message, via rclpy's deserialisation."""
    out = []
    for blob in blobs:
        try:
            out.append(parse(deserialize_message(blob, msg_type)))
        except ValueError as exc:
            out.append(str(exc))
    return out


def assert_block_matches(block, expected):
    assert len(block) == len(expected)
    for i, want in enumerate(expected):
        if isinstance(want, str):
            assert block.errors[i] == want, i
            assert np.isnan(block.values[i]).all()
        else:
            assert block.errors[i] is None, (i, block.errors[i])
            assert block.stamp_ns[i] == want[0]
            np.testing.assert_array_equal(block.values[i], want[1])
        assert block.stamped[i]


def mixed_joint_states():
    """Mostly one layout, with the faults a live stream can carry."""
    msgs = [joint_state(1_000_000_000 + 8_333_333 * i) for i in range(40)]
    msgs[3].position[2] = float('nan')                         # an occluded segment
    msgs[5].position[0] = float('inf')
    msgs[6].velocity[1] = float('inf')                         # not a required field
    msgs[8] = joint_state(msgs[8].header.stamp.sec * 10**9, names=NAMES[::-1])  # reordered
    msgs[9] = joint_state(1_070_000_000, names=('foot', 'shank', 'thigh'))   # one missing
    msgs[10] = joint_state(1_080_000_000, names=('foot', 'foot', 'thigh', 'hat'))
    msgs[11].position = [0.1, 0.2, 0.3]                        # 3 values for 4 names
    msgs[12].position = []                                     # not provided
    msgs[13] = joint_state(1_110_000_000, frame='lab')         # another layout, still fine
    msgs[14] = joint_state(1_120_000_000, names=NAMES + ('arm',))   # an extra joint: ignored
    msgs[15].position[3] = float('-inf')
    msgs[15].position[1] = float('nan')
    return msgs


@pytest.mark.parametrize('allow_nan', [False, True])
def test_joint_state_block_says_what_each_message_says(allow_nan):
    blobs = [serialize_message(m) for m in mixed_joint_states()]

    def one(msg):
        sample = from_joint_state(msg, NAMES, require=('position',), allow_nan=allow_nan)
        return sample.stamp_ns, sample.position

    block = joint_states_from_blobs(blobs, NAMES, ('position',), require=('position',),
                                    allow_nan=allow_nan)
    expected = reference(blobs, JointState, one)
    assert_block_matches(block, expected)
    refused = sum(isinstance(e, str) for e in expected)
    assert refused == (5 if allow_nan else 7)      # the faults above, none missed


def test_joint_state_block_several_fields_in_the_callers_order():
    msgs = mixed_joint_states()
    blobs = [serialize_message(m) for m in msgs]
    fields = ('effort', 'position', 'velocity')

    def one(msg):
        s = from_joint_state(msg, NAMES, require=fields)
        return s.stamp_ns, np.concatenate([s.effort, s.position, s.velocity])

    block = joint_states_from_blobs(blobs, NAMES, fields, require=fields)
    assert_block_matches(block, reference(blobs, JointState, one))
    assert block.values.shape == (len(msgs), 12)


def test_a_block_whose_first_message_is_unreadable_decodes_the_rest():
    good = [serialize_message(joint_state(2_000_000_000 + i)) for i in range(5)]
    short = good[0][:7]                 # no room for a stamp
    cut = good[1][:30]                  # a stamp, then truncated names
    blobs = [short, cut] + good
    block = joint_states_from_blobs(blobs, NAMES, ('position',), require=('position',))
    assert block.errors[0].startswith('unreadable CDR message')
    assert block.errors[1].startswith('unreadable CDR message')
    assert not block.stamped[0] and block.stamped[1]
    assert block.stamp_ns[1] == 2_000_000_001
    for i, blob in enumerate(good):
        msg = deserialize_message(blob, JointState)
        assert block.errors[i + 2] is None
        assert block.stamp_ns[i + 2] == 2_000_000_000 + i
        np.testing.assert_array_equal(block.values[i + 2], msg.position)
    assert joint_states_from_blobs([], NAMES, ('position',)).values.shape == (0, 4)


@pytest.mark.parametrize('allow_nan', [False, True])
def test_wrench_block_says_what_each_message_says(allow_nan):
    rng = np.random.default_rng(3)
    values = rng.normal(size=(30, 6)) * 100
    values[2, 1] = np.nan
    values[4, 5] = np.inf
    values[6, 2] = np.inf               # force.z: not read, not checked
    values[7, 0] = np.nan
    values[7, 5] = -np.inf
    msgs = [wrench_stamped(5_000_000_000 + 925_926 * i, values[i]) for i in range(30)]
    msgs[9] = wrench_stamped(5_009_000_000, values[9], frame='plate_1')
    msgs[10] = wrench_stamped(5_010_000_000, values[10], frame='foot')
    blobs = [serialize_message(m) for m in msgs]
    blobs.append(blobs[0][:10])

    def one(msg):
        return from_planar_wrench(msg, 'foot_com', allow_nan=allow_nan)

    block = planar_wrenches_from_blobs(blobs, 'foot_com', allow_nan=allow_nan)
    assert_block_matches(block.__class__(block.stamp_ns[:-1], block.values[:-1],
                                         block.errors[:-1], block.stamped[:-1]),
                         reference(blobs[:-1], WrenchStamped, one))
    assert block.errors[-1].startswith('unreadable CDR message') and not block.stamped[-1]
    anyframe = planar_wrenches_from_blobs(blobs[:-1], None, allow_nan=True)
    assert anyframe.errors[9] is None and anyframe.errors[10] is None


def test_a_layout_seen_before_is_not_mistaken_for_another_of_the_same_length():
    """Decoding caches a layout by its length and structural bytes: names of the same length
    (another joint) or another frame of the same length must not reuse it."""
    seen = [serialize_message(joint_state(3_000_000_000 + i)) for i in range(3)]
    other = [serialize_message(joint_state(3_100_000_000 + i,
                                            names=('foot', 'shank', 'thigh', 'hap')))
             for i in range(3)]
    assert len(seen[0]) == len(other[0])
    for _ in range(2):                  # the second round decodes from the cache
        ok = joint_states_from_blobs(seen, NAMES, ('position',), require=('position',))
        assert all(e is None for e in ok.errors)
        bad = joint_states_from_blobs(other, NAMES, ('position',), require=('position',))
        assert all('missing' in e and 'hat' in e for e in bad.errors)
    plates = [serialize_message(wrench_stamped(4_000_000_000, np.ones(6), frame=f))
              for f in ('plate_a', 'plate_b')]
    assert len(plates[0]) == len(plates[1])
    for _ in range(2):
        assert planar_wrenches_from_blobs(plates[:1], 'plate_a').errors == (None,)
        assert planar_wrenches_from_blobs(plates[1:], 'plate_a').errors[0].startswith(
            "WrenchStamped frame_id is 'plate_b'")
