"""The nodes in-process (private Context, one executor): the whole graph on the shipped bag,
bad input on both trackers, the recorder's QoS rules, and the shipped parameter files."""
from __future__ import annotations

import contextlib
from pathlib import Path
import time

from conftest import batch_samples
import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'reference_jump'
ANGLES, WRENCH = '/mocap/segment_angles', '/force_plate/wrench'
TORQUES = '/nmt/skeletal/joint_torques'
SKELETAL_OUT = (TORQUES, '/nmt/skeletal/segment_angles', '/nmt/skeletal/generalized_coordinates',
                '/nmt/skeletal/ground_wrench')
MUSCLE_OUT = ('/nmt/muscle/forces', '/nmt/muscle/activations', '/nmt/muscle/excitations')


def params(**values):
    from rclpy.parameter import Parameter

    return [Parameter(k, value=v) for k, v in values.items()]


def spin_until(executor, condition, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)
    return condition()


class StatusProbe:
    """Collects /nmt/status records (as msg_adapters StatusRecords)."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray

        from nmt_ros.nodes.node_base import STATUS_QOS

        self.records = []
        node.create_subscription(DiagnosticArray, '/nmt/status', self._on, STATUS_QOS)

    def _on(self, msg):
        from msg_adapters.diagnostics import from_diagnostic_array

        self.records.extend(from_diagnostic_array(msg)[1])

    def text(self, node=''):
        return '\n'.join(f'{r.name}: {r.message} {dict(r.values)}' for r in self.records
                         if r.name.startswith(node))


# --------------------------------------------------------------------------- whole graph

@pytest.mark.slow
def test_graph_in_process_tracks_the_bag_and_records_everything(ros_context, tmp_path):
    from rclpy.executors import SingleThreadedExecutor

    from nmt_ros.io.bags import bag_info, read_arrays
    from nmt_ros.nodes.muscle_tracker import MuscleTrackerNode
    from nmt_ros.nodes.observation_publisher import ObservationPublisherNode
    from nmt_ros.nodes.recorder import RecorderNode
    from nmt_ros.nodes.skeletal_tracker import SkeletalTrackerNode
    from nmt_ros.study.recording_evaluation import graph_summary

    out = tmp_path / 'recording'
    rec = RecorderNode(context=ros_context, parameter_overrides=params(output=str(out)))
    muscle = MuscleTrackerNode(context=ros_context, parameter_overrides=params(
        wait_for=[f'{t}=1' for t in MUSCLE_OUT], exit_when_finished=True))
    skel = SkeletalTrackerNode(context=ros_context, parameter_overrides=params(
        wait_for=[f'{TORQUES}=2'] + [f'{t}=1' for t in SKELETAL_OUT[1:]], substeps=1,
        exit_when_finished=True))
    obs = ObservationPublisherNode(context=ros_context, parameter_overrides=params(
        bag=str(BAG), expected_subscribers=2))
    nodes = (rec, muscle, skel, obs)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in nodes:
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: obs.done and skel.done and muscle.done, 60.0), \
            [n.status.reports()[0] for n in nodes]
        spin_until(executor, lambda: False, 0.3)
        for n in (obs, skel, muscle):
            n.on_shutdown(False)
        rec.on_shutdown(False)
    finally:
        for n in nodes:
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()
    assert obs.exit_code == 0 and skel.exit_code == 0 and muscle.exit_code == 0
    assert skel.status.state == 'finished' and muscle.status.state == 'finished', (
        muscle.status.reports()[0].message, muscle.status.reports()[0].values)
    assert skel.status.rejected == {} and muscle.status.rejected == {}
    info = {t.name: t.message_count for t in bag_info(out).topics}
    assert info[ANGLES] == 30 and info[WRENCH] == 269
    for topic in SKELETAL_OUT:
        assert info[topic] == skel.status.published[topic] == batch_samples(), topic
    for topic in MUSCLE_OUT:   # Stage 2 bridges instants Stage 1 withheld
        assert info[topic] == muscle.status.published[topic] >= batch_samples(), topic
    # every estimate is stamped with a force-plate instant of the trial
    wrench = read_arrays(out, WRENCH)
    torques = read_arrays(out, TORQUES)
    assert np.isin(torques.stamp_ns, wrench.stamp_ns).all()
    assert (np.diff(torques.stamp_ns) > 0).all()
    summary = graph_summary(out, BAG)
    assert summary['lossless']
    assert max(summary['vs_batch']['torque_rms_pct_peak'].values()) < 2.0
    assert max(summary['vs_batch']['muscle_force_rms_pct_f0'].values()) < 2.0
    assert summary['latency_ms']['joint_torques']['n'] == batch_samples()
    assert summary['latency_ms']['joint_torques']['min_ms'] > 0


# --------------------------------------------------------------------------- bad input

def _observations():
    from nmt_ros.io.trial_bag import read_observations
    from nmt_ros.records import TRIAL_EPOCH_NS

    obs = read_observations(BAG)
    sa = TRIAL_EPOCH_NS + np.rint(obs.t_angles * 1e9).astype(np.int64)
    sw = TRIAL_EPOCH_NS + np.rint(obs.t_wrench * 1e9).astype(np.int64)
    return obs, sa, sw


def _tracker_io(probe, source):
    """(status probe and joint-torque list on ``probe``, angle and wrench publishers on
    ``source``): what a test of the skeletal tracker node wires around it."""
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    from nmt_ros.nodes.node_base import data_qos

    status = StatusProbe(probe)
    outputs = []
    probe.create_subscription(JointState, TORQUES, outputs.append, data_qos(5000))
    return (status, outputs, source.create_publisher(JointState, ANGLES, data_qos(5000)),
            source.create_publisher(WrenchStamped, WRENCH, data_qos(5000)))


@pytest.mark.slow
def test_skeletal_tracker_rejects_bad_input_and_keeps_running(ros_context, tmp_path):
    from geometry_msgs.msg import WrenchStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from msg_adapters.joint_state import to_joint_state
    from msg_adapters.planar import to_planar_wrench
    from nmt_ros.io.bags import bag_info, read_raw
    from nmt_ros.nodes.node_base import data_qos
    from nmt_ros.nodes.recorder import RecorderNode
    from nmt_ros.nodes.skeletal_tracker import SkeletalTrackerNode

    obs, sa, sw = _observations()
    segs = ['foot', 'shank', 'thigh', 'hat']
    skel = SkeletalTrackerNode(context=ros_context, parameter_overrides=params(
        estimator='skt', lookahead_s=0.03, substeps=1, idle_flush_s=2.0))
    record = tmp_path / 'rec'
    rec = RecorderNode(context=ros_context, parameter_overrides=params(
        output=str(record), topics=[ANGLES, WRENCH, TORQUES], scan_period_s=0.02))
    probe = rclpy.create_node('probe', context=ros_context)
    source = rclpy.create_node('lab', context=ros_context)
    status, outputs, pub_a, pub_w = _tracker_io(probe, source)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (skel, probe, source, rec):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: pub_a.get_subscription_count() == 2
                          and pub_w.get_subscription_count() == 2, 10.0)
        # a 100 ms hole in both streams, between 0.10 and 0.20 s
        keep_a = (obs.t_angles < 0.1) | (obs.t_angles >= 0.2)
        keep_w = (obs.t_wrench < 0.1) | (obs.t_wrench >= 0.2)
        events = sorted([(sa[i], 0, i) for i in np.flatnonzero(keep_a)]
                        + [(sw[i], 1, i) for i in np.flatnonzero(keep_w)])
        def nan_angles():
            msg = to_joint_state(sa[5], segs, obs.angles[5])
            msg.position[1] = float('nan')
            return msg

        def inf_force():
            msg = to_planar_wrench(sw[40], 'foot_com', obs.wrench[40])
            msg.wrench.force.y = float('inf')
            return msg

        bad = {(0, 5): nan_angles, (1, 40): inf_force}
        for stamp, kind, i in events:
            if kind == 0:
                msg = bad[0, i]() if (0, i) in bad else to_joint_state(stamp, segs, obs.angles[i])
                pub_a.publish(msg)
                if i == 7:   # wrong length, wrong names
                    short = to_joint_state(stamp, segs, obs.angles[i])
                    short.position = short.position[:3]
                    pub_a.publish(short)
                    pub_a.publish(to_joint_state(stamp + 1, ['a', 'b', 'c', 'd'], [0] * 4))
            else:
                msg = bad[1, i]() if (1, i) in bad else to_planar_wrench(stamp, 'foot_com',
                                                                         obs.wrench[i])
                pub_w.publish(msg)
                if i == 60:   # duplicate, out of order, wrong frame
                    pub_w.publish(msg)
                    pub_w.publish(to_planar_wrench(sw[50], 'foot_com', obs.wrench[50]))
                    pub_w.publish(to_planar_wrench(stamp + 10, 'plate', obs.wrench[i]))
            executor.spin_once(timeout_sec=0)
        n_events = len(events) + 5
        assert spin_until(executor, lambda: skel.status.received.get(ANGLES, 0)
                          + skel.status.received.get(WRENCH, 0) >= n_events, 20.0), (
            n_events, skel.status.received, skel.status.rejected)
        source.destroy_publisher(pub_a)      # the lab's publisher dies
        source.destroy_publisher(pub_w)
        assert spin_until(executor, lambda: skel.status.state == 'finished', 10.0), \
            skel.status.reports()[0]
        spin_until(executor, lambda: False, 0.2)
        text = status.text('/skeletal_tracker')
        for words in ('non-finite value nan at index 1 (shank)',
                      'non-finite value inf at index 1 (force.y)',
                      'position has 3 values for 4 names',
                      "missing ['foot', 'shank', 'thigh', 'hat']",
                      "frame_id is 'plate', expected 'foot_com'",
                      'duplicate stamp', 'wrench: gap of 100.9 ms', 'angles: gap of 108.3 ms',
                      'filled with 108 interpolated samples', 'publisher gone'):
            assert words in text, words
        assert skel.status.rejected == {ANGLES: 3, WRENCH: 4}
        assert skel.stream.status == 'ok'
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                           for m in outputs])
        assert (np.diff(stamps) > 0).all() and stamps[-1] > sw[0] + 200_000_000
        # still alive: a new lab publisher starts a new trial
        pub_a = source.create_publisher(JointState, ANGLES, data_qos(5000))
        pub_w = source.create_publisher(WrenchStamped, WRENCH, data_qos(5000))
        assert spin_until(executor, lambda: pub_w.get_subscription_count() == 2, 10.0)
        later = 5_000_000_000
        for i in range(3):
            pub_a.publish(to_joint_state(sa[i] + later, segs, obs.angles[i]))
            pub_w.publish(to_planar_wrench(sw[i] + later, 'foot_com', obs.wrench[i]))
        assert spin_until(executor, lambda: skel.book.trial == 2, 5.0)
        rec.on_shutdown(False)
    finally:
        for n in (skel, probe, source, rec):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()
    # the recording kept everything, bad samples included, and is readable
    counts = {t.name: t.message_count for t in bag_info(record).topics}
    assert counts[ANGLES] == int(keep_a.sum()) + 2 + 3
    assert counts[WRENCH] == int(keep_w.sum()) + 3 + 3
    assert counts[TORQUES] == len(outputs) > 0
    assert sum(1 for _ in read_raw(record, [ANGLES])) == counts[ANGLES]


@contextlib.contextmanager
def _mhe_node(ros_context, probe_name, **overrides):
    """A skeletal tracker node (estimator 'mhe', ``overrides``) and a probe wired around it
    (``_tracker_io``) on one executor, its inputs matched; torn down afterwards. Yields
    (node, status probe, joint-torque list, angle publisher, wrench publisher, executor)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from nmt_ros.nodes.skeletal_tracker import SkeletalTrackerNode

    skel = SkeletalTrackerNode(context=ros_context, parameter_overrides=params(
        **{'estimator': 'mhe', 'idle_flush_s': 2.0, **overrides}))
    probe = rclpy.create_node(probe_name, context=ros_context)
    status, outputs, pub_a, pub_w = _tracker_io(probe, probe)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (skel, probe):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: pub_w.get_subscription_count() == 1, 10.0)
        yield skel, status, outputs, pub_a, pub_w, executor
    finally:
        for n in (skel, probe):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


