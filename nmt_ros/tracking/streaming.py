"""The streaming layer: Stage 1 and Stage 2 fed sample by sample, one trial at a time.

The nodes and the batch tools drive the same objects, so live and offline estimates cannot
drift apart (ARCHITECTURE.md). No ROS here: samples go in as trial times [s] and arrays,
estimates come out as small records.

:class:`Stage1Stream` runs the skeletal tracker (the recipe
:class:`~nmt_ros.tracking.skeletal_tracker.SkeletalTracker`) in step with the data. Its input
is a conditioner: live, a :class:`~nmt_ros.tracking.conditioning.FixedLagConditioner` it owns,
fed with ``add_angles`` / ``add_wrench``; offline, the conditioned observations of a whole
recording (:func:`track_stage1`, the batch Stage 1). ``poll`` advances the tracker over every
force-plate instant k / rate_hz whose conditioned observations are final (data up to
t + lookahead_s arrived) and returns their outputs. ``finish`` ends the trial: the
conditioner's last window is filtered as a whole (exactly what the fixed-lag filter computes
when no look-ahead is missing, i.e. the offline filter on that window) and the tracker is
stepped to the last common sample.

:class:`Stage2Stream` feeds Stage-1 joint torques and kinematics to the receding-horizon
Stage 2 (``NeuromuscularTracker.push``). Input times are snapped to the nominal grid
k / rate_hz (header stamps are rounded to the nanosecond; Stage 2 joins its windows on an
exactly uniform grid). Joint accelerations are not published by the skeletal tracker: they
are central differences of the joint rates here (one sample, 0.9 ms, of delay). With inputs
at 1080 Hz Stage 2 needs no internal substeps, and there the accelerations only enter the
reported (unclipped) Eq. 9 excitation, not the forces. Initial activations:
``nmt_ros.model.squat.rest_activations`` for the first torque sample (the live node has no
truth).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
import time

import casadi as ca
import numpy as np

from nmt_ros.model.compiled import compiled
from nmt_ros.model.contact import LiftoffDetector, liftoff_time
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.squat import rest_activations
from nmt_ros.records import SKTResult
from nmt_ros.tracking.conditioning import (
    ConditionedObservations,
    ConditioningSettings,
    FixedLagConditioner,
)
from nmt_ros.tracking.skeletal_tracker import (
    SkeletalTracker,
    SKTSettings,
    SKTState,
    initial_state,
    reference_arrays,
)
from nmt_ros.tracking.stage2 import (
    NeuromuscularTracker,
    Stage2Result,
    StreamState,
)
from nmt_ros.tracking.stage2.streaming import samples_for_next_window

# --------------------------------------------------------------------------- Stage 1

@dataclass(frozen=True)
class Stage1Output:
    """Stage-1 outputs at the force-plate instants ``t`` (trial time, s)."""

    t: np.ndarray             # [n]
    q: np.ndarray             # [n, 6] generalized coordinates (rad, m)
    qd: np.ndarray            # [n, 6]
    qdd: np.ndarray           # [n, 6]
    tau: np.ndarray           # [n, 3] ankle, knee, hip (N m)
    s: np.ndarray             # [n, 3] synthesised ground wrench Fx, Fy (N), Mz (N m)
    bias: np.ndarray          # [n] moment-bias estimate (N m)
    residual: np.ndarray      # [n, 7] normalised least-squares residual of Eq. 5
    joint_angles: np.ndarray  # [n, 3] OpenSim ankle, knee, hip angles (rad)
    joint_rates: np.ndarray   # [n, 3] their rates (rad/s)


class Stage1Stream:
    """Stage 1 run in step with the data (one trial; ``reset`` starts the next).

    ``conditioning`` (live): the settings of the fixed-lag conditioner the stream owns
    (default: 100 ms look-ahead); or ``conditioner``: one that is fed elsewhere, or the
    offline conditioned observations of a whole recording (batch). ``start``: the tracked
    model's state at t = 0 when it is known otherwise (e.g. a trial that starts in flight,
    from the measured ankle position); None: ``initial_state`` from the observations.
    """

    def __init__(self, model: JumperModel, settings: SKTSettings | None = None,
                 conditioning: ConditioningSettings | None = None, *,
                 conditioner: ConditionedObservations | FixedLagConditioner | None = None,
                 angle_rate_hz: float = 120.0, wrench_rate_hz: float = 1080.0,
                 block: int = 27, start: SKTState | None = None) -> None:
        if conditioner is not None and conditioning is not None:
            raise ValueError('Stage1Stream takes conditioning settings (it builds its '
                             'conditioner) or a conditioner, not both')
        if conditioner is None:
            conditioning = (conditioning if conditioning is not None
                            else ConditioningSettings(lookahead_s=0.1))
            if conditioning.lookahead_s is None:
                raise ValueError('Stage1Stream needs conditioning.lookahead_s')
        self.model = model
        self.settings = settings if settings is not None else SKTSettings()
        self.conditioning = conditioning
        self.angle_rate_hz = angle_rate_hz
        self.rate_hz = wrench_rate_hz
        self.block = block
        self.tracker = SkeletalTracker(model, self.settings, wrench_rate_hz)
        self._given = conditioner
        self._start = start
        self.reset()

    def reset(self) -> None:
        """Start a trial: a fresh conditioner (unless one was given) and tracker state."""
        self.conditioner = (self._given if self._given is not None else FixedLagConditioner(
            self.conditioning, self.angle_rate_hz, self.rate_hz))
        self.state: SKTState | None = None
        self.done = 0                 # output samples integrated past t = 0
        self.status = 'ok'            # 'ok' | 'lost_control'
        self.events: list[dict] = []
        self.ended_s: float | None = None   # trial time where tracking ended in flight
        self._liftoff = LiftoffDetector(self.settings.liftoff_force_bw
                                        * self.model.p.body_weight)
        self.finished = False

    @property
    def final_until(self) -> float:
        """Latest trial time [s] whose conditioned observations are final."""
        return self.conditioner.final_until()

    def add_angles(self, t: float, theta: np.ndarray) -> None:
        """One motion-capture sample: segment angles theta [4] (rad) at trial time t [s]."""
        self.conditioner.add_angles(t, theta)

    def add_wrench(self, t: float, s: np.ndarray) -> None:
        """One force-plate sample: Fx, Fy (N), Mz (N m) at trial time t [s]."""
        self.conditioner.add_wrench(t, s)

    def poll(self, t_end: float | None = None) -> Stage1Output | None:
        """Outputs that became final since the last call, up to ``t_end`` [s] if given
        (None if none)."""
        if self.finished:
            return None
        return self._advance(t_end)

    def finish(self) -> Stage1Output | None:
        """End of the trial: step to the last sample common to both streams."""
        if self.finished:
            return None
        self.finished = True
        if self.status != 'ok':
            return None
        if isinstance(self.conditioner, FixedLagConditioner):
            self.conditioner.close()   # end of data: every remaining instant becomes final
        return self._advance(None)

    def _flight_end(self, t_blk: np.ndarray, fy: np.ndarray) -> int | None:
        """Index in the block after which tracking ends (flight_tracking_s after the sample
        at which the tracked model's lift-off became known), or None."""
        st = self.settings
        if st.flight_tracking_s is None:
            return None
        self._liftoff.update(t_blk, fy)
        late = np.flatnonzero(t_blk > self._liftoff.known_s + st.flight_tracking_s)
        return int(late[0]) if late.size else None

    def _advance(self, t_end: float | None) -> Stage1Output | None:
        """Step over every output sample the data now allow; their outputs (None if none)."""
        if self.status != 'ok' or self.ended_s is not None:
            return None
        tracker = self.tracker
        final = self.conditioner.final_until()
        if t_end is not None:
            final = min(final, t_end)
        chunks, times = [], []
        if self.state is None:
            if final < 0.0:
                return None
            ref0 = reference_arrays(self.conditioner, np.array([0.0]))[0]
            self.state = (initial_state(self.model, ref0, self.settings)
                          if self._start is None else replace(self._start, t=0.0))
            q0 = np.concatenate([self.state.q, self.state.qd])
            first = tracker.outputs([(q0, 0.0, ref0)], self.state.x0)
            ev = tracker.check_control(first, np.array([0.0]))
            if ev:
                self.events = [{**e, 'reason': 'no consistent initial state: ' + e['reason']}
                               for e in ev]
                self.status = 'lost_control'
                return None
            chunks.append(first)
            times.append(np.array([0.0]))
        n_final = int(np.floor(final * self.rate_hz + 1e-9))
        while self.done < n_final and self.status == 'ok' and self.ended_s is None:
            n = min(self.block, n_final - self.done)
            refs = reference_arrays(self.conditioner,
                                    tracker.fine_times(self.done / self.rate_hz, n))
            self.state, out = tracker.advance(self.state, refs)
            t_blk = (self.done + 1 + np.arange(n)) / self.rate_hz
            self.done += n
            end = self._flight_end(t_blk, out['y'][:, 5])
            if end is not None:   # in flight past the tracked window: stop, status stays ok
                self.ended_s = float(t_blk[end])
                out = {k: v[:end] for k, v in out.items()}
                t_blk = t_blk[:end]
            ev = tracker.check_control(out, t_blk)
            if ev:
                self.events = ev
                self.status = 'lost_control'
                # Keep only the samples before the first event: the rest has diverged.
                keep = t_blk < min(e['t'] for e in ev) - 1e-12
                out = {k: v[keep] for k, v in out.items()}
                t_blk = t_blk[keep]
            chunks.append(out)
            times.append(t_blk)
        if not chunks:
            return None
        cat = {k: np.concatenate([c[k] for c in chunks])
               for k in ('Q', 'qdd', 'tau', 'y', 'b', 'residual')}
        m = self.model
        q, qd = cat['Q'][:, :6], cat['Q'][:, 6:]
        if q.shape[0]:
            joint_angles, = m.batch(m.joint_angles, q)
            joint_rates, = m.batch(m.joint_angles, qd)   # linear in q: the same map for rates
        else:   # the block ended at its first sample (flight or loss of control)
            joint_angles = joint_rates = np.zeros((0, 3))
        return Stage1Output(t=np.concatenate(times), q=q, qd=qd, qdd=cat['qdd'],
                            tau=cat['tau'], s=cat['y'][:, 4:7], bias=cat['b'],
                            residual=cat['residual'], joint_angles=joint_angles,
                            joint_rates=joint_rates)


def track_stage1(model: JumperModel, cond: ConditionedObservations,
                 settings: SKTSettings | None = None, rate_hz: float = 1080.0,
                 t_end: float | None = None, block: int = 27,
                 start: SKTState | None = None) -> SKTResult:
    """Batch Stage 1 over the whole recording: :class:`Stage1Stream` fed every sample.

    Output samples are at k / rate_hz (the force-plate instants). Stops at the first loss of
    control and reports it (status 'lost_control', events) with the outputs so far.
    ``start``: the initial state when known (see :class:`Stage1Stream`).
    """
    c0 = time.process_time()
    settings = settings if settings is not None else SKTSettings()
    stream = Stage1Stream(model, settings, conditioner=cond, wrench_rate_hz=rate_hz,
                          block=block, start=start)
    out = stream.poll(t_end)
    if out is None:  # lost at the start: an empty result that says why
        empty = np.zeros((0, 6))
        return SKTResult(t=np.zeros(0), q=empty, qd=empty, qdd=empty, tau=np.zeros((0, 3)),
                         s=np.zeros((0, 3)), bias=np.zeros(0), residual=np.zeros((0, 7)),
                         x0=np.zeros(2), status=stream.status, events=stream.events,
                         cpu_s=time.process_time() - c0)
    res = SKTResult(t=out.t, q=out.q, qd=out.qd, qdd=out.qdd, tau=out.tau, s=out.s,
                    bias=out.bias, residual=out.residual, x0=stream.state.x0,
                    status=stream.status, events=stream.events,
                    cpu_s=time.process_time() - c0)
    res.liftoff_s = liftoff_time(res.t, res.s[:, 1],
                                 settings.liftoff_force_bw * model.p.body_weight)
    return res


# --------------------------------------------------------------------------- Stage 2

@dataclass(frozen=True)
class Stage2Output:
    """Stage-2 outputs at input samples: stamps, trial times and [n, 9] arrays."""

    stamp_ns: np.ndarray   # [n] int64, the input samples' stamps
    t: np.ndarray          # [n]
    f: np.ndarray          # [n, 9] musculotendon forces (N)
    a: np.ndarray          # [n, 9] activations
    u: np.ndarray          # [n, 9] excitations (applied, held over the next interval)
    l_mt: np.ndarray       # [n, 9] musculotendon lengths (m)
    v_mt: np.ndarray       # [n, 9] lengthening speeds (m/s)
    saturated: np.ndarray  # [n, 9] bool


def initial_activations(model: JumperModel, theta: np.ndarray, tau: np.ndarray,
                        theta_dot: np.ndarray | None = None) -> tuple[np.ndarray, str | None]:
    """(a0[9], problem): the activations that produce the first torque sample tau [3] (N m)
    at joint angles theta [3] (rad) (``nmt_ros.model.squat.rest_activations``); ``problem``
    says when they only approximate it (bounded least squares) or could not be computed
    (zeros then)."""
    try:
        rest = rest_activations(model, theta, tau, theta_dot)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return np.zeros(len(model.p.muscles.names)), f'initial activations: {exc}; using 0'
    if not rest.exact:
        return rest.a, ('initial activations reproduce the first torque sample only '
                        f'approximately (residual {np.round(rest.residual, 2).tolist()} N m)')
    return rest.a, None


class Decimator:
    """Thins a time-ordered stream of instants to at most ``rate_hz``: an instant is kept
    when it is the first of its period [k / rate_hz, (k + 1) / rate_hz) of trial time. A
    function of the instants alone (the same output however they are split into blocks),
    and a stream at any rate keeps one instant per period (data at 100 Hz thinned to 120 Hz
    keep every instant; at 1080 Hz, the multiples of 1/120 s)."""

    def __init__(self, rate_hz: float) -> None:
        if not rate_hz > 0:
            raise ValueError(f'decimation rate must be positive, not {rate_hz!r} Hz')
        self.rate_hz = float(rate_hz)
        self.last_period = -np.inf        # period index of the last kept instant

    def keep(self, t: np.ndarray) -> np.ndarray:
        """Mask [n] of the instants t [n] s (increasing, after those seen before) kept."""
        k = np.floor(np.asarray(t, dtype=float) * self.rate_hz + 1e-6)
        prev = np.concatenate([[self.last_period], k[:-1]])
        mask = k > prev
        if k.size:
            self.last_period = max(self.last_period, float(k[-1]))
        return mask


def snap_to_grid(t: float, rate_hz: float) -> float:
    """Trial time t [s] snapped to the nominal sample grid k / rate_hz."""
    return round(t * rate_hz) / rate_hz


class Stage2Stream:
    """Receding-horizon Stage 2 fed Stage-1 samples on a uniform grid (one trial)."""

    def __init__(self, model: JumperModel, tracker: NeuromuscularTracker | None = None,
                 window_length_s: float = 0.1, window_stride_s: float | None = 0.005,
                 rate_hz: float = 1080.0) -> None:
        self.model = model
        self.tracker = tracker if tracker is not None else NeuromuscularTracker(model)
        self.window_length_s = window_length_s
        self.window_stride_s = window_stride_s
        self.rate_hz = rate_hz
        th, thd = ca.SX.sym('theta', 3), ca.SX.sym('theta_dot', 3)
        self._kinematics = compiled(ca.Function(
            'stage2_output_kinematics', [th, thd],
            [model.musculotendon_lengths(th), model.musculotendon_velocities(th, thd)]))
        self.reset()

    def warm_up(self) -> None:
        """Run a short stream (standing still, no torque) through a copy of this stream: the
        compiled kernels load (or compile, on a machine without their cache: about a minute)
        and the CasADi maps of its block sizes are made now, not in a trial's first windows."""
        copy = Stage2Stream(self.model, self.tracker, self.window_length_s,
                            self.window_stride_s, self.rate_hz)
        n = int(np.ceil((3 * self.window_length_s + 0.05) * self.rate_hz)) + 2
        zero = np.zeros(3)
        for k in range(n):
            copy.add(k, k / self.rate_hz, zero, zero, zero)
            copy.process()
        copy.process(final=True)

    def reset(self) -> None:
        """Start a trial."""
        self.state: StreamState | None = None
        self.pending: list[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._prev: tuple[float, np.ndarray] | None = None   # last pushed (t, theta_dot)
        self._pushed: deque[tuple[int, float, np.ndarray, np.ndarray]] = deque()
        self.a0: np.ndarray | None = None
        self.problem: str | None = None
        self.finished = False
        self._n_pushed = 0

    def add(self, stamp_ns: int, t: float, tau: np.ndarray, theta: np.ndarray,
            theta_dot: np.ndarray) -> None:
        """Queue one sample (processed by the next ``process``): joint torques tau [3] (N m),
        joint angles theta [3] (rad) and rates theta_dot [3] (rad/s) at trial time t [s]
        (snapped to the grid k / rate_hz), stamped ``stamp_ns``."""
        self.pending.append((int(stamp_ns), snap_to_grid(float(t), self.rate_hz),
                             np.asarray(tau, dtype=float), np.asarray(theta, dtype=float),
                             np.asarray(theta_dot, dtype=float)))

    def _accelerations(self, rows: list) -> np.ndarray:
        """theta_ddot [n, 3] of ``rows``: central differences of theta_dot, one-sided at the
        ends of the trial (the previous pushed sample and the next queued one are used)."""
        t = [r[1] for r in rows]
        v = [r[4] for r in rows]
        first = 0
        if self._prev is not None:
            t.insert(0, self._prev[0])
            v.insert(0, self._prev[1])
            first = 1
        if len(self.pending) > len(rows):
            nxt = self.pending[len(rows)]
            t.append(nxt[1])
            v.append(nxt[4])
        t, v = np.array(t), np.array(v)
        acc = np.zeros((len(rows), 3))
        if t.size < 2:
            return acc
        for i in range(len(rows)):
            j = i + first
            lo, hi = max(j - 1, 0), min(j + 1, t.size - 1)
            acc[i] = (v[hi] - v[lo]) / (t[hi] - t[lo])
        return acc

    def process(self, final: bool = False) -> Stage2Output | None:
        """Push the queued samples that complete windows (all of them if ``final``); the new
        outputs or None.

        Work is cut by data, never by when ``process`` is called: the samples are pushed in
        blocks that end exactly where the next window's look-ahead ends
        (``stage2.streaming.samples_for_next_window``; the sample after a block must be
        queued too, for the last one's acceleration), one block per window, the first block
        a window long. Called after every sample or once a minute, on an idle or a loaded
        machine, the stream makes the same pushes and gives the same outputs bit for bit.
        """
        if self.finished:
            return None
        steps = []
        while self.pending:
            if self.state is None:
                _, _, tau, theta, thd = self.pending[0]
                self.a0, self.problem = initial_activations(self.model, theta, tau, thd)
                self.state = self.tracker.start_stream(self.a0, 1.0 / self.rate_hz)
            if final:
                n = len(self.pending)
            else:
                n = samples_for_next_window(self.state, self._window()[0]) - self._n_pushed
                if len(self.pending) <= n:
                    break
            steps += self._push(n, final)
            if final:
                break
        if final:
            self.finished = True
        if self.state is None or (not steps and not final):
            return None
        return self._collect(steps, final)

    def _window(self) -> tuple[int, int]:
        """(window length, stride) in intervals of the stream's internal grid."""
        sub = self.state.substeps
        return self.tracker.planner.window_intervals(1.0 / (self.rate_hz * sub), sub,
                                                     self.window_length_s,
                                                     self.window_stride_s)

    def _push(self, n: int, final: bool) -> list:
        """Push the first n queued samples to Stage 2; its new steps."""
        rows = self.pending[:n]
        acc = self._accelerations(rows)
        self.pending = self.pending[n:]
        self._n_pushed += n
        stamps = np.array([r[0] for r in rows], dtype=np.int64)
        t = np.array([r[1] for r in rows])
        tau = np.array([r[2] for r in rows])
        theta = np.array([r[3] for r in rows])
        thd = np.array([r[4] for r in rows])
        self._prev = (float(t[-1]), thd[-1].copy())
        for i in range(n):
            self._pushed.append((int(stamps[i]), float(t[i]), theta[i], thd[i]))
        self.state, steps = self.tracker.push(self.state, t, tau, theta, thd, acc, final=final,
                                              window_length=self.window_length_s,
                                              window_stride=self.window_stride_s)
        return steps

    def _collect(self, steps: list, final: bool) -> Stage2Output | None:
        """Output rows at input samples (every ``substeps``-th internal row)."""
        rows_t, f, a, u, sat = [], [], [], [], []
        sub = self.state.substeps
        for step in steps:
            index = step.start + np.arange(step.t.size)
            keep = index % sub == 0
            rows_t.append(step.t[keep])
            f.append(step.f[keep])
            a.append(step.a[keep])
            u.append(step.u[keep])
            sat.append(step.saturated[keep])
        if final and self.state.muscle is not None and self._pushed:
            # the last sample: the state the last step ended in (the batch 'assemble' row)
            m = self.state.muscle
            last_t = self._pushed[-1][1]
            if abs(m.t - last_t) < 1e-9 and (not rows_t or not rows_t[-1].size
                                             or rows_t[-1][-1] < last_t - 1e-9):
                rows_t.append(np.array([m.t]))
                f.append(m.f[None])
                a.append(m.a[None])
                u.append(u[-1][-1:] if u and u[-1].size else np.zeros((1, m.a.size)))
                sat.append(np.zeros((1, m.a.size), dtype=bool))
        if not rows_t:
            return None
        t_out = np.concatenate(rows_t)
        if t_out.size == 0:
            return None
        stamps, theta, thd = [], [], []
        for tt in t_out:
            while self._pushed and self._pushed[0][1] < tt - 1e-9:
                self._pushed.popleft()
            if not self._pushed or abs(self._pushed[0][1] - tt) > 1e-9:
                raise RuntimeError(f'Stage 2 output at t = {tt:.6f} s matches no input sample')
            s, _, th, v = self._pushed.popleft()
            stamps.append(s)
            theta.append(th)
            thd.append(v)
        theta, thd = np.array(theta), np.array(thd)
        l_mt, v_mt = self.model.batch(self._kinematics, theta, thd)
        return Stage2Output(stamp_ns=np.array(stamps, dtype=np.int64), t=t_out,
                            f=np.vstack(f), a=np.vstack(a), u=np.vstack(u), l_mt=l_mt,
                            v_mt=v_mt, saturated=np.vstack(sat))


def track_stage2(model: JumperModel, t: np.ndarray, tau: np.ndarray, theta: np.ndarray,
                 theta_dot: np.ndarray, tracker: NeuromuscularTracker | None = None,
                 window_length_s: float = 0.1, window_stride_s: float | None = 0.01,
                 rate_hz: float = 1080.0, max_gap_s: float = 0.5,
                 chunk_s: float = 0.05) -> Stage2Result:
    """Batch Stage 2 = the live one: :class:`Stage2Stream` fed a Stage-1 record (joint
    torques tau, angles theta and rates theta_dot [n, 3] at times t [n], on the grid
    k / rate_hz, gaps allowed) in chunks of ``chunk_s``. A gap longer than ``max_gap_s``
    ends a trial (the next sample starts one, as in the node); shorter ones are filled by
    linear interpolation on the grid (as the node's input gate does). Returns the muscles on
    the grid instants they cover."""
    tracker = tracker if tracker is not None else NeuromuscularTracker(model)
    t = np.asarray(t, dtype=float)
    k = np.rint(t * rate_hz).astype(np.int64)
    cuts = np.nonzero(np.diff(t) > max_gap_s)[0] + 1
    parts = []
    for seg in np.split(np.arange(t.size), cuts):
        grid = np.arange(k[seg[0]], k[seg[-1]] + 1)
        tg = grid / rate_hz
        parts.append((tg, *(np.column_stack([np.interp(tg, t[seg], x[seg, j])
                                             for j in range(x.shape[1])])
                            for x in (tau, theta, theta_dot))))
    t = np.concatenate([p[0] for p in parts])
    tau, theta, theta_dot = (np.concatenate([p[i] for p in parts]) for i in (1, 2, 3))
    cuts = np.cumsum([p[0].size for p in parts])[:-1]
    outs: list[Stage2Output] = []
    c0 = time.process_time()
    for seg in np.split(np.arange(t.size), cuts):
        if seg.size < 2:
            continue
        stream = Stage2Stream(model, tracker, window_length_s, window_stride_s, rate_hz)
        next_chunk = t[seg[0]] + chunk_s
        for i in seg:
            stream.add(int(round(t[i] * 1e9)), t[i], tau[i], theta[i], theta_dot[i])
            if t[i] >= next_chunk:
                out = stream.process()
                next_chunk = t[i] + chunk_s
                if out is not None:
                    outs.append(out)
        out = stream.process(final=True)
        if out is not None:
            outs.append(out)
    cpu = time.process_time() - c0
    names = tuple(model.p.muscles.names)
    if not outs:
        raise ValueError('Stage 2 produced no output (fewer than two Stage-1 samples)')
    cat = {f: np.concatenate([getattr(o, f) for o in outs]) for f in ('t', 'f', 'a', 'u')}
    k = np.clip(np.searchsorted(t, cat['t'] - 1e-9), 0, t.size - 1)
    C, = model.batch(model.moment_arm_matrix, theta[k])
    m = len(names)
    return Stage2Result(
        mode='streamed', names=names, t=cat['t'], f=cat['f'], a=cat['a'], u=cat['u'],
        u_demand=cat['u'], eta=np.zeros_like(cat['f']), tau_ref=tau[k],
        tau_muscle=np.einsum('nij,nj->ni', C, cat['f']), W=np.zeros((cat['t'].size, 0, m)),
        g=np.zeros((cat['t'].size, 0)), cpu_s={'total': cpu}, window_length=window_length_s,
        window_stride=window_stride_s)
