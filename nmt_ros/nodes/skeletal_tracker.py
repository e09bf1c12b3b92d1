"""skeletal_tracker: Stage 1 live, in step with the observations.

Subscribes ``/mocap/segment_angles`` (JointState [foot, shank, thigh, hat], position) and
``/force_plate/wrench`` (WrenchStamped in ``wrench_frame``). Two estimators (``estimator``):

* ``mhe`` (default): the moving-horizon estimator
  (``nmt_ros.tracking.moving_horizon.MovingHorizonEstimator``, the batch ``nmt track``'s
  code): every sample goes in as it arrives, the estimator updates on data time alone (so
  what it publishes depends on the input stream only, not on timing) and gives, for every
  force-plate instant, a low-latency estimate (``/nmt/skeletal/low_latency/*``) and the
  refined one ``lag_s`` later (the topics below). Occluded markers / missing channels (NaN)
  are passed through as missing values and counted; the estimator bridges them.
* ``skt``: the paper's skeletal motion tracker, filtered with a fixed look-ahead
  (``lookahead_s``) and stepped after each arrival (``nmt_ros.tracking.streaming``).

Publishes, stamped with the observation instant (the force-plate samples):

- ``/nmt/skeletal/joint_torques``: JointState [ankle, knee, hip], position/velocity = OpenSim
  joint angle/rate, effort = torque [N m] (as ``/truth/joint_torques``);
- ``/nmt/skeletal/segment_angles``: JointState [foot, shank, thigh, hat] (position, velocity);
- ``/nmt/skeletal/generalized_coordinates``: JointState [th1..th4, r1, r2] (position,
  velocity): the whole tracked state, e.g. for the jump height;
- ``/nmt/skeletal/ground_wrench``: WrenchStamped ('foot_com') from the model's springs.

Joint accelerations are not published: the muscle tracker differences the joint rates.
Bad samples (inf, NaN in ``skt`` mode, wrong length or names, wrong frame, duplicate or
out-of-order stamps) are rejected with a reason on ``/nmt/status``; gaps are filled by
interpolation and reported; the estimator's own events (initialised, observations poorly
explained, loss of control and re-initialisation) go to ``/nmt/status`` too. The trial ends
(the last estimates are flushed) when the producer's end-of-stream
announcement has been matched by the messages received, when no input came for
``idle_flush_s`` or when a gap exceeds ``max_gap_s``; new data then start a new trial.
"""
from __future__ import annotations

from collections.abc import Sequence
import time

from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from msg_adapters.joint_state import from_joint_state, joint_state_blobs, joint_states_from_blobs
from msg_adapters.planar import (
    PLANAR,
    from_planar_wrench,
    planar_wrench_blobs,
    planar_wrenches_from_blobs,
)
from msg_adapters.series import CheckedBlock
from nmt_ros.model.parameters import JOINTS, Q_NAMES, SEGMENTS
from nmt_ros.model.subject import load_subject_model
from nmt_ros.nodes.input_gate import Sample, TrialClock
from nmt_ros.nodes.node_base import TrackerNode
from nmt_ros.nodes.node_status import ERROR, OK, WARN
from nmt_ros.nodes.runtime import run_node
from nmt_ros.topics import (
    FORCE_PLATE_WRENCH,
    MOCAP_SEGMENT_ANGLES,
    SKELETAL_GENERALIZED_COORDINATES,
    SKELETAL_GROUND_WRENCH,
    SKELETAL_JOINT_TORQUES,
    SKELETAL_LOW_LATENCY,
    SKELETAL_SEGMENT_ANGLES,
    WRENCH_FRAME,
)
from nmt_ros.tracking.conditioning import ConditioningSettings
from nmt_ros.tracking.moving_horizon.estimator import EstimateBlock, MovingHorizonEstimator
from nmt_ros.tracking.moving_horizon.settings import (
    MovingHorizonSettings,
    airborne_translation_diffusion_for,
    excitation_rate_weight_for,
    joint_torques_for,
    landing_rate_sd_scale_for,
)
from nmt_ros.tracking.skeletal_tracker import SKTSettings
from nmt_ros.tracking.streaming import Decimator, Stage1Output, Stage1Stream