def _in_stamp_order(sa, sw, n_a):
    """The first ``n_a`` angle samples and the force-plate samples up to the last of them,
    as (stamp, 0 = angle | 1 = wrench, index) in stamp order; and that wrench count."""
    n_w = int(np.searchsorted(sw, sa[n_a - 1], side='right'))
    return sorted([(sa[i], 0, i) for i in range(n_a)]
                  + [(sw[i], 1, i) for i in range(n_w)]), n_w


def _publish_in_order(events, obs, pub_a, pub_w, executor=None):
    """Publish ``events`` ((stamp, 0 = angle | 1 = wrench, index), ``_in_stamp_order``) of
    ``obs``; with ``executor``, spin it once after each message."""
    from msg_adapters.joint_state import to_joint_state
    from msg_adapters.planar import to_planar_wrench

    for stamp, kind, i in events:
        if kind == 0:
            pub_a.publish(to_joint_state(stamp, ['foot', 'shank', 'thigh', 'hat'],
                                         obs.angles[i]))
        else:
            pub_w.publish(to_planar_wrench(stamp, 'foot_com', obs.wrench[i]))
        if executor is not None:
            executor.spin_once(timeout_sec=0)


@pytest.mark.slow
def test_moving_horizon_node_estimates_from_start_s_on(ros_context):
    """start_s (a support the plates do not measure before it, e.g. a drop jump's box): the
    samples before it are counted and said once on /nmt/status, not used; the estimates
    start at the first force-plate instant from start_s and cover every one after it."""
    obs, sa, sw = _observations()
    start_s = 0.05
    n_a = 30                                      # 0.24 s of the reference jump
    events, n_w = _in_stamp_order(sa, sw, n_a)
    with _mhe_node(ros_context, 'probe_start', start_s=start_s) as (
            skel, status, outputs, pub_a, pub_w, executor):
        _publish_in_order(events, obs, pub_a, pub_w, executor)
        assert spin_until(executor, lambda: skel.status.state == 'finished', 20.0), \
            skel.status.reports()[0]
        published = skel.status.published[TORQUES]
        assert spin_until(executor, lambda: len(outputs) >= published, 10.0)
        early = int((obs.t_angles[:n_a] < start_s - 1e-9).sum()
                    + (obs.t_wrench[:n_w] < start_s - 1e-9).sum())
        assert skel.status.extra['before_start'] == early > 0
        said = [r for r in status.records if 'before start_s = 0.05 s are not estimated'
                in r.message]
        assert said and len({r.message for r in said}) == 1
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in outputs])
    expected = sw[:n_w][obs.t_wrench[:n_w] >= start_s - 1e-9]
    assert np.array_equal(stamps, expected), (stamps[:3], expected[:3])


