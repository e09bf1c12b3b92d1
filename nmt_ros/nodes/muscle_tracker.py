"""muscle_tracker: Stage 2 (neuromuscular tracking, receding Riccati windows) live.

Subscribes ``/nmt/skeletal/joint_torques`` (JointState [ankle, knee, hip]: OpenSim joint
angle, rate and torque, one per force-plate instant). Every ``process_period_s`` the queued
samples are pushed to Stage 2 (``NeuromuscularTracker.push``, the code of the batch windowed
mode): a window of length ``window_length_s`` (H) is planned (backward Riccati/adjoint sweep)
as soon as the torques up to its end are in, and applied over ``window_stride_s``. The
estimate for instant t is therefore available once Stage 1 reached t + H; its latency is the
skeletal tracker's plus H plus up to a stride. Joint accelerations are central differences
of the received joint rates (``nmt_ros.nodes._streams``).

Publishes, stamped with the observation instant of the torque sample they belong to:
``/nmt/muscle/forces`` (JointState [gmax, ilpso, hams, bfsh, rf, vas, gas, sol, ta]:
position = musculotendon length [m], velocity = lengthening speed [m/s], effort = force [N]),
``/nmt/muscle/activations`` and ``/nmt/muscle/excitations`` (position = value in [0, 1]).
Bad samples are rejected with a reason on ``/nmt/status``; the trial ends on the skeletal
tracker's end-of-stream announcement (or ``idle_flush_s`` without input).
"""
from __future__ import annotations

from collections.abc import Sequence
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from sensor_msgs.msg import JointState

from msg_adapters.diagnostics import from_diagnostic_array
from msg_adapters.joint_state import from_joint_state, joint_states_from_arrays
from msg_adapters.stamps import time_to_ns
from nmt_ros.model.jumper import default_model
from nmt_ros.model.parameters import JOINTS, MUSCLES
from nmt_ros.nodes._core import (
    ERROR,
    WARN,
    StreamGate,
    TrialBook,
    TrialClock,
)
from nmt_ros.nodes._ros import STATUS_QOS, STATUS_TOPIC, NmtNode, data_qos, run_node
from nmt_ros.nodes._streams import Stage2Output, Stage2Runner
from nmt_ros.tracking.neuromuscular_tracker import NeuromuscularTracker, load_stage2_settings

NODE_NAME = 'muscle_tracker'
TORQUES_TOPIC = '/nmt/skeletal/joint_torques'
FORCES_TOPIC = '/nmt/muscle/forces'
ACTIVATIONS_TOPIC = '/nmt/muscle/activations'
EXCITATIONS_TOPIC = '/nmt/muscle/excitations'
OUTPUT_TOPICS = (FORCES_TOPIC, ACTIVATIONS_TOPIC, EXCITATIONS_TOPIC)


