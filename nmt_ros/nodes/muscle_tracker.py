"""muscle_tracker: Stage 2 (neuromuscular tracking, receding Riccati windows) live.

Subscribes ``/nmt/skeletal/joint_torques`` (JointState [ankle, knee, hip]: OpenSim joint
angle, rate and torque, one per force-plate instant). The samples go to Stage 2
(``nmt_ros.tracking.streaming.Stage2Stream`` over ``NeuromuscularTracker.push``, the code of
the batch windowed mode) as they arrive: a window of length ``window_length_s`` (H) is planned
(bounded LQT, backward Riccati/adjoint sweep) in the callback of the sample that completes its
look-ahead, and applied over ``window_stride_s``. The estimate for instant t is therefore
available once Stage 1 reached t + H; its latency is the skeletal tracker's plus H plus up to
a stride. The work is cut by data (sample indices), never by a timer: the same input stream
gives the same estimates at any replay rate and under any CPU load. Joint accelerations are
central differences of the received joint rates.

Publishes, stamped with the observation instant of the torque sample they belong to:
``/nmt/muscle/forces`` (JointState [gmax, ilpso, hams, bfsh, rf, vas, gas, sol, ta]:
position = musculotendon length [m], velocity = lengthening speed [m/s], effort = force [N]),
``/nmt/muscle/activations`` and ``/nmt/muscle/excitations`` (position = value in [0, 1]).
Bad samples are rejected with a reason on ``/nmt/status``; the trial ends on the skeletal
tracker's end-of-stream announcement (or ``idle_flush_s`` without input).
"""
from __future__ import annotations

from collections.abc import Sequence
import gc
import time

import numpy as np
from sensor_msgs.msg import JointState

from msg_adapters.joint_state import from_joint_state, joint_state_blobs, joint_states_from_blobs
from msg_adapters.series import CheckedBlock
from nmt_ros.model.parameters import JOINTS, MUSCLES
from nmt_ros.model.subject import load_subject_model
from nmt_ros.nodes.input_gate import Sample
from nmt_ros.nodes.node_base import TrackerNode
from nmt_ros.nodes.node_status import ERROR, WARN
from nmt_ros.nodes.runtime import run_node
from nmt_ros.topics import (
    MUSCLE_ACTIVATIONS,
    MUSCLE_EXCITATIONS,
    MUSCLE_FORCES,
    MUSCLE_OUTPUTS,
    SKELETAL_JOINT_TORQUES,
)
from nmt_ros.tracking.stage2 import NeuromuscularTracker, load_stage2_settings
from nmt_ros.tracking.streaming import Decimator, Stage2Output, Stage2Stream

NODE_NAME = 'muscle_tracker'