@pytest.mark.slow
def test_moving_horizon_node_reports_bad_input_and_bridges_missing_values(ros_context):
    """The default Stage 1 (estimator 'mhe'): a NaN angle is a missing value (reported, then
    bridged by the dynamics: the estimates go on at every instant), so is a saturated
    plate reading (reported; its instants still estimated), inf, short, misnamed,
    wrongly framed, duplicate and late samples are rejected and reported; nothing published
    is non-finite, and the estimates are stamped with force-plate instants."""
    from msg_adapters.joint_state import to_joint_state
    from msg_adapters.planar import to_planar_wrench
    from nmt_ros.model.jumper import default_model

    obs, sa, sw = _observations()
    segs = ['foot', 'shank', 'thigh', 'hat']
    clipped = 3.0 * default_model().p.body_weight
    n_a = 22                                      # 0.175 s of the reference jump
    events, n_w = _in_stamp_order(sa, sw, n_a)
    with _mhe_node(ros_context, 'probe_mhe') as (skel, status, outputs, pub_a, pub_w,
                                                 executor):
        for stamp, kind, i in events:
            if kind == 0:
                msg = to_joint_state(stamp, segs, obs.angles[i])
                if i in (14, 15):                 # an occlusion of the shank: two samples
                    msg.position[1] = float('nan')
                pub_a.publish(msg)
                if i == 7:
                    short = to_joint_state(stamp, segs, obs.angles[i])
                    short.position = short.position[:3]
                    pub_a.publish(short)
                    pub_a.publish(to_joint_state(stamp + 1, ['a', 'b', 'c', 'd'], [0] * 4))
            else:
                msg = to_planar_wrench(stamp, 'foot_com', obs.wrench[i])
                if i == 40:
                    msg.wrench.force.y = float('inf')
                if 80 <= i < 84:                  # a saturated amplifier: 3 BW, repeated
                    msg.wrench.force.y = clipped
                pub_w.publish(msg)
                if i == 60:
                    pub_w.publish(msg)
                    pub_w.publish(to_planar_wrench(sw[50], 'foot_com', obs.wrench[50]))
                    pub_w.publish(to_planar_wrench(stamp + 10, 'plate', obs.wrench[i]))
            executor.spin_once(timeout_sec=0)
        assert spin_until(executor, lambda: skel.status.state == 'finished', 20.0), \
            skel.status.reports()[0]
        published = skel.status.published[TORQUES]
        assert spin_until(executor, lambda: len(outputs) >= published, 10.0)
        text = status.text('/skeletal_tracker')
        for words in ('/mocap/segment_angles: non-finite value nan at index 1 (shank): missing',
                      'non-finite value inf at index 1 (force.y)',
                      'position has 3 values for 4 names',
                      "missing ['foot', 'shank', 'thigh', 'hat']",
                      "frame_id is 'plate', expected 'foot_com'",
                      'duplicate stamp', 'initialised',
                      f'force plate saturated (Fy {clipped:.6g}: the same reading '
                      'on consecutive samples): taken as missing',
                      'gap of 1.9 ms after 1700000000.036111111; not filled (bridged by the '
                      'estimator)'):
            assert words in text, words
        said = {r.message for r in status.records if 'non-finite value nan' in r.message}
        assert len(said) == 1, said                                # once per occlusion
        # (the late sample is 'before the previous sample' or, taken in one batch with its
        # original and sorted by stamp, a 'duplicate stamp': rejected either way)
        assert skel.status.rejected == {ANGLES: 2, WRENCH: 4}
        assert skel.status.extra['missing_values'] == 2
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in outputs])
    effort = np.array([m.effort for m in outputs])
    # refined estimates at every accepted force-plate instant from the first, none invented
    accepted = np.delete(sw[:n_w], 40)
    assert np.array_equal(stamps, accepted), (np.setdiff1d(stamps, accepted),
                                              np.setdiff1d(accepted, stamps))
    assert np.isfinite(effort).all() and np.abs(effort).max() < 1000.0