class MuscleTrackerNode(NmtNode):
    """Stage 2 as a node (see the module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.param
        self.window_length_s = p('window_length_s', 0.1, 'Riccati window H [s]: latency vs '
                                 'agreement with the full horizon', low=0.001, high=10.0)
        self.window_stride_s = p('window_stride_s', 0.01, 'a window is planned every stride '
                                 '[s] (0 = every sample): CPU vs latency', low=0.0, high=10.0)
        self.saturation = p('saturation', 'plan', "excitation bounds: 'plan' (bounded LQT, "
                            "the batch default) or 'clip' (the paper's Eq. 9 clipped)")
        self.input_rate_hz = p('input_rate_hz', 1080.0, 'rate of the joint-torque samples '
                               '[Hz]', low=1.0, high=100000.0)
        self.process_period_s = p('process_period_s', 0.005, 'queued samples are pushed to '
                                  'Stage 2 this often [s] (batching amortises the cost)',
                                  low=0.0005, high=1.0)
        self.gap_factor = p('gap_factor', 1.5, 'a spacing above this many periods is a gap '
                            '(filled by interpolation, reported)', low=1.01, high=100.0)
        self.max_gap_s = p('max_gap_s', 0.5, 'a longer gap ends the trial [s]', low=0.0,
                           high=3600.0)
        self.idle_flush_s = p('idle_flush_s', 1.0, 'end the trial after this long without '
                              'input [s] (0 = never)', low=0.0, high=3600.0)
        self.end_timeout_s = p('end_timeout_s', 2.0, 'after an end-of-stream announcement, '
                               'flush at the latest after this long [s]', low=0.0, high=3600.0)
        self.input_reliable = p('input_reliable', True, 'subscribe RELIABLE (lossless)')
        stride = self.window_stride_s if self.window_stride_s > 0 else None
        self.status.settings = {'window_length_s': self.window_length_s,
                                'window_stride_s': self.window_stride_s,
                                'saturation': self.saturation,
                                'input_rate_hz': self.input_rate_hz}

        self.model = default_model()
        self.tracker = NeuromuscularTracker(
            self.model, load_stage2_settings(saturation=self.saturation))
        self.runner = Stage2Runner(self.model, self.tracker, self.window_length_s, stride,
                                   self.input_rate_hz)
        self.clock = TrialClock(0)
        self.gate = StreamGate(TORQUES_TOPIC, 1 / self.input_rate_hz, self.gap_factor,
                               self.max_gap_s)
        self.book = TrialBook((TORQUES_TOPIC,))
        self.tracking = False
        self.last_input = time.monotonic()
        self.received_at: dict[int, float] = {}
        self.newest_input_ns = 0
        self.newest_output_ns = 0

        qos = data_qos(self.qos_depth)
        self.pubs = {topic: self.create_publisher(JointState, topic, qos)
                     for topic in OUTPUT_TOPICS}
        self.create_timer(self.process_period_s, self.process)
        self.create_timer(0.05, self.watchdog)
        self.status.state = 'ready'
        self.create_subscription(DiagnosticArray, STATUS_TOPIC, self.on_status, STATUS_QOS)
        self.open_inputs_when_ready(self._open_inputs)

    def _open_inputs(self) -> None:
        qos = data_qos(self.qos_depth, self.input_reliable)
        self.create_subscription(JointState, TORQUES_TOPIC, self.on_torques, qos)

    # ------------------------------------------------------------------ inputs
    def on_torques(self, msg: JointState) -> None:
        received = time.monotonic()
        self.status.receive(TORQUES_TOPIC)
        self.book.saw(TORQUES_TOPIC, time_to_ns(msg.header.stamp))
        try:
            sample = from_joint_state(msg, JOINTS, require=('position', 'velocity', 'effort'))
        except ValueError as exc:
            self.status.reject(TORQUES_TOPIC, f'{TORQUES_TOPIC}: {exc}')
            self.notify()
            return
        self.status.mark_active()
        self.last_input = received
        if not self.tracking:
            self._start_trial(sample.stamp_ns)
        values = np.concatenate([sample.effort, sample.position, sample.velocity])
        result = self.gate.offer(sample.stamp_ns, values)
        if result.rejected:
            self.status.reject(TORQUES_TOPIC, result.rejected)
            self.notify()
            return
        if result.restart:
            self.status.event(WARN, result.restart)
            self._finish(result.restart)
            self._start_trial(sample.stamp_ns)
            self.book.saw(TORQUES_TOPIC, sample.stamp_ns)
            result = self.gate.offer(sample.stamp_ns, values)
        if result.gap:
            self.status.interpolated += len(result.samples) - 1
            self.status.event(WARN, result.gap)
        for s in result.samples:
            v = s.values
            self.runner.add(s.stamp_ns, self._grid_time(s.stamp_ns), v[0:3], v[3:6], v[6:9])
        self.received_at[sample.stamp_ns] = received
        self.newest_input_ns = max(self.newest_input_ns, sample.stamp_ns)
        self._check_end()

    def _grid_time(self, stamp_ns: int) -> float:
        """Trial time snapped to the nominal grid k / input_rate_hz (stamps are rounded to
        the nanosecond; Stage 2 joins its windows on an exactly uniform grid)."""
        return round(self.clock.t(stamp_ns) * self.input_rate_hz) / self.input_rate_hz

    def on_status(self, msg: DiagnosticArray) -> None:
        _, records = from_diagnostic_array(msg)
        if any(self.book.announcement(r.values, time.monotonic()) for r in records):
            self._check_end()

    # ------------------------------------------------------------------ trial
    def _start_trial(self, stamp_ns: int) -> None:
        trial = self.book.start()
        self.runner.reset()
        self.clock.reset()
        self.gate.reset()
        self.gate.not_before_ns = self.clock.start(stamp_ns)
        self.received_at = {}
        self.status.error = None
        self.tracking = True
        self.status.state = 'tracking'
        self.status.detail = f'trial {trial}'
        self.status.extra['trial'] = trial

    def process(self, final: bool = False) -> None:
        if not self.tracking:
            return
        try:
            out = self.runner.process(final=final)
        except Exception as exc:  # noqa: BLE001 - report, drop the trial, keep running
            self.status.error = f'Stage 2 failed: {exc!r}'
            self.status.event(ERROR, self.status.error)
            self.runner.finished = True
            self.notify(0.0)
            return
        if self.runner.problem:
            self.status.event(WARN, self.runner.problem)
            self.runner.problem = None
        self._publish(out)

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
        self.process(final=True)
        self.tracking = False
        self.status.state = 'finished'
        self.status.detail = f'trial {self.book.trial} finished: {why}'
        counts, firsts = self.book.finish()
        self.announce_end(counts, firsts, trial=self.book.trial, reason=why)
        if self.exit_when_finished:
            self.done = True

    def watchdog(self) -> None:
        if not self.tracking:
            return
        self._check_end()
        if not self.tracking:
            return
        idle = time.monotonic() - self.last_input
        if self.idle_flush_s > 0 and idle > self.idle_flush_s:
            gone = self.count_publishers(TORQUES_TOPIC) == 0
            why = f'no input for {idle:.2f} s' + ('; publisher gone' if gone else '')
            self.status.event(ERROR if gone else WARN, why)
            self._finish(why)

    # ------------------------------------------------------------------ outputs
    def _publish(self, out: Stage2Output | None) -> None:
        if out is None or out.t.size == 0:
            return
        stamps = out.stamp_ns
        batches = {
            FORCES_TOPIC: joint_states_from_arrays(stamps, MUSCLES, position=out.l_mt,
                                                   velocity=out.v_mt, effort=out.f),
            ACTIVATIONS_TOPIC: joint_states_from_arrays(stamps, MUSCLES, position=out.a),
            EXCITATIONS_TOPIC: joint_states_from_arrays(stamps, MUSCLES, position=out.u),
        }
        for i in range(stamps.size):
            for topic, msgs in batches.items():
                self.pubs[topic].publish(msgs[i])
        now = time.monotonic()
        for topic in batches:
            self.status.publish(topic, stamps.size)
            self.book.output(topic, int(stamps[0]), stamps.size)
        for s in stamps.tolist():
            received = self.received_at.pop(s, None)
            if received is not None:
                self.status.delay(now - received)
        self.newest_output_ns = int(stamps[-1])
        if out.saturated.any():
            self.status.extra['saturated_samples'] = int(
                self.status.extra.get('saturated_samples', 0) + out.saturated.any(axis=1).sum())

    def status_values(self) -> None:
        self.status.extra['data_lag_ms'] = (
            (self.newest_input_ns - self.newest_output_ns) / 1e6
            if self.newest_output_ns else float('nan'))

    def on_shutdown(self, interrupted: bool) -> None:
        if not interrupted:
            self.publish_status()
            if not self.wait_for_acks(10.0):
                self.exit_code = 1


def main(args: Sequence[str] | None = None) -> int:
    return run_node(MuscleTrackerNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
