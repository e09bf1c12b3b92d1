"""skeletal_tracker: Stage 1 (SKT) live, in step with the observations.

Subscribes ``/mocap/segment_angles`` (JointState [foot, shank, thigh, hat], position) and
``/force_plate/wrench`` (WrenchStamped in ``wrench_frame``), filters them with a fixed
look-ahead (``lookahead_s``: the estimate for instant t is computed once data up to
t + lookahead_s has arrived) and steps Stage 1 (``Stage1Stream``, the batch tracker's code)
after each arrival. Publishes, stamped with the observation instant (the force-plate
samples k / wrench_rate_hz from the trial start):

- ``/nmt/skeletal/joint_torques``: JointState [ankle, knee, hip], position/velocity = OpenSim
  joint angle/rate, effort = torque [N m] (as ``/truth/joint_torques``);
- ``/nmt/skeletal/segment_angles``: JointState [foot, shank, thigh, hat] (position, velocity);
- ``/nmt/skeletal/generalized_coordinates``: JointState [th1..th4, r1, r2] (position,
  velocity): the whole tracked state, e.g. for the jump height;
- ``/nmt/skeletal/ground_wrench``: WrenchStamped ('foot_com') from the model's springs.

Joint accelerations are not published: the muscle tracker differences the joint rates.
Bad samples (NaN/inf, wrong length or names, wrong frame, duplicate or out-of-order stamps)
are rejected with a reason on ``/nmt/status``; gaps are filled by interpolation and
reported. The trial ends (the last look-ahead is flushed) when the producer's end-of-stream
announcement has been matched by the messages received, when no input came for
``idle_flush_s`` or when a gap exceeds ``max_gap_s``; new data then start a new trial.
"""
from __future__ import annotations

from collections.abc import Sequence
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from msg_adapters.diagnostics import from_diagnostic_array
from msg_adapters.joint_state import from_joint_state, joint_states_from_arrays
from msg_adapters.planar import from_planar_wrench, planar_wrenches_from_arrays
from msg_adapters.stamps import time_to_ns
from nmt_ros.model.jumper import default_model
from nmt_ros.model.parameters import JOINTS, Q_NAMES, SEGMENTS
from nmt_ros.nodes._core import (
    ERROR,
    WARN,
    StreamGate,
    TrialBook,
    TrialClock,
)
from nmt_ros.nodes._ros import STATUS_QOS, STATUS_TOPIC, NmtNode, data_qos, run_node
from nmt_ros.nodes._streams import Stage1Output, Stage1Runner
from nmt_ros.tracking.conditioning import ConditioningSettings
from nmt_ros.tracking.skeletal_tracker import SKTSettings

NODE_NAME = 'skeletal_tracker'
ANGLES_TOPIC = '/mocap/segment_angles'
WRENCH_TOPIC = '/force_plate/wrench'
TORQUES_TOPIC = '/nmt/skeletal/joint_torques'
SEGMENTS_TOPIC = '/nmt/skeletal/segment_angles'
COORDS_TOPIC = '/nmt/skeletal/generalized_coordinates'
GROUND_TOPIC = '/nmt/skeletal/ground_wrench'
OUTPUT_TOPICS = (TORQUES_TOPIC, SEGMENTS_TOPIC, COORDS_TOPIC, GROUND_TOPIC)