def test_a_long_update_is_not_mistaken_for_silent_input(ros_context):
    """The idle watchdog ends a trial after ``idle_flush_s`` without input, judged after the
    waiting inputs were taken. An update slower than ``idle_flush_s`` (a re-initialisation on
    a busy machine) inside that take is not silence: the trial goes on. (Before the fix idle
    time counted from the batch's arrival: a 60 min soak ended its trial on "no input for
    1.03 s" after a re-initialisation while the force plate streamed on.)"""
    obs, sa, sw = _observations()
    events, _ = _in_stamp_order(sa, sw, 12)
    idle_s = 0.3
    with _mhe_node(ros_context, 'probe_idle', idle_flush_s=idle_s) as (
            skel, _status, _outputs, pub_a, pub_w, executor):
        def taken():
            return sum(skel.status.received.values())

        half = len(events) // 2
        _publish_in_order(events[:half], obs, pub_a, pub_w)
        assert spin_until(executor, lambda: taken() == half and skel.tracking, 10.0)
        poll = skel.mhe.poll

        def slow_poll():
            time.sleep(idle_s + 0.3)
            return poll()

        skel.mhe.poll = slow_poll
        _publish_in_order(events[half:], obs, pub_a, pub_w)
        time.sleep(0.2)                           # delivered to the node's readers
        skel.watchdog()                           # takes them; the update takes 0.6 s
        assert taken() == len(events)
        assert skel.tracking, skel.status.detail
        skel.mhe.poll = poll
        # without input, the watchdog does end the trial
        assert spin_until(executor, lambda: not skel.tracking, 5.0)
        assert 'no input for' in skel.status.detail