class MuscleTrackerNode(TrackerNode):
    """Stage 2 as a node (see the module docstring)."""

    INPUTS = {SKELETAL_JOINT_TORQUES: JointState}
    OUTPUTS = dict.fromkeys(MUSCLE_OUTPUTS, JointState)

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.param
        self.window_length_s = p('window_length_s', 0.03, 'Riccati window H [s]: latency vs '
                                 'agreement with the full horizon', low=0.001, high=10.0)
        self.window_stride_s = p('window_stride_s', 0.02, 'a window is planned every stride '
                                 '[s] (0 = every sample): CPU vs latency', low=0.0, high=10.0)
        self.saturation = p('saturation', 'plan', "excitation bounds: 'plan' (bounded LQT, "
                            "the batch default) or 'clip' (the paper's Eq. 9 clipped)")
        self.input_rate_hz = p('input_rate_hz', 1080.0, 'rate of the joint-torque samples '
                               '[Hz]', low=1.0, high=100000.0)
        self.subject_file = p('subject_file', '', "the subject's model (a subject.yaml written "
                              "by nmt import-lab; '' = the shipped jumper)")
        self.side_rate_hz = p('side_rate_hz', 0.0, 'rate of the activations and excitations '
                              '[Hz] (the forces keep every input instant); 0 = every instant '
                              '(publishing costs ~0.1 ms per message)', low=0.0, high=100000.0)
        self.side_decimator = Decimator(self.side_rate_hz) if self.side_rate_hz else None
        stride = self.window_stride_s if self.window_stride_s > 0 else None
        self.status.settings = {'window_length_s': self.window_length_s,
                                'window_stride_s': self.window_stride_s,
                                'saturation': self.saturation,
                                'input_rate_hz': self.input_rate_hz,
                                'subject_file': self.subject_file,
                                'side_rate_hz': self.side_rate_hz}

        self.model = load_subject_model(self.subject_file or None)
        self.tracker = NeuromuscularTracker(
            self.model, load_stage2_settings(saturation=self.saturation))
        self.stream = Stage2Stream(self.model, self.tracker, self.window_length_s, stride,
                                   self.input_rate_hz)
        self.gates = self.stream_gates({SKELETAL_JOINT_TORQUES: 1 / self.input_rate_hz})
        self.received_at: dict[int, float] = {}
        self.stream.warm_up()          # compiled kernels loaded before the inputs open
        # the model, CasADi functions and rclpy objects are permanent: out of the cyclic
        # garbage collector's scans (a full collection of them stalled a window by ~150 ms)
        gc.freeze()
        self.listen()

    # ------------------------------------------------------------------ inputs
    def parse(self, topic: str, msg: JointState) -> tuple[int, np.ndarray]:
        sample = from_joint_state(msg, JOINTS, require=('position', 'velocity', 'effort'))
        return sample.stamp_ns, np.concatenate([sample.effort, sample.position,
                                                sample.velocity])

    def parse_block(self, topic: str, blobs: Sequence[bytes]) -> CheckedBlock:
        return joint_states_from_blobs(blobs, JOINTS, ('effort', 'position', 'velocity'),
                                       require=('position', 'velocity', 'effort'))

    def feed(self, topic: str, samples: Sequence[Sample], stamp_ns: int,
             received: float) -> None:
        for s in samples:
            v = s.values
            self.stream.add(s.stamp_ns, self.clock.t(s.stamp_ns), v[0:3], v[3:6], v[6:9])
        self.received_at[stamp_ns] = received
        self.newest_input_ns = max(self.newest_input_ns, stamp_ns)
        if not self.taking:          # a callback per message; else at the batch's end
            self.batch_done()

    def batch_done(self) -> None:
        # Stage 2's pushes are cut by the data (``Stage2Stream.process``): once per batch
        # gives the same outputs as once per message, without the per-call planning
        self.process()
        self._check_end()

    # ------------------------------------------------------------------ trial
    def on_trial_start(self, epoch_ns: int) -> None:
        self.received_at = {}
        self.side_decimator = Decimator(self.side_rate_hz) if self.side_rate_hz else None

    def process(self, final: bool = False) -> None:
        if not self.tracking:
            return
        try:
            out = self.stream.process(final=final)
        except Exception as exc:  # noqa: BLE001 - report, drop the trial, keep running
            self.status.error = f'Stage 2 failed: {exc!r}'
            self.status.event(ERROR, self.status.error)
            self.stream.finished = True
            self.notify(0.0)
            return
        if self.stream.problem:
            self.status.event(WARN, self.stream.problem)
            self.stream.problem = None
        self._publish(out)

    def flush(self) -> None:
        self.process(final=True)

    # ------------------------------------------------------------------ outputs
    def _publish(self, out: Stage2Output | None) -> None:
        if out is None or out.t.size == 0:
            return
        stamps = out.stamp_ns
        self.publish_batches(stamps, {
            MUSCLE_FORCES: joint_state_blobs(stamps, MUSCLES, position=out.l_mt,
                                             velocity=out.v_mt, effort=out.f)})
        # activations and excitations: every instant, or the first of each side-rate period
        keep = (self.side_decimator.keep(out.t) if self.side_decimator is not None
                else np.ones(out.t.size, dtype=bool))
        if keep.any():
            newest = self.newest_output_ns
            side = stamps[keep]
            self.publish_batches(side, {
                MUSCLE_ACTIVATIONS: joint_state_blobs(side, MUSCLES, position=out.a[keep]),
                MUSCLE_EXCITATIONS: joint_state_blobs(side, MUSCLES, position=out.u[keep]),
            })
            self.newest_output_ns = max(newest, self.newest_output_ns)
        now = time.monotonic()
        for s in stamps.tolist():
            received = self.received_at.pop(s, None)
            if received is not None:
                self.status.delay(now - received)
        if out.saturated.any():
            self.status.extra['saturated_samples'] = int(
                self.status.extra.get('saturated_samples', 0) + out.saturated.any(axis=1).sum())


def main(args: Sequence[str] | None = None) -> int:
    return run_node(MuscleTrackerNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
