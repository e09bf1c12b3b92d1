"""skeletal_tracker: Stage 1 (SKT) live, in step with the observations.

Subscribes ``/mocap/segment_angles`` (JointState [foot, shank, thigh, hat], position) and
``/force_plate/wrench`` (WrenchStamped in ``wrench_frame``), filters them with a fixed
look-ahead (``lookahead_s``: the estimate for instant t is computed once data up to
t + lookahead_s has arrived) and steps Stage 1 after each arrival
(``nmt_ros.tracking.streaming.Stage1Stream``, the batch tracker's code). Publishes, stamped
with the observation instant (the force-plate samples k / wrench_rate_hz from the trial
start):

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

from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from msg_adapters.joint_state import from_joint_state, joint_states_from_arrays
from msg_adapters.planar import from_planar_wrench, planar_wrenches_from_arrays
from nmt_ros.model.jumper import default_model
from nmt_ros.model.parameters import JOINTS, Q_NAMES, SEGMENTS
from nmt_ros.nodes.input_gate import Sample, TrialClock
from nmt_ros.nodes.node_base import TrackerNode
from nmt_ros.nodes.node_status import ERROR
from nmt_ros.nodes.runtime import run_node
from nmt_ros.topics import (
    FORCE_PLATE_WRENCH,
    MOCAP_SEGMENT_ANGLES,
    SKELETAL_GENERALIZED_COORDINATES,
    SKELETAL_GROUND_WRENCH,
    SKELETAL_JOINT_TORQUES,
    SKELETAL_SEGMENT_ANGLES,
    WRENCH_FRAME,
)
from nmt_ros.tracking.conditioning import ConditioningSettings
from nmt_ros.tracking.skeletal_tracker import SKTSettings
from nmt_ros.tracking.streaming import Stage1Output, Stage1Stream

NODE_NAME = 'skeletal_tracker'


class SkeletalTrackerNode(TrackerNode):
    """Stage 1 as a node (see the module docstring)."""

    INPUTS = {MOCAP_SEGMENT_ANGLES: JointState, FORCE_PLATE_WRENCH: WrenchStamped}
    OUTPUTS = {SKELETAL_JOINT_TORQUES: JointState, SKELETAL_SEGMENT_ANGLES: JointState,
               SKELETAL_GENERALIZED_COORDINATES: JointState, SKELETAL_GROUND_WRENCH: WrenchStamped}

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
        self.wrench_frame = p('wrench_frame', WRENCH_FRAME, "required header.frame_id of the "
                              "force-plate wrench ('' = any)")
        self.epoch_ns = p('epoch_ns', 0, 'header stamp of trial time 0 [ns] (0 = the first '
                          'observation received)', low=0, high=2**62)
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
        self.stream = Stage1Stream(self.model, self.settings, self.conditioning,
                                   angle_rate_hz=self.angle_rate_hz,
                                   wrench_rate_hz=self.wrench_rate_hz)
        self.clock = TrialClock(self.epoch_ns)
        self.gates = self.stream_gates({MOCAP_SEGMENT_ANGLES: 1 / self.angle_rate_hz,
                                        FORCE_PLATE_WRENCH: 1 / self.wrench_rate_hz})
        self.polled_until = -np.inf
        self.first_pending = np.inf
        self.create_timer(self.poll_period_s, self.poll)
        self.listen()

    # ------------------------------------------------------------------ inputs
    def parse(self, topic: str, msg: JointState | WrenchStamped) -> tuple[int, np.ndarray]:
        if topic == MOCAP_SEGMENT_ANGLES:
            sample = from_joint_state(msg, SEGMENTS, require=('position',))
            return sample.stamp_ns, sample.position
        return from_planar_wrench(msg, self.wrench_frame or None)

    def feed(self, topic: str, samples: Sequence[Sample], stamp_ns: int,
             received: float) -> None:
        if self.stream.status != 'ok':
            return
        add = self.stream.add_angles if topic == MOCAP_SEGMENT_ANGLES else self.stream.add_wrench
        for sample in samples:
            add(self.clock.t(sample.stamp_ns), sample.values)
        self.newest_input_ns = max(self.newest_input_ns, stamp_ns)
        self.first_pending = min(self.first_pending, received)
        if self.stream.final_until - self.polled_until >= self.poll_min_s:
            self.poll()
        self._check_end()

    def poll(self) -> None:
        """Step Stage 1 over everything that became final; publish."""
        if not self.tracking or self.stream.final_until <= self.polled_until:
            return
        self.polled_until = self.stream.final_until
        received, self.first_pending = self.first_pending, np.inf
        self._publish(self.stream.poll(), received)

    # ------------------------------------------------------------------ trial
    def on_trial_start(self, epoch_ns: int) -> None:
        self.polled_until = -np.inf
        self.first_pending = np.inf
        self.status.extra['epoch_ns'] = epoch_ns

    def flush(self) -> None:
        self._publish(self.stream.finish(), time.monotonic())

    def end_state(self) -> str:
        return 'lost_control' if self.stream.status != 'ok' else 'finished'

    # ------------------------------------------------------------------ outputs
    def _publish(self, out: Stage1Output | None, received: float) -> None:
        if self.stream.status != 'ok' and self.status.state != 'lost_control':
            ev = self.stream.events[0] if self.stream.events else {}
            self.status.state = 'lost_control'
            self.status.error = (f'loss of control at t = {ev.get("t", float("nan")):.4f} s: '
                                 f'{ev.get("reason", "?")}')
            self.status.event(ERROR, self.status.error, **{k: v for k, v in ev.items()
                                                              if k != 'reason'})
            self.publish_status()
        if out is None or out.t.size == 0:
            return
        stamps = self.clock.stamps(out.t)
        self.publish_batches(stamps, {
            SKELETAL_JOINT_TORQUES: joint_states_from_arrays(
                stamps, JOINTS, position=out.joint_angles, velocity=out.joint_rates,
                effort=out.tau),
            SKELETAL_SEGMENT_ANGLES: joint_states_from_arrays(
                stamps, SEGMENTS, position=out.q[:, :4], velocity=out.qd[:, :4]),
            SKELETAL_GENERALIZED_COORDINATES: joint_states_from_arrays(
                stamps, Q_NAMES, position=out.q, velocity=out.qd),
            SKELETAL_GROUND_WRENCH: planar_wrenches_from_arrays(stamps, WRENCH_FRAME, out.s),
        })
        if np.isfinite(received):
            self.status.delay(time.monotonic() - received)

    def status_values(self) -> None:
        super().status_values()
        self.status.extra['final_until_s'] = float(self.stream.final_until)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SkeletalTrackerNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