def test_skeletal_tracker_reports_loss_of_control(ros_context):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from msg_adapters.joint_state import to_joint_state
    from msg_adapters.planar import to_planar_wrench
    from nmt_ros.nodes.skeletal_tracker import SkeletalTrackerNode

    obs, sa, sw = _observations()
    skel = SkeletalTrackerNode(context=ros_context, parameter_overrides=params(
        estimator='skt', lookahead_s=0.02, substeps=1, idle_flush_s=0.3,
        max_angle_error_deg=0.001))
    probe = rclpy.create_node('probe3', context=ros_context)
    status, outputs, pub_a, pub_w = _tracker_io(probe, probe)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(skel)
    executor.add_node(probe)
    try:
        assert spin_until(executor, lambda: pub_w.get_subscription_count() == 1, 10.0)
        for i in range(12):
            pub_a.publish(to_joint_state(sa[i], ['foot', 'shank', 'thigh', 'hat'],
                                         obs.angles[i]))
        for i in range(100):
            pub_w.publish(to_planar_wrench(sw[i], 'foot_com', obs.wrench[i]))
        assert spin_until(executor, lambda: not skel.tracking
                          and skel.status.state == 'lost_control', 10.0), skel.status.reports()[0]
        spin_until(executor, lambda: False, 0.1)
        text = status.text('/skeletal_tracker')
        assert 'loss of control at t = ' in text and 'segment angle' in text
        assert "'state': 'finished'" in status.text('/skeletal_tracker: stream')
        assert any(r.level == 2 for r in status.records if r.name == '/skeletal_tracker')
        assert len(outputs) < 100          # the estimates stop where control was lost
    finally:
        for n in (skel, probe):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


