"""The trackers' streaming state, without ROS: what a node feeds and what it gets back.

:class:`Stage1Runner` owns a :class:`~nmt_ros.tracking.conditioning.FixedLagConditioner`
and a :class:`~nmt_ros.tracking.skeletal_tracker.Stage1Stream` (the same stepping code as the
batch ``track``). Samples go in with ``add_angles`` / ``add_wrench``; ``poll`` returns the
outputs that became final (data up to ``t + lookahead_s`` arrived). ``finish`` ends the
trial: the conditioner's last window is filtered as a whole (exactly what the fixed-lag
filter computes when no look-ahead is missing, i.e. the offline filter on that window) and
the tracker is stepped to the last common sample.

:class:`Stage2Runner` feeds Stage-1 joint torques and kinematics to the receding-horizon
Stage 2 (``NeuromuscularTracker.push``). Joint accelerations are not published by the
skeletal tracker: they are central differences of the joint rates here (one sample, 0.9 ms,
of delay). With inputs at 1080 Hz Stage 2 needs no internal substeps, and there the
accelerations only enter the reported (unclipped) Eq. 9 excitation, not the forces.
Initial activations: ``nmt_ros.model.squat.rest_activations`` for the first
torque sample (the live node has no truth).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.tracking.conditioning import (
    ConditioningSettings,
    FixedLagConditioner,
)
from nmt_ros.tracking.neuromuscular_tracker import NeuromuscularTracker, StreamState
from nmt_ros.tracking.skeletal_tracker import SKTSettings, Stage1Stream

# --------------------------------------------------------------------------- Stage 1

@dataclass(frozen=True)
class Stage1Output:
    """Stage-1 outputs at the force-plate instants ``t`` (trial time, s)."""

    t: np.ndarray          # [n]
    q: np.ndarray          # [n, 6]
    qd: np.ndarray         # [n, 6]
    qdd: np.ndarray        # [n, 6]
    tau: np.ndarray        # [n, 3] ankle, knee, hip (N m)
    s: np.ndarray          # [n, 3] synthesised ground wrench Fx, Fy, Mz
    bias: np.ndarray       # [n] moment-bias estimate


def _stage1_output(out: dict) -> Stage1Output:
    Q = out['Q']
    return Stage1Output(t=out['t'], q=Q[:, :6], qd=Q[:, 6:], qdd=out['qdd'], tau=out['tau'],
                        s=out['y'][:, 4:7], bias=out['b'])


class Stage1Runner:
    """Stage 1 fed sample by sample (one trial; ``reset`` starts the next)."""

    def __init__(self, model: JumperModel, skt: SKTSettings | None = None,
                 conditioning: ConditioningSettings | None = None,
                 angle_rate_hz: float = 120.0, wrench_rate_hz: float = 1080.0) -> None:
        skt = skt if skt is not None else SKTSettings()
        conditioning = (conditioning if conditioning is not None
                        else ConditioningSettings(lookahead_s=0.1))
        if conditioning.lookahead_s is None:
            raise ValueError('Stage1Runner needs conditioning.lookahead_s')
        self.model = model
        self.skt = skt
        self.conditioning = conditioning
        self.angle_rate_hz = angle_rate_hz
        self.wrench_rate_hz = wrench_rate_hz
        self.reset()

    def reset(self) -> None:
        cs = self.conditioning
        self.conditioner = FixedLagConditioner(cs, self.angle_rate_hz, self.wrench_rate_hz)
        self.stream = Stage1Stream(self.model, self.conditioner, self.skt, self.wrench_rate_hz)
        self.finished = False

    @property
    def status(self) -> str:
        return self.stream.status

    @property
    def events(self) -> list[dict]:
        return self.stream.events

    @property
    def final_until(self) -> float:
        return self.conditioner.final_until()

    def add_angles(self, t: float, theta: np.ndarray) -> None:
        self.conditioner.add_angles(t, theta)

    def add_wrench(self, t: float, s: np.ndarray) -> None:
        self.conditioner.add_wrench(t, s)

    def poll(self) -> Stage1Output | None:
        """Outputs that became final since the last call (None if none)."""
        if self.finished:
            return None
        out = self.stream.poll()
        return None if out is None else _stage1_output(out)

    def finish(self) -> Stage1Output | None:
        """End of the trial: step to the last sample common to both streams."""
        if self.finished:
            return None
        self.finished = True
        if self.stream.status != 'ok':
            return None
        self.conditioner.close()   # end of data: every remaining instant becomes final
        out = self.stream.poll()
        return None if out is None else _stage1_output(out)


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
    """(a0[9], problem): the activations that produce the first torque sample
    (``nmt_ros.model.squat.rest_activations``); ``problem`` says when they only
    approximate it (bounded least squares) or could not be computed (zeros then)."""
    from nmt_ros.model.squat import rest_activations

    try:
        rest = rest_activations(model, theta, tau, theta_dot)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return np.zeros(len(model.p.muscles.names)), f'initial activations: {exc}; using 0'
    if not rest.exact:
        return rest.a, ('initial activations reproduce the first torque sample only '
                        f'approximately (residual {np.round(rest.residual, 2).tolist()} N m)')
    return rest.a, None


class Stage2Runner:
    """Receding-horizon Stage 2 fed Stage-1 samples on a uniform grid (one trial)."""

    def __init__(self, model: JumperModel, tracker: NeuromuscularTracker | None = None,
                 window_length_s: float = 0.1, window_stride_s: float | None = 0.005,
                 rate_hz: float = 1080.0) -> None:
        self.model = model
        self.tracker = tracker if tracker is not None else NeuromuscularTracker(model)
        self.window_length_s = window_length_s
        self.window_stride_s = window_stride_s
        self.rate_hz = rate_hz
        self.reset()

    def reset(self) -> None:
        self.state: StreamState | None = None
        self.pending: list[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._prev: tuple[float, np.ndarray] | None = None   # last pushed (t, theta_dot)
        self._pushed: deque[tuple[int, float, np.ndarray, np.ndarray]] = deque()
        self.a0: np.ndarray | None = None
        self.problem: str | None = None
        self.finished = False

    def add(self, stamp_ns: int, t: float, tau: np.ndarray, theta: np.ndarray,
            theta_dot: np.ndarray) -> None:
        """Queue one sample (processed by the next ``process``)."""
        self.pending.append((int(stamp_ns), float(t), np.asarray(tau, dtype=float),
                             np.asarray(theta, dtype=float), np.asarray(theta_dot, dtype=float)))

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
        """Push the queued samples (all but the last unless ``final``); new outputs or None."""
        if self.finished:
            return None
        n = len(self.pending) if final else len(self.pending) - 1
        if n <= 0:
            if final:
                self.finished = True
            return None
        rows = self.pending[:n]
        acc = self._accelerations(rows)
        self.pending = self.pending[n:]
        stamps = np.array([r[0] for r in rows], dtype=np.int64)
        t = np.array([r[1] for r in rows])
        tau = np.array([r[2] for r in rows])
        theta = np.array([r[3] for r in rows])
        thd = np.array([r[4] for r in rows])
        self._prev = (float(t[-1]), thd[-1].copy())
        tr = self.tracker
        if self.state is None:
            self.a0, self.problem = initial_activations(self.model, theta[0], tau[0], thd[0])
            self.state = tr.start_stream(self.a0, 1.0 / self.rate_hz)
        for i in range(n):
            self._pushed.append((int(stamps[i]), float(t[i]), theta[i], thd[i]))
        self.state, steps = tr.push(self.state, t, tau, theta, thd, acc, final=final,
                                    window_length=self.window_length_s,
                                    window_stride=self.window_stride_s)
        if final:
            self.finished = True
        return self._collect(steps, final)

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
        m = self.model
        l_mt, = m.batch(m.musculotendon_lengths, theta)
        v_mt, = m.batch(m.musculotendon_velocities, theta, thd)
        return Stage2Output(stamp_ns=np.array(stamps, dtype=np.int64), t=t_out,
                            f=np.vstack(f), a=np.vstack(a), u=np.vstack(u), l_mt=l_mt,
                            v_mt=v_mt, saturated=np.vstack(sat))
