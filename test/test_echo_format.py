"""`nmt echo`: ros2-topic-echo text for messages (literal expectations), and the echo
machinery receiving a JointState over a private rclpy Context."""
from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from msg_adapters.joint_state import to_joint_state
from msg_adapters.wrench import to_wrench_stamped
from nmt_ros.io.msg_yaml import format_echo, message_to_ordereddict


def ros2_example() -> JointState:
    msg = JointState(name=['hip_flexion_r', 'knee_angle_r'], position=[0.1, -0.25])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1, 8333333
    return msg


def test_joint_state_yaml():
    assert format_echo(ros2_example()) == '''\
header:
  stamp:
    sec: 1
    nanosec: 8333333
  frame_id: ''
name:
- hip_flexion_r
- knee_angle_r
position:
- 0.1
- -0.25
velocity: []
effort: []
---
'''


def test_adapter_joint_state_shows_nan_for_not_provided():
    msg = to_joint_state(2_500_000_000, ['ankle'], effort=[-12.5], frame_id='model')
    assert format_echo(msg) == '''\
header:
  stamp:
    sec: 2
    nanosec: 500000000
  frame_id: model
name:
- ankle
position:
- .nan
velocity:
- .nan
effort:
- -12.5
---
'''


def test_wrench_yaml_and_csv():
    msg = to_wrench_stamped(1_000_000_007, 'plate', [1.5, 700.0, 0.0], [0.0, 0.0, -3.25])
    assert format_echo(msg) == '''\
header:
  stamp:
    sec: 1
    nanosec: 7
  frame_id: plate
wrench:
  force:
    x: 1.5
    y: 700.0
    z: 0.0
  torque:
    x: 0.0
    y: 0.0
    z: -3.25
---
'''
    assert format_echo(msg, csv=True) == '1,7,plate,1.5,700.0,0.0,0.0,0.0,-3.25\n'


def test_no_arr_no_str_and_flow_style():
    msg = ros2_example()
    assert format_echo(msg, no_arr=True, no_str=True) == '''\
header:
  stamp:
    sec: 1
    nanosec: 8333333
  frame_id: '<string length: <0>>'
name: '<sequence type: string, length: 2>'
position: '<sequence type: double, length: 2>'
velocity: '<sequence type: double, length: 0>'
effort: '<sequence type: double, length: 0>'
---
'''
    assert format_echo(msg, flow_style=True).splitlines()[-6:] == [
        "  frame_id: ''", 'name: [hip_flexion_r, knee_angle_r]', 'position: [0.1, -0.25]',
        'velocity: []', 'effort: []', '---']
    assert format_echo(msg, csv=True) == '1,8333333,,hip_flexion_r,knee_angle_r,0.1,-0.25,,\n'


def test_truncation_of_sequences_strings_and_special_floats():
    msg = Float64MultiArray(data=[1e-05, float('nan'), float('inf'), 1e20, 3.0])
    msg.layout.dim = [MultiArrayDimension(label='muscle', size=5, stride=5)]
    assert format_echo(msg, truncate_length=3) == '''\
layout:
  dim:
  - label: mus...
    size: 5
    stride: 5
  data_offset: 0
data:
- 1.0e-05
- .nan
- .inf
- '...'
---
'''
    assert format_echo(msg, truncate_length=3, csv=True) == 'mus...,5,5,0,1e-05,nan,inf,...\n'
    assert format_echo(String(data='x' * 130)) == 'data: ' + 'x' * 128 + '...\n---\n'
    assert format_echo(String(data='x' * 130), truncate_length=None) == (
        'data: ' + 'x' * 130 + '\n---\n')


def test_byte_fields_and_nested_sequences():
    msg = DiagnosticArray(status=[DiagnosticStatus(
        level=b'\x01', name='skeletal_tracker', message='lag',
        values=[KeyValue(key='lag_ms', value='1.5')])])
    assert format_echo(msg) == '''\
header:
  stamp:
    sec: 0
    nanosec: 0
  frame_id: ''
status:
- level: "\\x01"
  name: skeletal_tracker
  message: lag
  hardware_id: ''
  values:
  - key: lag_ms
    value: '1.5'
---
'''
    d = message_to_ordereddict(msg)
    assert list(d) == ['header', 'status'] and d['status'][0]['level'] == '\x01'


# --------------------------------------------------------------------------- echo over ROS

TOPIC = '/echo_test/segment_angles'
EXPECTED = '''\
header:
  stamp:
    sec: 3
    nanosec: 250000000
  frame_id: ''
name:
- foot
- shank
position:
- 0.5
- -1.0
velocity:
- .nan
- .nan
effort:
- .nan
- .nan
---
'''


@pytest.fixture
def publisher(ros_context):
    """A node publishing one JointState every 20 ms (reliable) on TOPIC."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node = rclpy.create_node('echo_test_publisher', context=ros_context)
    pub = node.create_publisher(JointState, TOPIC,
                                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    msg = to_joint_state(3.25, ['foot', 'shank'], position=[0.5, -1.0])
    node.create_timer(0.02, lambda: pub.publish(msg))
    yield node
    node.destroy_node()


@pytest.mark.ros
def test_echo_machinery_receives_and_formats(ros_context, publisher):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import ReliabilityPolicy

    from nmt_ros.cli.echo import EchoOptions, choose_qos, echo

    node = rclpy.create_node('echo_test_subscriber', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(publisher)
    executor.add_node(node)
    out, warnings = [], []
    try:
        count = echo(node, executor, 'echo_test/segment_angles',  # relative name resolves
                     options=EchoOptions(once=True, timeout_s=10.0), write=out.append,
                     warn=warnings.append)
        assert count == 1
        assert out == [EXPECTED]
        assert choose_qos(node, TOPIC).reliability == ReliabilityPolicy.RELIABLE
        out.clear()
        count = echo(node, executor, TOPIC, options=EchoOptions(once=True, timeout_s=10.0,
                                                                  csv=True), write=out.append)
        assert out == ['3,250000000,,foot,shank,0.5,-1.0,nan,nan,nan,nan\n']
        with pytest.raises(TimeoutError, match='could not determine the type of /nobody'):
            echo(node, executor, '/nobody', options=EchoOptions(timeout_s=0.2), write=out.append,
                 warn=warnings.append)
        assert 'WARNING: topic [/nobody] does not appear to be published yet' in warnings
    finally:
        executor.shutdown()
        node.destroy_node()


@pytest.mark.ros
def test_nmt_echo_command(ros_context, publisher, capsys):
    from rclpy.executors import SingleThreadedExecutor

    from nmt_ros.cli.main import main

    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(publisher)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        assert main(['echo', TOPIC, '--once', '--timeout', '10']) == 0
        assert capsys.readouterr().out == EXPECTED
    finally:
        executor.shutdown()
        thread.join(timeout=5)
    assert main(['echo', '/nobody_here', 'std_msgs/msg/String', '--once', '--timeout',
                 '0.2']) == 1
    assert 'no message received on /nobody_here' in capsys.readouterr().err