@pytest.mark.slow
@pytest.mark.parametrize('take_period_s', [0.01, 0.0])
def test_muscle_tracker_rejects_bad_input_and_flushes_on_end_of_stream(ros_context,
                                                                       take_period_s):
    """Both input paths (raw batches decoded at once, the default; typed messages one
    callback each, ``take_period_s`` 0) refuse the same messages for the same reasons and
    estimate the same instants."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from msg_adapters.joint_state import to_joint_state
    from nmt_ros.model.jumper import default_model
    from nmt_ros.nodes.muscle_tracker import MuscleTrackerNode
    from nmt_ros.nodes.node_base import NmtNode, data_qos
    from nmt_ros.records import TRIAL_EPOCH_NS
    from nmt_ros.tracking.conditioning import condition
    from nmt_ros.tracking.skeletal_tracker import SKTSettings
    from nmt_ros.tracking.streaming import track_stage1

    obs, _, _ = _observations()
    model = default_model()
    res = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench),
                SKTSettings().with_(substeps=1), t_end=0.08)
    th, = model.batch(model.joint_angles, res.q)
    thd, = model.batch(model.joint_angles, res.qd)
    stamps = TRIAL_EPOCH_NS + np.rint(res.t * 1e9).astype(np.int64)
    muscle = MuscleTrackerNode(context=ros_context, parameter_overrides=params(
        window_length_s=0.02, idle_flush_s=0.0, take_period_s=take_period_s))
    producer = NmtNode('fake_skeletal', context=ros_context)   # announces like Stage 1
    probe = rclpy.create_node('probe2', context=ros_context)
    status = StatusProbe(probe)
    forces = []
    probe.create_subscription(JointState, '/nmt/muscle/forces', forces.append, data_qos(5000))
    pub = producer.create_publisher(JointState, TORQUES, data_qos(5000))
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (muscle, producer, probe):
        executor.add_node(n)
    joints = ['ankle', 'knee', 'hip']
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() == 1, 10.0)
        sent = 0
        for i in range(stamps.size):
            pub.publish(to_joint_state(stamps[i], joints, th[i], thd[i], res.tau[i]))
            sent += 1
            if i == 10:
                bad = to_joint_state(stamps[i] + 1, joints, th[i], thd[i], res.tau[i])
                bad.effort[2] = float('nan')
                pub.publish(bad)
                pub.publish(to_joint_state(stamps[i] + 2, ['ankle', 'knee', 'neck'],
                                           th[i], thd[i], res.tau[i]))
                sent += 2
            executor.spin_once(timeout_sec=0)
        assert spin_until(executor, lambda: muscle.status.received.get(TORQUES, 0) == sent,
                          10.0)
        assert muscle.status.state == 'tracking'     # no idle flush: waits for the end
        producer.announce_end({TORQUES: sent}, {TORQUES: int(stamps[0])})
        assert spin_until(executor, lambda: muscle.status.state == 'finished', 10.0), \
            muscle.status.reports()
        assert spin_until(executor, lambda: len(forces) == stamps.size, 5.0)
        text = status.text('/muscle_tracker')
        assert 'non-finite value nan at index 2 (hip)' in text
        assert "missing ['hip']" in text
        assert 'every message received' in text
        got = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in forces])
        np.testing.assert_array_equal(got, stamps)
        effort = np.array([m.effort for m in forces])
        assert np.isfinite(effort).all() and (effort >= 0).all()
    finally:
        for n in (muscle, producer, probe):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()


# --------------------------------------------------------------------------- recorder, config

def test_recorder_adapts_qos_like_rosbag2():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from nmt_ros.nodes.recorder import adapted_qos, is_hidden

    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    sensor = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
    assert adapted_qos([reliable], 100).reliability == ReliabilityPolicy.RELIABLE
    assert adapted_qos([reliable], 100).durability == DurabilityPolicy.TRANSIENT_LOCAL
    mixed = adapted_qos([reliable, sensor], 100)
    assert mixed.reliability == ReliabilityPolicy.BEST_EFFORT
    assert mixed.durability == DurabilityPolicy.VOLATILE and mixed.depth == 100
    assert is_hidden('/a/_private') and not is_hidden('/nmt/status')


def test_recorder_records_raw_with_publisher_times(ros_context, tmp_path):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from nmt_ros.io.bags import bag_info, read_bag, read_raw
    from nmt_ros.nodes.node_base import data_qos
    from nmt_ros.nodes.recorder import RecorderNode

    out = tmp_path / 'rec'
    rec = RecorderNode(context=ros_context, parameter_overrides=params(
        output=str(out), exclude=['/rosout', '/parameter_events'], scan_period_s=0.02))
    talker = rclpy.create_node('talker', context=ros_context)
    pubs = {'/reliable': talker.create_publisher(String, '/reliable', data_qos(100)),
            '/sensor': talker.create_publisher(String, '/sensor', QoSProfile(
                depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))}
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(rec)
    executor.add_node(talker)
    try:
        assert spin_until(executor, lambda: all(p.get_subscription_count() == 1
                                                for p in pubs.values()), 10.0)
        t0 = time.time_ns()
        for i in range(20):
            for name, pub in pubs.items():
                pub.publish(String(data=f'{name} {i}'))
        assert spin_until(executor, lambda: rec.status.received.get('/reliable', 0) == 20
                          and rec.status.received.get('/sensor', 0) > 0, 5.0)
        rec.on_shutdown(False)
    finally:
        executor.remove_node(rec)
        executor.remove_node(talker)
        rec.destroy_node()
        talker.destroy_node()
        executor.shutdown()
    info = {t.name: t for t in bag_info(out).topics}
    assert info['/reliable'].message_count == 20
    assert info['/reliable'].offered_qos[0].reliability == 'reliable'
    assert info['/sensor'].offered_qos[0].reliability == 'best_effort'
    assert '/rosout' not in info
    texts = [m.msg.data for m in read_bag(out, ['/reliable'])]
    assert texts == [f'/reliable {i}' for i in range(20)]
    for raw in read_raw(out, ['/reliable']):
        assert t0 <= raw.publish_time_ns <= raw.log_time_ns


NODE_CLASSES = {
    'observation_publisher': 'nmt_ros.nodes.observation_publisher.ObservationPublisherNode',
    'skeletal_tracker': 'nmt_ros.nodes.skeletal_tracker.SkeletalTrackerNode',
    'muscle_tracker': 'nmt_ros.nodes.muscle_tracker.MuscleTrackerNode',
    'recorder': 'nmt_ros.nodes.recorder.RecorderNode',
}


def _node_class(node):
    import importlib

    module, _, name = NODE_CLASSES[node].rpartition('.')
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize('node', sorted(NODE_CLASSES))
def test_shipped_config_equals_the_declared_defaults(node, ros_context, tmp_path):
    """config/<node>.yaml documents exactly the parameters the node declares, with the same
    defaults; config/nmt_graph*.yaml only set declared parameters."""
    section = yaml.safe_load((ROOT / 'config' / f'{node}.yaml').read_text())[node][
        'ros__parameters']
    extra = {'output': str(tmp_path / 'r')} if node == 'recorder' else {}
    extra.update({'expected_subscribers': 0, 'bag': str(BAG)}
                 if node == 'observation_publisher' else {})
    instance = _node_class(node)(context=ros_context, parameter_overrides=params(**extra))
    try:
        builtin = {'use_sim_time', 'start_type_description_service'}
        declared = {name: p.value for name, p in instance._parameters.items()
                    if name not in builtin}
        assert sorted(section) == sorted(declared)
        for key, value in section.items():
            if key in extra:
                continue
            got = declared[key]
            if isinstance(value, list):
                assert [v for v in value if v] == list(got or []), key
            else:
                assert value == got, key
        for graph in ('nmt_graph.yaml', 'nmt_graph_low_latency.yaml'):
            keys = yaml.safe_load((ROOT / 'config' / graph).read_text())[node]['ros__parameters']
            assert set(keys) <= set(declared), (graph, set(keys) - set(declared))
    finally:
        instance.on_shutdown(True)
        instance.destroy_node()


@pytest.mark.parametrize('subject', ['', 'bags/real_dropjump/subject.yaml'])
def test_the_offline_estimator_runs_with_the_settings_the_node_reported(ros_context, subject):
    """Live = batch needs the batch to rebuild the node's estimator settings from what the
    node said on /nmt/status: non-default estimator parameters (wrench_cutoff_hz included)
    go through the status message and its adapter and come back as the node's
    MovingHorizonSettings; with a lab subject's file also the settings the node derives
    from it (net torques, the rate prior, its relaxation at landings, the flight's height
    diffusion: until 2026-12-07 the last two were missing, and `nmt demo --bag` on an
    unseen drop jump reported the live graph 3-6.5 % of peak from a batch run with the
    jumper's)."""
    from msg_adapters.diagnostics import from_diagnostic_array, to_diagnostic_array
    from nmt_ros.nodes.node_base import to_records
    from nmt_ros.nodes.skeletal_tracker import SkeletalTrackerNode
    from nmt_ros.study.recording_evaluation import mhe_settings_from_status
    from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

    given = {'lag_s': 0.06, 'window_s': 0.15, 'update_rate_hz': 30.0, 'iterations': 2,
             'wrench_cutoff_hz': 20.0, 'angle_rate_hz': 100.0, 'wrench_rate_hz': 1000.0,
             'excitation_weight': 200.0}
    if subject:
        given['subject_file'] = str(ROOT / subject)
    node = SkeletalTrackerNode(context=ros_context, parameter_overrides=params(
        estimator='mhe', **given))
    try:
        assert node.mhe_settings != MovingHorizonSettings()
        if subject:     # what the node derives for a lab subject differs from the jumper's
            d = MovingHorizonSettings()
            for name in ('airborne_translation_diffusion_m_sqrt_s', 'landing_rate_sd_scale',
                         'joint_torques', 'excitation_rate_weight'):
                assert getattr(node.mhe_settings, name) != getattr(d, name), name
        message = to_diagnostic_array(0, to_records(node.status.reports()))
        _, records = from_diagnostic_array(message)
        values = next(r.values for r in records if ':' not in r.name)
        rebuilt = mhe_settings_from_status(values)
        assert rebuilt == node.mhe_settings
        assert rebuilt.wrench_cutoff_hz == 20.0 and rebuilt.iterations == 2
        assert rebuilt.excitation_weight == 200.0
    finally:
        node.on_shutdown(True)
        node.destroy_node()