class SkeletalTrackerNode(NmtNode):
    """Stage 1 as a node (see the module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.param
        self.lookahead_s = p('lookahead_s', 0.1, 'look-ahead of the zero-lag filters [s]: '
                             'latency vs accuracy (bench/bench_latency.py)', low=0.0, high=2.0)
        self.filter_window_s = p('filter_window_s', 0.5, 'history the live filter keeps [s]',
                                 low=0.05, high=10.0)
        self.angle_cutoff_hz = p('angle_cutoff_hz', 10.0, 'segment-angle low-pass [Hz]',
                                 low=0.1, high=59.0)
        self.force_cutoff_hz = p('force_cutoff_hz', 50.0, 'ground-wrench low-pass [Hz]',
                                 low=0.1, high=539.0)
        self.angle_rate_hz = p('angle_rate_hz', 120.0, 'nominal motion-capture rate [Hz]',
                               low=1.0, high=10000.0)
        self.wrench_rate_hz = p('wrench_rate_hz', 1080.0, 'nominal force-plate rate [Hz]; '
                                'the estimates are at these instants', low=1.0, high=100000.0)
        self.substeps = p('substeps', 1, 'RK4 steps per force sample (the batch default, 2, '
                          'costs twice the CPU for < 0.5 % of peak torque)', low=1, high=64)
        self.bias_rate = p('bias_rate', SKTSettings().bias_rate, 'moment-bias estimator rate '
                           '[1/s] (0 = off)', low=0.0, high=1000.0)
        self.max_angle_error_deg = p('max_angle_error_deg', SKTSettings().max_angle_error_deg,
                                     'loss of control: segment-angle error above this [deg]',
                                     low=0.0, high=360.0)
        self.max_force_error_bw = p('max_force_error_bw', SKTSettings().max_force_error_bw,
                                    'loss of control: vertical force error above this [BW]',
                                    low=0.0, high=100.0)
        self.wrench_frame = p('wrench_frame', 'foot_com', "required header.frame_id of the "
                              "force-plate wrench ('' = any)")
        self.epoch_ns = p('epoch_ns', 0, 'header stamp of trial time 0 [ns] (0 = the first '
                          'observation received)', low=0, high=2**62)
        self.gap_factor = p('gap_factor', 1.5, 'a spacing above this many periods is a gap '
                            '(filled by interpolation, reported)', low=1.01, high=100.0)
        self.max_gap_s = p('max_gap_s', 0.5, 'a longer gap ends the trial [s]', low=0.0,
                           high=3600.0)
        self.idle_flush_s = p('idle_flush_s', 1.0, 'end the trial after this long without '
                              'input [s] (0 = never)', low=0.0, high=3600.0)
        self.end_timeout_s = p('end_timeout_s', 2.0, 'after an end-of-stream announcement, '
                               'flush at the latest after this long even if messages are '
                               'missing [s]', low=0.0, high=3600.0)
        self.input_reliable = p('input_reliable', True, 'subscribe RELIABLE (lossless); '
                                'false: BEST_EFFORT, to accept best-effort sources')
        self.poll_min_s = p('poll_min_s', 0.008, 'step Stage 1 on an arrival once the final '
                            'horizon advanced this much [s] (batches the filter refits; '
                            '0 = after every arrival)', low=0.0, high=1.0)
        self.poll_period_s = p('poll_period_s', 0.01, 'and at least this often [s]', low=0.001,
                               high=1.0)
        self.settings = SKTSettings().with_(
            substeps=self.substeps, bias_rate=self.bias_rate,
            max_angle_error_deg=self.max_angle_error_deg,
            max_force_error_bw=self.max_force_error_bw)
        self.conditioning = ConditioningSettings(
            angle_cutoff_hz=self.angle_cutoff_hz, force_cutoff_hz=self.force_cutoff_hz,
            lookahead_s=self.lookahead_s, window_s=self.filter_window_s)
        self.status.settings = {
            'lookahead_s': self.lookahead_s, 'substeps': self.substeps,
            'angle_cutoff_hz': self.angle_cutoff_hz, 'force_cutoff_hz': self.force_cutoff_hz,
            'filter_window_s': self.filter_window_s, 'wrench_rate_hz': self.wrench_rate_hz,
            'angle_rate_hz': self.angle_rate_hz, 'bias_rate': self.bias_rate}

        # the numerical core (built before any input is accepted)
        self.model = default_model()
        self.runner = Stage1Runner(self.model, self.settings, self.conditioning,
                                   self.angle_rate_hz, self.wrench_rate_hz)
        self.clock = TrialClock(self.epoch_ns)
        self.gates = {
            ANGLES_TOPIC: StreamGate(ANGLES_TOPIC, 1 / self.angle_rate_hz, self.gap_factor,
                                     self.max_gap_s),
            WRENCH_TOPIC: StreamGate(WRENCH_TOPIC, 1 / self.wrench_rate_hz, self.gap_factor,
                                     self.max_gap_s)}
        self.book = TrialBook((ANGLES_TOPIC, WRENCH_TOPIC))
        self.tracking = False
        self.last_input = time.monotonic()
        self.newest_input_ns = 0
        self.newest_output_ns = 0

        qos = data_qos(self.qos_depth)
        self.pubs = {
            TORQUES_TOPIC: self.create_publisher(JointState, TORQUES_TOPIC, qos),
            SEGMENTS_TOPIC: self.create_publisher(JointState, SEGMENTS_TOPIC, qos),
            COORDS_TOPIC: self.create_publisher(JointState, COORDS_TOPIC, qos),
            GROUND_TOPIC: self.create_publisher(WrenchStamped, GROUND_TOPIC, qos),
        }
        self.status.state = 'ready'
        self.create_timer(0.05, self.watchdog)
        self.create_timer(self.poll_period_s, self.poll)
        self.polled_until = -np.inf
        self.first_pending = np.inf
        # end-of-stream announcements (transient local: heard even if matched late)
        self.create_subscription(DiagnosticArray, STATUS_TOPIC, self.on_status, STATUS_QOS)
        self.open_inputs_when_ready(self._open_inputs)

    def _open_inputs(self) -> None:
        qos = data_qos(self.qos_depth, self.input_reliable)
        self.create_subscription(JointState, ANGLES_TOPIC, self.on_angles, qos)
        self.create_subscription(WrenchStamped, WRENCH_TOPIC, self.on_wrench, qos)
        self.status.state = 'ready'

    # ------------------------------------------------------------------ inputs
    def on_angles(self, msg: JointState) -> None:
        received = time.monotonic()
        self._saw(ANGLES_TOPIC, msg)
        try:
            sample = from_joint_state(msg, SEGMENTS, require=('position',))
        except ValueError as exc:
            self._reject(ANGLES_TOPIC, f'{ANGLES_TOPIC}: {exc}')
            return
        self._feed(ANGLES_TOPIC, sample.stamp_ns, sample.position, received)

    def on_wrench(self, msg: WrenchStamped) -> None:
        received = time.monotonic()
        self._saw(WRENCH_TOPIC, msg)
        try:
            stamp_ns, s = from_planar_wrench(msg, self.wrench_frame or None)
        except ValueError as exc:
            self._reject(WRENCH_TOPIC, f'{WRENCH_TOPIC}: {exc}')
            return
        self._feed(WRENCH_TOPIC, stamp_ns, s, received)

    def on_status(self, msg: DiagnosticArray) -> None:
        _, records = from_diagnostic_array(msg)
        if any(self.book.announcement(r.values, time.monotonic()) for r in records):
            self._check_end()

    def _saw(self, topic: str, msg: object) -> None:
        self.status.receive(topic)
        self.book.saw(topic, time_to_ns(msg.header.stamp))

    def _reject(self, topic: str, reason: str) -> None:
        self.status.reject(topic, reason)
        self.notify()

    def _feed(self, topic: str, stamp_ns: int, values: np.ndarray, received: float) -> None:
        self.status.mark_active()
        self.last_input = received
        if not self.tracking:
            self._start_trial(stamp_ns)
        result = self.gates[topic].offer(stamp_ns, values)
        if result.rejected:
            self.status.reject(topic, result.rejected)
            self.notify()
            return
        if result.restart:
            self.status.event(WARN, result.restart)
            self._finish(result.restart)
            self._start_trial(stamp_ns)
            self.book.saw(topic, stamp_ns)
            result = self.gates[topic].offer(stamp_ns, values)
        if result.gap:
            self.status.interpolated += len(result.samples) - 1
            self.status.event(WARN, result.gap)
        if self.runner.status != 'ok':
            return
        add = self.runner.add_angles if topic == ANGLES_TOPIC else self.runner.add_wrench
        for sample in result.samples:
            add(self.clock.t(sample.stamp_ns), sample.values)
        self.newest_input_ns = max(self.newest_input_ns, stamp_ns)
        self.first_pending = min(self.first_pending, received)
        if self.runner.final_until - self.polled_until >= self.poll_min_s:
            self.poll()
        self._check_end()

    def poll(self) -> None:
        """Step Stage 1 over everything that became final; publish."""
        if not self.tracking or self.runner.final_until <= self.polled_until:
            return
        self.polled_until = self.runner.final_until
        received, self.first_pending = self.first_pending, np.inf
        self._publish(self.runner.poll(), received)

    # ------------------------------------------------------------------ trial
    def _start_trial(self, stamp_ns: int) -> None:
        trial = self.book.start()
        self.runner.reset()
        self.clock.reset()
        epoch = self.clock.start(stamp_ns)
        for gate in self.gates.values():
            gate.reset()
            gate.not_before_ns = epoch
        self.polled_until = -np.inf
        self.first_pending = np.inf
        self.status.error = None
        self.tracking = True
        self.status.state = 'tracking'
        self.status.detail = f'trial {trial}'
        self.status.extra.update({'trial': trial, 'epoch_ns': epoch})

    def _check_end(self) -> None:
        if self.tracking:
            why = self.book.verdict(time.monotonic(), self.end_timeout_s)
            if why:
                if 'missing' in why:
                    self.status.event(ERROR, why)
                self._finish(why)

    def _finish(self, why: str) -> None:
        if not self.tracking:
            return
        self._publish(self.runner.finish(), time.monotonic())
        self.tracking = False
        lost = self.runner.status != 'ok'
        self.status.state = 'lost_control' if lost else 'finished'
        self.status.detail = f'trial {self.book.trial} finished: {why}'
        counts, firsts = self.book.finish()
        self.announce_end(counts, firsts, trial=self.book.trial, reason=why)
        if self.exit_when_finished:
            self.done = True

    def watchdog(self) -> None:
        """Idle/publisher-gone detection and the end-of-stream timeout."""
        if not self.tracking:
            return
        self._check_end()
        if not self.tracking:
            return
        idle = time.monotonic() - self.last_input
        if self.idle_flush_s > 0 and idle > self.idle_flush_s:
            gone = [t for t in (ANGLES_TOPIC, WRENCH_TOPIC) if self.count_publishers(t) == 0]
            why = (f'no input for {idle:.2f} s' + (f'; publisher gone on {gone}' if gone else ''))
            self.status.event(WARN if not gone else ERROR, why)
            self._finish(why)

    # ------------------------------------------------------------------ outputs
    def _publish(self, out: Stage1Output | None, received: float) -> None:
        if self.runner.status != 'ok' and self.status.state != 'lost_control':
            ev = self.runner.events[0] if self.runner.events else {}
            self.status.state = 'lost_control'
            self.status.error = (f'loss of control at t = {ev.get("t", float("nan")):.4f} s: '
                                 f'{ev.get("reason", "?")}')
            self.status.event(ERROR, self.status.error, **{k: v for k, v in ev.items()
                                                              if k != 'reason'})
            self.publish_status()
        if out is None or out.t.size == 0:
            return
        m = self.model
        stamps = self.clock.stamps(out.t)
        theta, = m.batch(m.joint_angles, out.q)
        theta_dot, = m.batch(m.joint_angles, out.qd)
        batches = {
            TORQUES_TOPIC: joint_states_from_arrays(stamps, JOINTS, position=theta,
                                                    velocity=theta_dot, effort=out.tau),
            SEGMENTS_TOPIC: joint_states_from_arrays(stamps, SEGMENTS, position=out.q[:, :4],
                                                     velocity=out.qd[:, :4]),
            COORDS_TOPIC: joint_states_from_arrays(stamps, Q_NAMES, position=out.q,
                                                   velocity=out.qd),
            GROUND_TOPIC: planar_wrenches_from_arrays(stamps, 'foot_com', out.s),
        }
        for i in range(stamps.size):
            for topic, msgs in batches.items():
                self.pubs[topic].publish(msgs[i])
        for topic in batches:
            self.status.publish(topic, stamps.size)
            self.book.output(topic, int(stamps[0]), stamps.size)
        self.newest_output_ns = int(stamps[-1])
        if np.isfinite(received):
            self.status.delay(time.monotonic() - received)

    def status_values(self) -> None:
        self.status.extra['data_lag_ms'] = (
            (self.newest_input_ns - self.newest_output_ns) / 1e6
            if self.newest_output_ns else float('nan'))
        self.status.extra['final_until_s'] = float(self.runner.final_until)

    def on_shutdown(self, interrupted: bool) -> None:
        if not interrupted:
            self.publish_status()
            if not self.wait_for_acks(10.0):
                self.exit_code = 1


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SkeletalTrackerNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