NODE_NAME = 'skeletal_tracker'


#: Stage 1's output topics, in publishing order (the first: the joint torques)
SKELETAL_TOPICS = (SKELETAL_JOINT_TORQUES, SKELETAL_SEGMENT_ANGLES,
                   SKELETAL_GENERALIZED_COORDINATES, SKELETAL_GROUND_WRENCH)


class SkeletalTrackerNode(TrackerNode):
    """Stage 1 as a node (see the module docstring)."""

    INPUTS = {MOCAP_SEGMENT_ANGLES: JointState, FORCE_PLATE_WRENCH: WrenchStamped}
    OUTPUTS = {SKELETAL_JOINT_TORQUES: JointState, SKELETAL_SEGMENT_ANGLES: JointState,
               SKELETAL_GENERALIZED_COORDINATES: JointState, SKELETAL_GROUND_WRENCH: WrenchStamped}
    OUTPUTS.update({SKELETAL_LOW_LATENCY[k]: v for k, v in OUTPUTS.items()})

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.param
        self.estimator = p('estimator', 'mhe', "Stage 1: 'mhe' (the moving-horizon estimator: "
                           "low-latency and refined estimates) or 'skt' (the paper's tracker)")
        if self.estimator not in ('mhe', 'skt'):
            self.fail_to_start(f"estimator must be 'mhe' or 'skt', not {self.estimator!r}")
        d = MovingHorizonSettings()
        self.lag_s = p('lag_s', d.lag_s, 'mhe: the refined estimate lags the newest data by '
                       'this [s] (latency vs accuracy: bench/bench_estimator.py)', low=0.0,
                       high=1.0)
        self.window_s = p('window_s', d.window_s, 'mhe: data span of the window [s] (>= lag '
                          '+ one update)', low=0.01, high=2.0)
        self.update_rate_hz = p('update_rate_hz', d.update_rate_hz, 'mhe: updates per second '
                                'of data (CPU vs latency)', low=1.0, high=2000.0)
        self.iterations = p('iterations', d.iterations, 'mhe: Gauss-Newton iterations per '
                            'update', low=1, high=20)
        self.mocap_latency_s = p('mocap_latency_s', d.angle_latency_s, "mhe: the mocap "
                                 'stamps are this long after the instant they measured (a '
                                 "camera system's latency, stamped on arrival) [s]",
                                 low=0.0, high=1.0)
        self.frame_clock_alpha = p('frame_clock_alpha', d.frame_clock_alpha, "mhe: mocap "
                                   "stamps taken on the camera's frame clock, this smoothing "
                                   'per frame (0 = the stamps as received)', low=0.0, high=1.0)
        self.saturation_min_bw = p('saturation_min_bw', d.saturation_min_bw, 'mhe: a plate '
                                   'reading at least this [BW] repeating exactly is a '
                                   'saturated channel, taken as missing (0 = off)',
                                   low=0.0, high=100.0)
        self.wrench_cutoff_hz = p('wrench_cutoff_hz', d.wrench_cutoff_hz, 'mhe: smoothness of '
                                  'the estimated ground wrench, the cut-off of its '
                                  'smoothing-spline prior [Hz] (at most 0.8 x the force '
                                  "plate's Nyquist frequency; lower it for noisy lab plates)",
                                  low=0.1, high=50000.0)
        self.excitation_weight = p('excitation_weight', d.excitation_weight, 'mhe: effort '
                                   'weight w_u of the excitations [1/s]: how the redundant '
                                   'muscles share the torques (README, "Known limitations": '
                                   '200 gave the estimator\'s own muscle forces 4.3 instead of '
                                   '7.9 % F0 at equal torques, with more losses of control)',
                                   low=0.0, high=1e6)
        self.still_rate_sd_scale = p(
            'still_rate_sd_scale', d.still_rate_sd_scale, "mhe: the excitations' rate prior "
            'SD times this where the force plate says the body is still (quiet stance; 1 = '
            'off)', low=0.01, high=100.0)
        self.airborne_start_wait_s = p(
            'airborne_start_wait_s', d.airborne_start_wait_s, 'mhe: a stream that begins in '
            'the air starts on its first landing if one comes within this much data [s] (its '
            'window then spans the whole fall); 0 = start in the air', low=0.0, high=10.0)
        self.slow_backlog_s = p('slow_backlog_s', d.slow_backlog_s, 'mhe: with more data '
                                'than this waiting, update every other period until caught up '
                                '(less latency after a burst; the estimates then depend on the '
                                'timing) [s]; 0 = never', low=0.0, high=60.0)
        self.max_backlog_s = p('max_backlog_s', d.max_backlog_s, 'mhe: with more data than '
                               'this waiting, skip to the newest data and re-initialise [s]; '
                               '0 = never', low=0.0, high=3600.0)
        self.side_rate_hz = p('side_rate_hz', 0.0, 'mhe: rate of every output but the '
                              'refined joint torques (segment angles, coordinates, ground '
                              'wrench, the low-latency topics) [Hz]; 0 = every force-plate '
                              'instant (publishing costs ~0.1 ms per message)', low=0.0,
                              high=100000.0)
        self.side_decimators = self._side_decimators()
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
        self.substeps = p('substeps', 1, 'RK4 steps per force sample at 1080 Hz (the batch '
                          'default, 2, costs twice the CPU for < 0.5 % of peak torque); slower '
                          'force plates get proportionally more (11 at 100 Hz)', low=1, high=64)
        self.subject_file = p('subject_file', '', "the subject's model (a subject.yaml written "
                              "by nmt import-lab; '' = the shipped jumper)")
        self.joint_torques = p('joint_torques', 'auto', "mhe: the joint torques published: "
                               "'muscle' (the muscles'), 'net' (the net torques of the "
                               "estimated motion and ground wrench) or 'auto' (net with a "
                               "subject_file, a lab recording's subject; the muscles' for the "
                               'shipped jumper)')
        self.excitation_rate_weight = p(
            'excitation_rate_weight', 0.0, "mhe: the excitations' rate prior w_du [s]; 0 = "
            "auto (2 with a subject_file, a lab recording's subject; 10 for the shipped "
            'jumper)', low=0.0, high=1e6)
        try:
            self.joint_torques = joint_torques_for(self.joint_torques, bool(self.subject_file))
            self.excitation_rate_weight = excitation_rate_weight_for(
                self.excitation_rate_weight, bool(self.subject_file))
        except ValueError as err:
            self.fail_to_start(str(err))
            self.joint_torques = 'muscle'
            self.excitation_rate_weight = d.excitation_rate_weight
        self.start_s = p('start_s', 0.0, 'mhe: estimate from this trial time on [s]; earlier '
                         'samples are counted and not used (a support the force plates do '
                         'not measure, e.g. the box of a drop jump: nmt launch passes the '
                         "step-off nmt import-lab found)", low=0.0, high=1e6)
        self.before_start = 0
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
        self.mhe_settings = d.with_(lag_s=self.lag_s, window_s=self.window_s,
                                    slow_backlog_s=self.slow_backlog_s,
                                    max_backlog_s=self.max_backlog_s,
                                    update_rate_hz=self.update_rate_hz,
                                    iterations=self.iterations,
                                    wrench_cutoff_hz=self.wrench_cutoff_hz,
                                    excitation_weight=self.excitation_weight,
                                    excitation_rate_weight=self.excitation_rate_weight,
                                    landing_rate_sd_scale=landing_rate_sd_scale_for(
                                        bool(self.subject_file)),
                                    airborne_translation_diffusion_m_sqrt_s=(
                                        airborne_translation_diffusion_for(
                                            bool(self.subject_file))),
                                    airborne_start_wait_s=self.airborne_start_wait_s,
                                    still_rate_sd_scale=self.still_rate_sd_scale,
                                    joint_torques=self.joint_torques,
                                    angle_rate_hz=self.angle_rate_hz,
                                    wrench_rate_hz=self.wrench_rate_hz,
                                    angle_latency_s=self.mocap_latency_s,
                                    frame_clock_alpha=self.frame_clock_alpha,
                                    saturation_min_bw=self.saturation_min_bw)
        self.status.settings = {
            'estimator': self.estimator, 'lag_s': self.lag_s, 'window_s': self.window_s,
            'update_rate_hz': self.update_rate_hz, 'iterations': self.iterations,
            'wrench_cutoff_hz': self.wrench_cutoff_hz,
            'excitation_weight': self.excitation_weight,
            'airborne_start_wait_s': self.airborne_start_wait_s,
            'slow_backlog_s': self.slow_backlog_s, 'max_backlog_s': self.max_backlog_s,
            'side_rate_hz': self.side_rate_hz,
            'lookahead_s': self.lookahead_s,
            'substeps': self.substeps, 'angle_cutoff_hz': self.angle_cutoff_hz,
            'force_cutoff_hz': self.force_cutoff_hz, 'filter_window_s': self.filter_window_s,
            'wrench_rate_hz': self.wrench_rate_hz, 'angle_rate_hz': self.angle_rate_hz,
            'bias_rate': self.bias_rate, 'subject_file': self.subject_file,
            'start_s': self.start_s, 'joint_torques': self.joint_torques,
            'excitation_rate_weight': self.excitation_rate_weight,
            'landing_rate_sd_scale': self.mhe_settings.landing_rate_sd_scale,
            'still_rate_sd_scale': self.still_rate_sd_scale,
            'mocap_latency_s': self.mocap_latency_s,
            'frame_clock_alpha': self.frame_clock_alpha,
            'saturation_min_bw': self.saturation_min_bw,
            'airborne_translation_diffusion_m_sqrt_s':
                self.mhe_settings.airborne_translation_diffusion_m_sqrt_s}

        # the numerical core (built before any input is accepted: the estimator's compiled
        # kernel is made or loaded here, not at the first sample)
        self.model = load_subject_model(self.subject_file or None)
        self.stream = Stage1Stream(self.model, self.settings, self.conditioning,
                                   angle_rate_hz=self.angle_rate_hz,
                                   wrench_rate_hz=self.wrench_rate_hz)
        self.mhe = (MovingHorizonEstimator(self.model, self.mhe_settings)
                    if self.estimator == 'mhe' else None)
        self.events_seen = 0
        self.masked = 0
        self.in_gap: dict[str, bool] = {}
        self.clock = TrialClock(self.epoch_ns)
        self.gates = self.stream_gates({MOCAP_SEGMENT_ANGLES: 1 / self.angle_rate_hz,
                                        FORCE_PLATE_WRENCH: 1 / self.wrench_rate_hz},
                                       fill_gaps=self.estimator == 'skt')
        self.polled_until = -np.inf
        self.first_pending = np.inf
        if self.estimator == 'skt':
            self.create_timer(self.poll_period_s, self.poll)
        self.listen()

    # ------------------------------------------------------------------ inputs
    def parse(self, topic: str, msg: JointState | WrenchStamped) -> tuple[int, np.ndarray]:
        lenient = self.estimator == 'mhe'
        if topic == MOCAP_SEGMENT_ANGLES:
            sample = from_joint_state(msg, SEGMENTS, require=('position',), allow_nan=lenient)
            return sample.stamp_ns, sample.position
        return from_planar_wrench(msg, self.wrench_frame or None, allow_nan=lenient)

    def parse_block(self, topic: str, blobs: Sequence[bytes]) -> CheckedBlock:
        lenient = self.estimator == 'mhe'
        if topic == MOCAP_SEGMENT_ANGLES:
            return joint_states_from_blobs(blobs, SEGMENTS, ('position',),
                                           require=('position',), allow_nan=lenient)
        return planar_wrenches_from_blobs(blobs, self.wrench_frame or None, allow_nan=lenient)

    def feed(self, topic: str, samples: Sequence[Sample], stamp_ns: int,
             received: float) -> None:
        if self.estimator == 'mhe':
            self._feed_mhe(topic, samples, stamp_ns, received)
            return
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

    def _feed_mhe(self, topic: str, samples: Sequence[Sample], stamp_ns: int,
                  received: float) -> None:
        """Every accepted sample into the estimator; publish what its updates produced (the
        updates run on data time: when they run does not depend on arrival timing)."""
        add = self.mhe.add_angles if topic == MOCAP_SEGMENT_ANGLES else self.mhe.add_wrench
        names = SEGMENTS if topic == MOCAP_SEGMENT_ANGLES else PLANAR
        for sample in samples:
            if self.clock.t(sample.stamp_ns) < self.start_s - 1e-9:
                if not self.before_start:
                    self.status.event(OK, f'samples before start_s = {self.start_s:g} s are '
                                      'not estimated', t=self.clock.t(sample.stamp_ns))
                    self.notify()
                self.before_start += 1
                self.status.extra['before_start'] = self.before_start
                continue
            total = sample.values.sum()        # not NaN: no value missing (the cheap test)
            gaps = np.flatnonzero(np.isnan(sample.values)) if total != total else ()
            if len(gaps):
                self.masked += gaps.size
                self.status.extra['missing_values'] = self.masked
                if not self.in_gap.get(topic):      # said once per run of missing samples
                    where = ', '.join(f'{i} ({names[i]})' for i in gaps)
                    self.status.event(WARN, f'{topic}: non-finite value nan at index {where}: '
                                      'missing, bridged by the estimator',
                                      t=self.clock.t(sample.stamp_ns))
                    self.notify()
            self.in_gap[topic] = bool(len(gaps))
            try:
                add(self.clock.t(sample.stamp_ns), sample.values)
            except ValueError as exc:          # a sample later than the update it belongs to
                self.status.reject(topic, f'{topic}: {exc}')
        self.newest_input_ns = max(self.newest_input_ns, stamp_ns)
        self.first_pending = min(self.first_pending, received)
        if not self.taking:          # a callback per message; else at the batch's end
            self._poll_mhe()

    def batch_done(self) -> None:
        if self.mhe is not None and self.tracking:
            self._poll_mhe()

    def _poll_mhe(self) -> None:
        """Run the updates the data allow (a batch that left the estimator more than
        max_backlog_s behind makes it skip ahead, reported); publish; end-of-stream check."""
        blocks = self.mhe.poll()
        if blocks:
            received, self.first_pending = self.first_pending, np.inf
            self._publish_blocks(blocks, received)
        self._report_events()
        self._check_end()

    def _report_events(self) -> None:
        levels = {'info': OK, 'warn': WARN, 'error': ERROR}
        new = self.mhe.events[self.events_seen:]
        self.events_seen = len(self.mhe.events)
        for ev in new:
            self.status.event(levels[ev.level], f't = {ev.t:.4f} s: {ev.message}',
                              **ev.values)
            if ev.level == 'error':
                self.status.error = ev.message
        if new:
            self.status.extra['restarts'] = self.mhe.restarts
            self.notify()

    # ------------------------------------------------------------------ trial
    def on_trial_start(self, epoch_ns: int) -> None:
        self.polled_until = -np.inf
        self.before_start = 0
        self.side_decimators = self._side_decimators()
        self.first_pending = np.inf
        self.status.extra['epoch_ns'] = epoch_ns
        if self.mhe is not None:
            self.mhe = MovingHorizonEstimator(self.model, self.mhe_settings)
            self.events_seen = 0

    def flush(self) -> None:
        if self.mhe is not None:
            self._publish_blocks(self.mhe.finish(), time.monotonic())
            self._report_events()
            return
        self._publish(self.stream.finish(), time.monotonic())

    def end_state(self) -> str:
        if self.mhe is not None:
            return 'finished'
        return 'lost_control' if self.stream.status != 'ok' else 'finished'

    # ------------------------------------------------------------------ outputs
    def _side_decimators(self) -> dict[str, Decimator]:
        """A fresh ``side_rate_hz`` decimator per estimate kind (none at 0: every instant)."""
        if self.side_rate_hz <= 0:
            return {}
        return {kind: Decimator(self.side_rate_hz) for kind in ('refined', 'low_latency')}

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
        self._publish_estimates(out.t, out.joint_angles, out.joint_rates, out.tau, out.q,
                                out.qd, out.s, SKELETAL_TOPICS)
        if np.isfinite(received):
            self.status.delay(time.monotonic() - received)

    def _publish_blocks(self, blocks: list[EstimateBlock], received: float) -> None:
        """Refined blocks on the main topics, low-latency ones on the low-latency topics. With
        ``side_rate_hz``, every topic but the refined joint torques (Stage 2's input) only at
        the first observation instant of each period of that rate (``Decimator``)."""
        for block in blocks:
            refined = block.kind == 'refined'
            topics = SKELETAL_TOPICS if refined else tuple(
                SKELETAL_LOW_LATENCY[t] for t in SKELETAL_TOPICS)
            if self.side_rate_hz > 0:
                if refined:
                    self._publish_block(block, topics[:1])
                    topics = topics[1:]
                block = block.part(block.kind, self.side_decimators[block.kind].keep(block.t))
            self._publish_block(block, topics)
            if refined and np.isfinite(received):
                self.status.delay(time.monotonic() - received)

    def _publish_block(self, block: EstimateBlock, topics: tuple[str, ...]) -> None:
        self._publish_estimates(block.t, block.theta, block.theta_dot, block.tau, block.q,
                                block.qd, block.s, topics)

    def _publish_estimates(self, t: np.ndarray, theta: np.ndarray, theta_dot: np.ndarray,
                           tau: np.ndarray, q: np.ndarray, qd: np.ndarray, s: np.ndarray,
                           topics: tuple[str, ...]) -> None:
        """Stage 1's estimates at trial times t [s] on ``topics`` (a subset of
        SKELETAL_TOPICS or their low-latency names, in that order)."""
        if t.size == 0:
            return
        stamps = self.clock.stamps(t)
        make = (lambda: joint_state_blobs(stamps, JOINTS, position=theta,
                                                 velocity=theta_dot, effort=tau),
                lambda: joint_state_blobs(stamps, SEGMENTS, position=q[:, :4],
                                                 velocity=qd[:, :4]),
                lambda: joint_state_blobs(stamps, Q_NAMES, position=q, velocity=qd),
                lambda: planar_wrench_blobs(stamps, WRENCH_FRAME, s))
        names = dict(zip(SKELETAL_TOPICS, make))
        names.update({SKELETAL_LOW_LATENCY[k]: v for k, v in zip(SKELETAL_TOPICS, make)})
        self.publish_batches(stamps, {topic: names[topic]() for topic in topics})

    def status_values(self) -> None:
        super().status_values()
        if self.mhe is not None:
            self.status.extra['updated_until_s'] = float(self.mhe.updated_until)
        else:
            self.status.extra['final_until_s'] = float(self.stream.final_until)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SkeletalTrackerNode, args, executor='events')


if __name__ == '__main__':
    raise SystemExit(main())
