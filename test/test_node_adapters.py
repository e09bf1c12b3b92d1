"""msg_adapters added for the node graph: planar ground wrench and CDR header stamps."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from msg_adapters.cdr_header import header_stamp_ns, header_stamps_ns
from msg_adapters.diagnostics import to_diagnostic_array
from msg_adapters.joint_state import joint_states_from_arrays
from msg_adapters.planar import (
    from_planar_wrench,
    planar_from_wrenches,
    planar_to_xyz,
    planar_wrenches_from_arrays,
    to_planar_wrench,
)

T0 = 1_700_000_000_000_000_000


def test_planar_wrench_round_trip_vectorised():
    rng = np.random.default_rng(3)
    s = rng.normal(size=(50, 3)) * [100, 800, 20]
    stamps = T0 + np.arange(50) * 925_926
    msgs = planar_wrenches_from_arrays(stamps, 'foot_com', s)
    assert all(m.header.frame_id == 'foot_com' for m in msgs)
    assert msgs[3].wrench.force.z == 0 and msgs[3].wrench.torque.x == 0
    got_stamps, got = planar_from_wrenches(msgs, 'foot_com')
    np.testing.assert_array_equal(got_stamps, stamps)
    np.testing.assert_array_equal(got, s)
    stamp, one = from_planar_wrench(msgs[7], 'foot_com')
    assert stamp == stamps[7]
    np.testing.assert_array_equal(one, s[7])
    force, torque = planar_to_xyz(s)
    np.testing.assert_array_equal(force[:, :2], s[:, :2])
    np.testing.assert_array_equal(torque[:, 2], s[:, 2])


def test_planar_wrench_validation():
    with pytest.raises(ValueError, match='non-finite value nan at index 1'):
        to_planar_wrench(T0, 'foot_com', [1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match='length 3'):
        to_planar_wrench(T0, 'foot_com', [1.0, 2.0])
    msg = to_planar_wrench(T0, 'plate', [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="frame_id is 'plate', expected 'foot_com'"):
        from_planar_wrench(msg, 'foot_com')
    msg.wrench.torque.z = float('inf')
    with pytest.raises(ValueError, match=r'non-finite value inf .*torque.z'):
        from_planar_wrench(msg)
    msg.wrench.torque.z = 0.0
    msg.wrench.force.z = float('nan')   # out of plane: ignored
    assert from_planar_wrench(msg)[1].tolist() == [1.0, 2.0, 0.0]


def test_header_stamps_from_cdr_bytes():
    stamps = T0 + np.array([0, 1, 999_999_999, 5_000_000_001])
    blobs = [serialize_message(m) for m in joint_states_from_arrays(
        stamps, ['a', 'b'], position=np.ones((4, 2)))]
    blobs.append(serialize_message(to_planar_wrench(T0 + 7, 'f', [1, 2, 3])))
    blobs.append(serialize_message(to_diagnostic_array(T0 + 9, [])))
    got = header_stamps_ns(blobs)
    np.testing.assert_array_equal(got, np.r_[stamps, T0 + 7, T0 + 9])
    assert header_stamp_ns(blobs[2]) == stamps[2]
    assert header_stamps_ns([]).shape == (0,)
    with pytest.raises(ValueError, match='too short'):
        header_stamps_ns([b'\x00\x01\x00\x00'])
    assert header_stamp_ns(serialize_message(JointState())) == 0
