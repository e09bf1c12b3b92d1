"""The moving-horizon estimator: Stage 1 live and offline, muscle-driven, with a fixed lag.

Fed the raw samples of both streams in time order (``add_angles``, ``add_wrench``), it runs
one update per 1 / update_rate_hz of DATA time, once both streams have reached that instant
(or one stream is ``max_wait_s`` ahead of the other: a stalled stream is not waited for).
Every decision depends on sample times and values only, never on the wall clock, so the
estimates are a function of the input stream (the same offline, live at 1x or 4x, loaded or
not). An update extends the window's splines to the new data, takes ``iterations``
Levenberg-Marquardt steps on the whole window (``window.SlidingWindow``) and marginalises what
fell out of it into the arrival cost. Each update emits, for every force-plate instant:

* a low-latency estimate once the update covering it has run (as causal as the method is:
  the window's newest end), and
* the refined estimate once data ``lag_s`` past it has been used.

Start: once ``start_window_s`` of data arrived, the window is initialised from the data
(filtered angles, the ankle height the vertical force implies, the ground wrench, activations
from inverse dynamics + static optimisation made feasible for Eq. 8a) and solved with a
continuation on the dynamics' weight (a stream that begins in the air: once it has landed,
on all of its data, ``_awaiting_landing``). Loss of control (the newest data no longer explained,
non-finite numbers, a singular step, an emitted span far from its own mocap samples) is
detected, reported and followed by the same initialisation from the newest data.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
import time

import numpy as np

from nmt_ros.model.compiled import compiled
from nmt_ros.model.contact import liftoff_time
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.point_map import PointMap
from nmt_ros.model.squat import rest_activations
from nmt_ros.records import SKTResult
from nmt_ros.tracking.frame_clock import FrameClock
from nmt_ros.tracking.moving_horizon import normal_equations, window
from nmt_ros.tracking.moving_horizon.point_functions import excitation, output_function
from nmt_ros.tracking.moving_horizon.residuals import LAYOUT, NV, NX, PLATE
from nmt_ros.tracking.moving_horizon.segment_kernel import KernelSpec, SegmentKernel, capacity
from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings
from nmt_ros.tracking.moving_horizon.spline import KnotGrid, evaluate
from nmt_ros.tracking.moving_horizon.window import SlidingWindow
from nmt_ros.tracking.observation_noise import OBSERVATION_NOISE
from nmt_ros.tracking.plate_saturation import CHANNELS, PlateSaturation


@dataclass
class EstimateBlock:
    """Estimates at instants t [n] (trial time, s) of one kind ('refined' | 'low_latency')."""

    kind: str
    t: np.ndarray
    q: np.ndarray           # [n, 6] rad, m
    qd: np.ndarray          # [n, 6]
    qdd: np.ndarray         # [n, 6]
    tau: np.ndarray         # [n, 3] N m: joint torques (ankle, knee, hip), settings.joint_torques
    tau_muscle: np.ndarray  # [n, 3] N m: the muscles' joint torques
    theta: np.ndarray       # [n, 3] rad: joint angles (ankle_angle, knee_angle, hip_flexion)
    theta_dot: np.ndarray   # [n, 3] rad/s
    f: np.ndarray           # [n, 9] N: musculotendon forces
    a: np.ndarray           # [n, 9]
    u: np.ndarray           # [n, 9] excitations (Eq. 8a inverted)
    s: np.ndarray           # [n, 3] estimated ground wrench (N, N, N m about the foot COM)
    plate: np.ndarray       # [NX] the force plate's error model (residuals.PLATE)

    def part(self, kind: str, rows: slice) -> EstimateBlock:
        """The rows ``rows`` as a block of ``kind``."""
        return EstimateBlock(kind=kind, plate=self.plate,
                             **{f: getattr(self, f)[rows] for f in BLOCK_FIELDS})


BLOCK_FIELDS = ('t', 'q', 'qd', 'qdd', 'tau', 'tau_muscle', 'theta', 'theta_dot', 'f', 'a', 'u',
                's')
#: The pull of a refit foot's control points to their current values (``_reseed_foot``),
#: against the spline basis' squared weights (~0.5 per mocap sample near a control point):
#: it decides only the points no sample reaches.
RESEED_PULL = 0.01


@dataclass
class EstimatorEvent:
    """Something the status should say: level 'info' | 'warn' | 'error', data time t [s]."""

    level: str
    t: float
    message: str
    values: dict = field(default_factory=dict)


class MovingHorizonEstimator:
    """Streaming Stage 1 (see the module docstring). One object per trial."""

    def __init__(self, model: JumperModel, settings: MovingHorizonSettings | None = None,
                 max_wait_s: float = 0.3) -> None:
        """``max_wait_s`` [s of data]: how far one stream may run ahead before an update
        goes on without the other (a stalled stream). It must exceed the skew with which a
        live node receives the two streams: at 0.1 s a node on a loaded machine rejected
        3-100 mocap samples per minute as 'too late' (a replay that bursts after a stall
        delivers 0.1 s of force-plate samples between two takes of the mocap topic)."""
        self.model = model
        self.settings = st = settings if settings is not None else MovingHorizonSettings()
        st.validate()
        bw = model.p.body_weight
        m = model.p.muscles
        mass_diag = np.diag(np.asarray(model.mass_matrix(np.zeros(6))))
        self.kernel_spec = KernelSpec(
            angle_capacity=capacity(st.angle_rate_hz, st.knot_rate_hz),
            wrench_capacity=capacity(st.wrench_rate_hz, st.knot_rate_hz),
            dt=1.0 / st.knot_rate_hz, angle_sd=tuple(st.angle_sd()),
            wrench_sd=tuple(st.wrench_sd(bw)), huber_k=st.huber_k,
            sd_dyn=tuple(np.maximum(st.dynamics_sd * mass_diag, st.dynamics_sd_floor)),
            sd_height=st.contact_height_sd_m, sd_slip=st.contact_slip_sd_m_s,
            full_load=st.contact_full_load_bw * bw, free_load=st.contact_free_load_bw * bw,
            stiffness=float(model.p.contact.k_y),
            w_u=st.excitation_weight, w_du=st.excitation_rate_weight, rho=st.bound_weight,
            tau_act=m.tau_act, tau_deact=m.tau_deact,
            wrench_accel_sd=tuple(st.wrench_accel_sd(bw)), share_free=st.share_free,
            full_share=st.contact_full_share, release_sd=st.contact_release_sd,
            support_sd=st.contact_support_sd_m,
            free_foot_sd=float(np.radians(st.free_foot_angle_sd_deg)))
        self.kernel = SegmentKernel(model, self.kernel_spec)
        normal_equations.warm_up()       # the compiled (numba) loops loaded now
        window.warm_up()
        self.outputs = PointMap(compiled(output_function(model)))
        self.plate_sd = np.asarray(st.plate_sd, dtype=float)
        # the highest the ankle can be above its standing height with a contact point on the
        # ground (the foot rotated about its farthest point), plus a margin [m]
        points = np.asarray(model.p.contact.points, dtype=float)
        self.max_loaded_lift_m = (float(np.hypot(points[:, 0], points[:, 1]).max())
                                  - model.ankle_height + st.loaded_lift_margin_m)
        pas = model.p.passive
        self.joint_range = (np.asarray(pas.theta_lower, dtype=float),
                            np.asarray(pas.theta_upper, dtype=float))
        self.plate_drift = np.asarray(st.plate_drift_sd, dtype=float) ** 2
        self.max_wait_s = max_wait_s
        self.period = 1.0 / st.update_rate_hz
        self.grid: KnotGrid | None = None
        self.window: SlidingWindow | None = None
        self.pending_angles: list[tuple[float, np.ndarray]] = []
        self.pending_wrench: list[tuple[float, np.ndarray]] = []
        self.history_angles = spline_history(4)
        self.history_wrench = spline_history(3)
        self.newest = [-np.inf, -np.inf]       # newest angle / wrench sample time
        self.next_update: float | None = None
        self.updated_until = -np.inf           # data time covered by the last update
        self.out_low: list[float] = []         # instants waiting for a low-latency estimate
        self.out_refined: list[float] = []     # instants waiting for the refined estimate
        self.events: list[EstimatorEvent] = []
        self.damping = st.damping
        self.unhealthy_since: float | None = None
        self.round_robin = 0
        self.state = 'waiting'                 # waiting | tracking | finished
        # the first window spans all the data since the stream began (a stream that begins
        # in the air), and whether that was decided (``_awaiting_landing``)
        self.start_from_first = False
        self.start_decided = False
        self.updates = 0
        self.restarts = 0
        self.stride = 1                        # update periods between updates (_stride)
        self.newest_stamp = -np.inf            # newest mocap stamp as received [s]
        self.frame_clock = (FrameClock(1.0 / st.angle_rate_hz, st.frame_clock_alpha)
                            if st.frame_clock_alpha > 0 else None)
        self.jitter_said = False
        self.saturation = (PlateSaturation(st.saturation_min_bw * bw
                                           * np.array([1.0, 1.0, st.moment_lever_m]))
                           if st.saturation_min_bw > 0 else None)

    # ------------------------------------------------------------------ inputs
    def add_angles(self, t: float, theta: np.ndarray) -> None:
        """A mocap sample: segment angles [4] rad stamped at trial time t [s] (NaN =
        occluded), taken at its frame's instant on the camera's frame clock
        (``frame_clock``), ``angle_latency_s`` before the stamp."""
        if t <= self.newest_stamp:
            raise ValueError(f'sample at t = {t:.6f} s is not after the previous one '
                             f'({self.newest_stamp:.6f} s)')
        self.newest_stamp = t
        if self.settings.angle_latency_s:
            t = t - self.settings.angle_latency_s
        if self.frame_clock is not None:
            clock = self.frame_clock
            t = clock.instant(t)
            if not self.jitter_said and clock.frames >= 120 and clock.jitter_rms_ms > 0.1:
                self.jitter_said = True
                what = ('too much to tell frames apart: the stamps are used as received'
                        if clock.passed_through > clock.frames // 2
                        else "the angles are taken at the clock's instants")
                self.events.append(EstimatorEvent(
                    'warn', t, f'mocap stamps jitter {clock.jitter_rms_ms:.2f} ms RMS about a '
                    f'{1 / clock.period_s:.2f} Hz frame clock: {what}',
                    {'stamp_jitter_rms_ms': clock.jitter_rms_ms}))
        self._add(0, t, np.asarray(theta, dtype=float).reshape(4))

    def add_wrench(self, t: float, s: np.ndarray) -> None:
        """A force-plate sample: [Fx, Fy, Mz about the foot COM] at trial time t [s];
        a channel clipped by a saturated amplifier is missing (``plate_saturation``)."""
        y = np.array(s, dtype=float).reshape(3)
        if self.saturation is not None and t > self.newest[1]:
            now, before, begins = self.saturation.check(y)
            if self.saturation.newly_held is not None:
                names = ', '.join(CHANNELS[c] for c in np.flatnonzero(
                    self.saturation.newly_held))
                self.events.append(EstimatorEvent(
                    'info', t, f'force plate {names}: readings repeat exactly at low loads '
                    '(a held or coarsely quantised signal): saturation not looked for there'))
            if (before.any() and self.pending_wrench
                    and self.pending_wrench[-1][0] == self.newest[1]):
                self.pending_wrench[-1][1][before] = np.nan   # the run's first sample
            if now.any():
                if begins:
                    names = ', '.join(f'{CHANNELS[c]} {y[c]:.6g}'
                                      for c in np.flatnonzero(now))
                    self.events.append(EstimatorEvent(
                        'warn', t, f'force plate saturated ({names}: the same reading on '
                        'consecutive samples): taken as missing, bridged by the estimator',
                        {'saturated_samples': int(self.saturation.saturated.sum())}))
                y[now] = np.nan
        self._add(1, t, y)

    def _add(self, k: int, t: float, y: np.ndarray) -> None:
        if t <= self.newest[k]:
            raise ValueError(f'sample at t = {t:.6f} s is not after the previous one '
                             f'({self.newest[k]:.6f} s)')
        if t <= self.updated_until:
            raise ValueError(f'sample at t = {t:.6f} s arrived after the update that covered '
                             f'it (t <= {self.updated_until:.6f} s): too late')
        self.newest[k] = t
        (self.pending_angles if k == 0 else self.pending_wrench).append((float(t), y))
        if k == 1:
            self.out_low.append(float(t))
            self.out_refined.append(float(t))
        if self.grid is None:
            self.grid = KnotGrid(float(t), 1.0 / self.settings.knot_rate_hz)

    def feed(self, t_angles: np.ndarray, angles: np.ndarray, t_wrench: np.ndarray,
             wrench: np.ndarray) -> list[EstimateBlock]:
        """Add the samples of both streams in time order (``time_order``), polling after
        each as a live node that keeps up does; the estimates that became available."""
        blocks: list[EstimateBlock] = []
        for t, k, i in time_order(t_angles, t_wrench):
            if k == 0:
                self.add_angles(t, angles[i])
            else:
                self.add_wrench(t, wrench[i])
            blocks += self.poll()
        return blocks

    # ------------------------------------------------------------------ stepping
    def poll(self) -> list[EstimateBlock]:
        """Run every update the data now allow; the estimates that became available."""
        blocks: list[EstimateBlock] = []
        self._catch_up()
        if self._awaiting_landing():
            return blocks
        while self.state != 'finished':
            t_u = self._next_update_time()
            if t_u is None or not self._ready(t_u):
                break
            blocks += self._update(t_u)
        return blocks

    def _awaiting_landing(self) -> bool:
        """Whether the first window waits for more data (the samples stay pending).

        A stream that begins in the air (its first finite force-plate sample below
        ``contact_full_load_bw``) holds nothing that tells how high the body is or how fast
        it falls until the feet meet the ground: a window started in the air met the landing
        5-15 cm and ~1 m/s off, moved its trajectory that far in one step and lost control
        35 ms after the touchdown (``bags/routine``'s drop: this bag and 13 of 16 noise
        realisations). So the first update waits, up to ``airborne_start_wait_s`` of data,
        for a landing; with one, it comes at the first update time with
        ``airborne_landing_s`` of the landing and its window spans all the data since the
        stream began. Without one the updates run as for any stream, from
        ``start_window_s`` on (the real drop jump's 0.41 s fall from a box, stepped up and
        off at +0.8 m/s: one window over that whole fall started at its landing did not
        converge). Decided once, from the samples alone."""
        st = self.settings
        if self.start_decided or self.grid is None:
            return False
        if st.airborne_start_wait_s <= 0 or self.updates > 0:
            self.start_decided = True
            return False
        t_ref = self.grid.t_ref
        until = t_ref + st.airborne_start_wait_s + 1e-12
        t = np.array([p[0] for p in self.pending_wrench])
        fy = np.array([p[1][1] for p in self.pending_wrench])
        finite = np.isfinite(fy)
        # samples past the wait do not count (however the data arrive, the same decision)
        loaded = finite & (fy > st.contact_full_load_bw * self.model.p.body_weight) & (
            t <= until)
        if finite.any() and loaded[np.argmax(finite)]:     # began on the ground
            self.start_decided = True
            return False
        if loaded.any():                        # landed: start with some of the landing
            first = t_ref + st.start_window_s
            k = np.ceil((t[np.argmax(loaded)] + st.airborne_landing_s - first) / self.period
                        - 1e-9)
            self.next_update = first + max(int(k), 0) * self.period
            self.start_from_first = True
            self.start_decided = True
            return False
        if min(self.newest) < until and max(self.newest) < until + self.max_wait_s:
            return True                         # in the air so far (or no data): wait
        self.start_decided = True               # no landing within the wait
        return False

    def _catch_up(self) -> None:
        """Data waiting for more than ``max_backlog_s`` (a live consumer that fell behind,
        e.g. on a starved machine): skip to the newest data and re-initialise there, saying
        so, instead of falling further behind. Fed sample by sample (offline, or a live
        consumer that keeps up) this never happens."""
        st = self.settings
        if self.window is None or self.next_update is None or st.max_backlog_s <= 0:
            return
        lo = min(self.newest)
        behind = lo - self.next_update
        if behind <= st.max_backlog_s:
            return
        first = self.grid.t_ref + st.start_window_s
        k = int(np.floor((lo - first) / self.period + 1e-9))
        t_new = first + k * self.period
        self._drop_window(self.next_update, f'fell behind the data by {behind:.2f} s (more '
                          f'than max_backlog_s = {st.max_backlog_s:g} s): skipping to t = '
                          f'{t_new:.4f} s and re-initialising there',
                          {'behind_s': float(behind)})
        self.next_update = t_new

    def _stride(self, t_u: float) -> int:
        """Update periods to the next update: 2 while the data wait more than
        ``slow_backlog_s`` beyond this update (a live consumer short of CPU: half the updates,
        every instant still estimated, instead of falling behind to a skip), else 1. The
        updates stay on the grid of ``update_rate_hz``; fed sample by sample (offline, or a
        consumer that keeps up) the stride is always 1."""
        st = self.settings
        waiting = min(self.newest) - t_u
        if (st.slow_backlog_s <= 0 or waiting <= st.slow_backlog_s
                or st.window_s < st.lag_s + 2 * self.period - 1e-12):
            self.stride = 1
            return 1
        if self.stride == 1:
            self.events.append(EstimatorEvent(
                'warn', t_u, f'{waiting:.2f} s of data waiting (more than slow_backlog_s = '
                f'{st.slow_backlog_s:g} s): updating every {2 * self.period * 1e3:.0f} ms '
                'until caught up', {'waiting_s': float(waiting)}))
        self.stride = 2
        return 2

    def finish(self) -> list[EstimateBlock]:
        """End of the data: update to the last sample and emit everything left."""
        blocks: list[EstimateBlock] = []
        last = max(self.newest)
        if not np.isfinite(last) or self.state == 'finished':
            self.state = 'finished'
            return blocks
        while True:
            t_u = self._next_update_time()
            if t_u is None or t_u > last + 1e-12:
                break
            blocks += self._update(t_u)
        if self.updated_until < last - 1e-12:
            blocks += self._update(last)
        if self.window is not None:
            blocks += self._emit(self.updated_until, final=True)
        self.state = 'finished'
        return blocks

    def _next_update_time(self) -> float | None:
        if self.grid is None:
            return None
        if self.next_update is None:
            return self.grid.t_ref + self.settings.start_window_s
        return self.next_update

    def _ready(self, t_u: float) -> bool:
        lo, hi = min(self.newest), max(self.newest)
        return lo >= t_u - 1e-12 or hi >= t_u + self.max_wait_s

    def _take_pending(self, t_u: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        out = []
        for name, k in (('pending_angles', 4), ('pending_wrench', 3)):
            pend = getattr(self, name)
            n = 0
            while n < len(pend) and pend[n][0] <= t_u + 1e-12:
                n += 1
            taken, rest = pend[:n], pend[n:]
            setattr(self, name, rest)
            out.append((np.array([p[0] for p in taken]),
                        np.array([p[1] for p in taken]).reshape(len(taken), k)))
        return tuple(out)

    def _update(self, t_u: float) -> list[EstimateBlock]:
        st = self.settings
        angles, wrench = self._take_pending(t_u)
        keep = max(st.start_window_s,
                   st.airborne_start_wait_s + st.airborne_landing_s + 2 * self.period)
        self.history_angles.add(*angles, keep_after=t_u - keep - 1e-9)
        self.history_wrench.add(*wrench, keep_after=t_u - keep - 1e-9)
        self.updated_until = t_u
        self.next_update = t_u + self.period * self._stride(t_u)
        self.updates += 1
        if self.window is None:
            if not self._start(t_u):
                return []
            return self._emit(t_u)
        w = self.window
        w.extend(self.grid.segment_of(t_u))
        w.add_samples(angles, wrench)
        # where the update's unchecked step begins (None: its steps are checked or kept)
        before_step = ((w.C, w.plate, self.damping)
                       if st.undo_broken_steps and not st.check_steps else None)
        why = self._gauss_newton(t_u, self._to_relinearise(), st.check_steps)
        if why is not None and before_step is not None:
            why = self._undo_step(t_u, before_step, why)
            before_step = None
        iterations = self._rescue_iterations()
        if (why is None and iterations
                and self._newest_cost_per_row() > st.rescue_cost_per_row):
            why = self._gauss_newton(t_u, np.arange(w.first, w.last + 1), True, iterations)
        if why is None and not self._healthy(t_u):
            why = 'the newest observations are no longer explained'
        if why is not None:
            why = self._reseed_foot(t_u, why)
        if why is not None:
            self._drop_window(t_u, f'loss of control: {why}; re-initialising from the newest '
                              'observations')
            if not self._start(t_u):
                return []
            before_step = None
        blocks = self._emit(t_u, undo=None if before_step is None
                            else partial(self._undo_step, t_u, before_step))
        if self.window is not None:
            try:
                self._slide(t_u)
            except np.linalg.LinAlgError as exc:
                # the arrival cost cannot be formed (the marginalised part's normal equations
                # not positive definite): the next update starts again
                self._drop_window(t_u, f'loss of control: marginalisation failed ({exc}); '
                                  're-initialising at the next update')
        return blocks

    def _undo_step(self, t_u: float, before: tuple[np.ndarray, np.ndarray, float],
                   why: str) -> str | None:
        """Take back the update's unchecked Gauss-Newton step (it made the estimate
        unusable: outside the envelope, or estimates that cannot be published) and try the
        rescue's checked Levenberg-Marquardt iterations from where the step began instead;
        why the result is still unusable (None: it is usable). The step changed only the
        control points and plate parameters (the kept linearisations stay valid models), so
        restoring them restores where the update began."""
        w, st = self.window, self.settings
        w.C, w.plate, self.damping = before
        if not st.rescue_iterations:
            return why
        still = self._gauss_newton(t_u, np.arange(w.first, w.last + 1), True,
                                   st.rescue_iterations)
        if still is None:
            self.events.append(EstimatorEvent(
                'warn', t_u, f"the update's step taken back ({why}): checked iterations "
                'instead', {}))
        return still

    def _reseed_foot(self, t_u: float, why: str) -> str | None:
        """Before a loss of control (``why``): a window whose foot alone has left the mocap
        (at least ``reseed_foot_deg`` from one of the window's samples, every other segment
        within that) has its foot's control points refit to the window's mocap foot angles
        (least squares on the spline's basis, a light pull to the current points where
        samples are few) and ``reseed_iterations`` checked Levenberg-Marquardt iterations on
        the whole window, which re-linearise the contact's held weights from the refit foot.
        Returns why the window is still unusable (None: it is usable), ``why`` itself when
        it was not refit."""
        st, w = self.settings, self.window
        if st.reseed_foot_deg <= 0 or w is None:
            return why
        rows = np.flatnonzero(np.isfinite(w.angles.y).all(axis=1)
                              & (w.angles.t >= w.t_start - 1e-12)
                              & (w.angles.t <= w.t_end + 1e-12))
        if rows.size < 4 or not np.isfinite(w.C).all():
            return why
        worst = self._angle_errors_deg(rows).max(axis=0)      # per segment [deg]
        if not (np.isfinite(worst).all() and worst[0] >= st.reseed_foot_deg
                and (worst[1:] < st.reseed_foot_deg).all()):
            return why
        n = w.C.shape[0]
        B = evaluate(np.eye(n), w.first, w.grid, w.angles.t[rows], 1)[:, 0, :]
        foot = LAYOUT['q'].start
        C = w.C.copy()
        C[:, foot] = np.linalg.solve(B.T @ B + RESEED_PULL * np.eye(n),
                                     B.T @ w.angles.y[rows, 0] + RESEED_PULL * w.C[:, foot])
        w.C = C
        still = self._gauss_newton(t_u, np.arange(w.first, w.last + 1), True,
                                   st.reseed_iterations)
        self.events.append(EstimatorEvent(
            'warn', t_u, f'the foot {worst[0]:.0f} deg from the mocap, the other segments '
            f'within {worst[1:].max():.0f} ({why}): its angle refit to the mocap'
            + ('' if still is None else f', still unusable ({still})'),
            {'foot_error_deg': float(worst[0])}))
        return still

    def _drop_window(self, t: float, message: str, values: dict | None = None) -> None:
        """A loss of control (or a skip): say it (an error at data time t [s]), drop the
        window and count a re-initialisation."""
        self.events.append(EstimatorEvent('error', t, message, values or {}))
        self.window = None
        self.restarts += 1

    def _gauss_newton(self, t_u: float, segments: np.ndarray, check: bool,
                      iterations: int | None = None) -> str | None:
        """The update's Gauss-Newton step(s) (``iterations``, default the settings'); why
        the result is unusable (None: it is not): a singular system, non-finite values or the
        physical envelope."""
        w, st = self.window, self.settings
        try:
            # a diverging step shows as non-finite numbers: checked below, not warned about
            with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
                self.damping = w.solve(segments, iterations or st.iterations, self.damping,
                                       check=check)
        except np.linalg.LinAlgError as exc:
            return f'singular step ({exc})'
        if not (np.isfinite(w.C).all() and np.isfinite(w.plate).all()):
            return 'non-finite estimate'
        return self._outside_envelope(t_u)

    def _to_relinearise(self) -> np.ndarray:
        """The newest ``relinearise_s`` of segments, plus ``relinearise_older`` older ones in
        turn (a deterministic round robin)."""
        st, w = self.settings, self.window
        newest = self._newest_segments()
        older = np.arange(w.first, newest[0])
        pick = []
        for _ in range(min(st.relinearise_older, older.size)):
            self.round_robin = (self.round_robin + 1) % older.size
            pick.append(older[self.round_robin])
        return np.unique(np.concatenate([newest, np.array(pick, dtype=np.int64)]))

    def _newest_cost_per_row(self) -> float:
        """Mean normalised residual^2 per row over the newest ``relinearise_s`` of segments
        (their kept linearisations): of the angle and wrench rows together or of the angle
        rows alone, whichever is larger. Alone, because the force plate's rows outnumber the
        angles' nine to one: a window that fits the wrench and has left its angles (a
        landing whose shank and thigh sat 30 deg off the mocap for 0.3 s, angle rows at
        20-85 per row) scored 3-8 together."""
        kept = self.window.rows(self._newest_segments())
        both = float(kept[:, 0].sum() + kept[:, 2].sum()) / max(
            float(kept[:, 1].sum() + kept[:, 3].sum()), 1.0)
        angles = float(kept[:, 0].sum()) / max(float(kept[:, 1].sum()), 1.0)
        return max(both, angles)

    def _newest_segments(self) -> np.ndarray:
        """The window's newest ``relinearise_s`` of segments (global indices, at least one)."""
        st, w = self.settings, self.window
        n_new = max(1, int(np.ceil(st.relinearise_s * st.knot_rate_hz)))
        return np.arange(max(w.first, w.last - n_new + 1), w.last + 1)

    def _rescue_iterations(self) -> int:
        """The rescue's iterations at this update: ``rescue_iterations``, at most
        ``still_rescue_iterations`` where the plate says the body is still over the newest
        ``relinearise_s`` of segments (there the rescues answer the plate's noise)."""
        st, w = self.settings, self.window
        if st.still_rescue_iterations >= st.rescue_iterations:
            return st.rescue_iterations
        if w.still_segments(self._newest_segments()).all():
            return st.still_rescue_iterations
        return st.rescue_iterations

    def _healthy(self, t_u: float) -> bool:
        """The newest data explained: their cost per row (``_newest_cost_per_row``) below
        ``max_cost_per_row`` (else, for longer than ``recover_after_s``, a loss of
        control)."""
        st = self.settings
        per_row = self._newest_cost_per_row()
        if per_row > st.max_cost_per_row:
            if self.unhealthy_since is None:
                self.unhealthy_since = t_u
                self.events.append(EstimatorEvent('warn', t_u, 'observations poorly '
                                                  'explained', {'cost_per_row': per_row}))
            return t_u - self.unhealthy_since < st.recover_after_s
        self.unhealthy_since = None
        return True

    def _outside_envelope(self, t_u: float) -> str | None:
        """Why the window's estimate is physically impossible (None: it is not): evaluated
        at the window's knots and at the newest angle sample."""
        st, w = self.settings, self.window
        t = w.grid.time(np.arange(w.first, w.last + 1) + 0.5)
        v = w.values(t, 2)
        q, qd, s = v[:, 0, LAYOUT['q']], v[:, 1, LAYOUT['q']], v[:, 0, LAYOUT['s']]
        bw = self.model.p.body_weight
        if np.abs(qd[:, :4]).max() > st.max_rate_rad_s:
            return f'segment rate {np.abs(qd[:, :4]).max():.0f} rad/s'
        if np.hypot(s[:, 0], s[:, 1]).max() > st.max_force_bw * bw:
            return f'ground force {np.hypot(s[:, 0], s[:, 1]).max() / bw:.1f} BW'
        if np.abs(q[:, 4:6]).max() > st.max_translation_m:
            return f'ankle {np.abs(q[:, 4:6]).max():.1f} m from the origin'
        lift = q[:, 5] - self.model.ankle_height
        floating = (s[:, 1] > st.contact_full_load_bw * bw) & (lift > self.max_loaded_lift_m)
        if floating.any():
            k = np.argmax(np.where(floating, lift, -np.inf))
            return (f'a ground force of {s[k, 1] / bw:.1f} BW with the ankle {lift[k]:.2f} m '
                    f'above its standing height (on the ground at most '
                    f'{self.max_loaded_lift_m - st.loaded_lift_margin_m:.2f} m)')
        newest = np.nonzero(np.isfinite(w.angles.y).all(axis=1))[0][-3:]
        if newest.size == 3:       # all three newest samples far off (not a spike)
            err = self._angle_errors_deg(newest).min(axis=0).max()
            if err > st.max_angle_error_deg:
                return f'a segment angle {err:.0f} deg from its three newest samples'
        return None

    def _angle_errors_deg(self, rows: np.ndarray) -> np.ndarray:
        """|window - mocap| [len(rows), 4] deg of each segment angle at the window's mocap
        samples ``rows``."""
        w = self.window
        return np.degrees(np.abs(w.values(w.angles.t[rows], 1)[:, 0, :4] - w.angles.y[rows]))

    def _slide(self, t_u: float) -> None:
        st, w = self.settings, self.window
        keep_from = self.grid.segment_of(t_u - st.window_s)
        if keep_from > w.first:
            sd = 0.0
            if st.airborne_translation_diffusion_m_sqrt_s > 0:
                t_old = w.grid.time(np.arange(w.first, keep_from) + 0.5)
                fy = w.values(t_old, 1)[:, 0, LAYOUT['s']][:, 1]
                if (fy < st.contact_free_load_bw * self.model.p.body_weight).all():
                    span_s = (keep_from - w.first) / st.knot_rate_hz
                    sd = st.airborne_translation_diffusion_m_sqrt_s * np.sqrt(span_s)
            w.drop_before(keep_from, translation_sd=sd)

    # ------------------------------------------------------------------ outputs
    def _emit(self, t_u: float, final: bool = False,
              undo: Callable[[str], str | None] | None = None,
              retry: bool = True) -> list[EstimateBlock]:
        """The estimates that became available at update time t_u [s] (``final``: all the
        window holds). Estimates that cannot be published drop the window, unless ``undo``
        (taking back the update's step, ``_undo_step``) makes them publishable; the window
        re-initialised on the newest data then estimates those instants again (``retry``),
        and what it cannot publish either is withheld."""
        st = self.settings
        lo = self.window.t_start
        ready = {}
        for kind, queue, until in (('low_latency', 'out_low', t_u),
                                   ('refined', 'out_refined', t_u if final else t_u - st.lag_s)):
            pend = getattr(self, queue)
            n = 0
            while n < len(pend) and pend[n] <= until + 1e-12:
                n += 1
            now, rest = pend[:n], pend[n:]
            setattr(self, queue, rest)
            dropped = [t for t in now if t < lo - 1e-12]
            if dropped and kind == 'refined':
                self.events.append(EstimatorEvent(
                    'warn', t_u, f'{len(dropped)} instants without a refined estimate '
                    '(re-initialisation)', {'from_s': dropped[0], 'to_s': dropped[-1]}))
            now = [t for t in now if t >= lo - 1e-12]
            if now:
                ready[kind] = np.array(now)
        if not ready:
            return []
        kinds = list(ready)
        spans = [ready[k] for k in kinds]

        def judged() -> tuple[EstimateBlock, str | None]:
            both = self.estimates('', np.concatenate(spans), t_data=t_u)
            return both, self._implausible(both) or self._far_from_mocap(spans)
        both, why = judged()
        if why is not None and undo is not None:
            why = undo(why)
            if why is None:
                both, why = judged()
        if why is not None and not final and self._reseed_foot(t_u, why) is None:
            both, why = judged()
        if why is not None:
            if retry and not final:
                # the window restarts on the newest data and estimates the same instants
                # again (those before its start are reported as lost by the retry)
                self._drop_window(t_u, f'loss of control: {why}; re-initialising from the '
                                  'newest observations', {'from_s': float(both.t.min()),
                                                          'to_s': float(both.t.max())})
                for k in kinds:
                    queue = 'out_low' if k == 'low_latency' else 'out_refined'
                    setattr(self, queue, [float(t) for t in ready[k]] + getattr(self, queue))
                if self._start(t_u):
                    return self._emit(t_u, retry=False)
                return []
            # never published: the instants are reported as lost and the window restarts
            self._drop_window(t_u, f'loss of control: {why}; {both.t.size} instants withheld, '
                              're-initialising from the newest observations',
                              {'from_s': float(both.t.min()), 'to_s': float(both.t.max())})
            if not final:
                self._start(t_u)
            return []
        blocks, start = [], 0
        for k in kinds:
            n = ready[k].size
            blocks.append(both.part(k, slice(start, start + n)))
            start += n
        return blocks

    def _implausible(self, b: EstimateBlock) -> str | None:
        """Why estimates cannot be published (None: they can): non-finite values, joint
        torques above ``max_torque_nm`` or musculotendon forces above ``max_muscle_force_f0``
        times F0."""
        st = self.settings
        bad = [f for f in BLOCK_FIELDS if not np.isfinite(getattr(b, f)).all()]
        if bad:
            return f'non-finite {", ".join(bad)}'
        if np.abs(b.tau_muscle).max(initial=0.0) > st.max_torque_nm:
            return f'joint torque {np.abs(b.tau_muscle).max():.0f} N m'
        ratio = np.abs(b.f) / self.model.p.muscles.f0
        if ratio.max(initial=0.0) > st.max_muscle_force_f0:
            return f'muscle force {ratio.max():.1f} F0'
        return None

    def _far_from_mocap(self, spans: list[np.ndarray]) -> str | None:
        """Why the estimates at the instants of ``spans`` [s] (emitted spans, inside the
        window) cannot be published for their angles (None: they can): in a span, a segment
        angle more than ``max_span_angle_error_deg`` from every finite mocap sample of it
        (two or more: a lone spike is the mocap's). ``_outside_envelope`` judges the
        window's newest samples only: on the real drop jump resampled to 200 Hz the
        touchdown's refined shank was published 45-64 deg from the mocap for 25 ms while
        the newest samples were fitted. One evaluation of the window for all spans."""
        w = self.window
        ta, ya = w.angles.t, w.angles.y
        finite = np.isfinite(ya).all(axis=1)
        groups = [np.flatnonzero((ta >= t[0] - 1e-12) & (ta <= t[-1] + 1e-12) & finite)
                  for t in spans]
        groups = [g for g in groups if g.size >= 2]
        if not groups:
            return None
        err = self._angle_errors_deg(np.concatenate(groups))
        start = 0
        for g in groups:
            worst = float(err[start:start + g.size].min(axis=0).max())
            start += g.size
            if worst > self.settings.max_span_angle_error_deg:
                return (f'a segment angle {worst:.0f} deg from all {g.size} mocap samples '
                        'of its span')
        return None

    def estimates(self, kind: str, t: np.ndarray, t_data: float | None = None
                  ) -> EstimateBlock:
        """Evaluate the window at instants t (inside it). With ``joint_torques`` 'net', the
        joint part of Eq. 1's residual is added in full ``lag_s`` or more behind ``t_data``
        (the newest data, s; None: everywhere) and in proportion closer to it: at the
        window's open end the residual rests on one side's data only (the real drop jump's
        last sample, its landing: 563 N m at the ankle against the muscles' -257), so the
        low-latency torques and a stream's final instants lean on the muscles'."""
        w = self.window
        v = w.values(t, 3)
        q, qd, qdd = (v[:, k, LAYOUT['q']] for k in range(3))
        a = v[:, 0, LAYOUT['a']]
        sv = v[:, 0, LAYOUT['s']]
        tau_m, f, th, thd, tau_r = self.outputs(q, qd, qdd, a, sv)
        tau = tau_m
        if self.settings.joint_torques == 'net':
            share = (np.ones(t.size) if t_data is None or self.settings.lag_s <= 0 else
                     np.clip((t_data - t) / self.settings.lag_s, 0.0, 1.0))
            tau = tau_m + share[:, None] * tau_r
        m = self.model.p.muscles
        ex = excitation(a, v[:, 1, LAYOUT['a']], v[:, 2, LAYOUT['a']], m.tau_act, m.tau_deact)
        return EstimateBlock(kind=kind, t=t, q=q, qd=qd, qdd=qdd, tau=tau, tau_muscle=tau_m,
                             theta=th, theta_dot=thd, f=f, a=a, u=ex.u, s=sv,
                             plate=w.plate.copy())

    # ------------------------------------------------------------------ start
    def _start(self, t_u: float) -> bool:
        """Initialise the window on the newest ``start_window_s`` of data (the first window
        of a stream that begins in the air: on all of it, ``_awaiting_landing``; False: too
        little data yet)."""
        st = self.settings
        ta, ya = self.history_angles.get()
        tw, yw = self.history_wrench.get()
        if np.isfinite(ya).all(axis=1).sum() < 2 or np.isfinite(yw).all(axis=1).sum() < 4:
            return False
        span = (max(st.start_window_s, t_u - self.grid.t_ref) if self.start_from_first
                else st.start_window_s)
        first = self.grid.segment_of(max(t_u - span, self.grid.t_ref))
        last = self.grid.segment_of(t_u)
        t0 = self.grid.time(first) - 1e-12
        sel_a, sel_w = ta >= t0, tw >= t0
        C, plate = initial_control_points(self.model, self.grid, first, last - first + 1,
                                          ta[sel_a], ya[sel_a], tw[sel_w], yw[sel_w],
                                          self.plate_sd)
        capacity = int(np.ceil((st.window_s + span + 2 * self.period)
                               * st.knot_rate_hz)) + 8
        w = SlidingWindow(self.grid, first, C, plate, self.kernel, self.plate_drift, capacity)
        w.add_samples((ta[sel_a], ya[sel_a]), (tw[sel_w], yw[sel_w]))
        w.start_prior(self.plate_sd)
        w.plate_reversion_s = np.asarray(st.plate_reversion_s, dtype=float)
        w.joint_range = self.joint_range
        w.extrapolation_velocity = st.extrapolation_velocity
        w.landing_load = st.landing_load_bw * self.model.p.body_weight
        w.landing_span_s = st.landing_span_s
        w.landing_relax = st.landing_relax()
        w.still_band = np.asarray(st.still_band_bw, dtype=float) * self.model.p.body_weight
        w.still_span_s = st.still_span_s
        w.still_relax = np.array([1.0, st.still_rate_sd_scale])
        if st.arrival_noise_sd is not None:
            noise = np.empty(NV)
            noise[LAYOUT['q']] = np.r_[np.radians([st.arrival_noise_sd[0]] * 4),
                                       [st.arrival_noise_sd[1]] * 2]
            noise[LAYOUT['a']] = st.arrival_noise_sd[2]
            noise[LAYOUT['s']] = st.arrival_noise_sd[3]
            w.arrival_noise = noise ** 2
        segments = np.arange(w.first, w.last + 1)
        per_stage = max(1, st.start_iterations // (len(st.start_dynamics_sd) + 1))
        damping = st.damping
        try:
            with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
                for sd in st.start_dynamics_sd:
                    w.lin_seg[:] = -1
                    damping = w.solve(segments, per_stage, damping,
                                      dynamics_scale=sd / st.dynamics_sd)
                w.lin_seg[:] = -1
                w.solve(segments, st.start_iterations - per_stage * len(st.start_dynamics_sd),
                        damping)
        except np.linalg.LinAlgError as exc:
            failed = f'singular step ({exc})'
        else:
            failed = (None if np.isfinite(w.C).all() and np.isfinite(w.plate).all()
                      else 'non-finite estimate')
        if failed is not None:     # no window: the next update tries again on newer data
            self.events.append(EstimatorEvent('error', t_u, f'initialisation failed: '
                                              f'{failed}; trying again at the next update'))
            self.window = None
            return False
        # tracking starts undamped: the start's damping reflects its far-from-quadratic
        # first iterations, and carried over it would keep the first updates from following
        # the new data
        self.damping = st.damping
        self.round_robin = 0
        self.window = w
        self.state = 'tracking'
        self.start_from_first = False
        self.unhealthy_since = None
        self.events.append(EstimatorEvent('info', t_u, 'initialised', {
            'window_s': float(w.t_end - w.t_start),
            'cost': float(w.model_cost(w.C, w.plate))}))
        return True


class spline_history:  # noqa: N801 - a small record with methods, named for what it holds
    """The newest samples of one stream (for initialisation)."""

    def __init__(self, k: int) -> None:
        self.t = np.zeros(0)
        self.y = np.zeros((0, k))

    def add(self, t: np.ndarray, y: np.ndarray, keep_after: float) -> None:
        self.t = np.concatenate([self.t, t])
        self.y = np.concatenate([self.y, y])
        keep = self.t >= keep_after
        self.t, self.y = self.t[keep], self.y[keep]

    def get(self) -> tuple[np.ndarray, np.ndarray]:
        return self.t, self.y


def initial_control_points(model: JumperModel, grid: KnotGrid, first: int, n_seg: int,
                           ta: np.ndarray, ya: np.ndarray, tw: np.ndarray, yw: np.ndarray,
                           plate_sd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A dynamically consistent starting point for a short window from the data alone:
    (C [n_seg + 3, NV], plate parameters [NX]).

    The state at the window's first instant: the angles and rates of a straight-line fit of
    the window's samples (rates zero when the body is at rest: rates below 0.2 rad/s and the
    vertical force within 10 % of body weight); when loaded, the foot flat (its observed
    angle is the noisiest channel) at the height where the springs carry the observed
    vertical force, else 5 cm above the ground. The motion continues at that rate over the
    window; activations are the rest activations of that posture's torques (static
    optimisation), the wrench the springs' (anchored so that they carry the observed
    fore-aft force), and the force plate's offsets what is left of the observed wrench
    (within 3 SD of their prior; the COP offset zero).
    """
    n = n_seg + 3
    ya, yw = _fill_nan(ta, ya), _fill_nan(tw, yw)
    t0 = float(grid.time(first))
    # local linear fits of the angles and wrench around t0 (the window is short)
    sa = np.polyfit(ta - t0, ya, 1) if ta.size > 1 else np.vstack([np.zeros(4), ya[0]])
    sw = np.polyfit(tw - t0, yw, 1) if tw.size > 1 else np.vstack([np.zeros(3), yw[0]])
    theta0, rate0 = sa[1], sa[0]
    s0 = sw[1]
    bw = model.p.body_weight
    at_rest = (np.abs(rate0[1:]).max() < 0.2 and abs(s0[1] - bw) < 0.1 * bw)
    q0 = np.r_[theta0, 0.0, 0.0]
    qd0 = np.r_[rate0, 0.0, 0.0] * (not at_rest)
    loaded = s0[1] > 0.05 * bw
    if loaded:   # the foot flat (its noisy angle ignored), the springs carrying Fy
        q0[0] = flat_foot_angle(model)
        qd0[0] = 0.0
        q0[5] = ankle_height_for_force(model, q0, s0[1])
    else:        # airborne: 5 cm above the ground
        q0[5] = model.ankle_height + 0.05
    x0 = model.anchors_at(q0)
    if loaded:   # the horizontal springs carry the observed fore-aft force
        x0 = x0 + s0[0] / (x0.size * model.p.contact.k_x)
    t_ctrl = grid.time(first + np.arange(n) - 1)     # control point i ~ value at knot i - 1
    C = np.zeros((n, NV))
    C[:, LAYOUT['q']] = q0[None, :] + (t_ctrl - t0)[:, None] * qd0[None, :]
    springs = model.call(model.contact_outputs, q0, qd0, x0)[0]
    theta_j = model.call(model.joint_angles, q0)[0]
    tau, _ = model.inverse_dynamics(q0[None], qd0[None], np.zeros((1, 6)), springs[None])
    a0 = rest_activations(model, theta_j, tau[0],
                          model.call(model.joint_angles, qd0)[0]).a
    C[:, LAYOUT['a']] = a0
    C[:, LAYOUT['s']] = springs
    plate = np.zeros(NX)
    b = PLATE['b']
    plate[b] = np.clip(s0 - springs, -3 * plate_sd[b], 3 * plate_sd[b])
    return C, plate


def flat_foot_angle(model: JumperModel) -> float:
    """Foot angle [rad] at which its heel and toe points are at the same height."""
    (hx, hy), (tx, ty) = model.p.contact.points
    return float(-np.arctan2(ty - hy, tx - hx))


def ankle_height_for_force(model: JumperModel, q: np.ndarray, fy: float) -> float:
    """Ankle height r2 [m] at which the springs at rest (anchors under the points) carry
    the vertical force fy [N] in posture q (bisection; the force falls with height)."""
    lo, hi = model.ankle_height - 0.03, model.ankle_height + 0.05
    qq = np.asarray(q, dtype=float).copy()
    for _ in range(50):
        qq[5] = 0.5 * (lo + hi)
        f = float(model.call(model.contact_outputs, qq, np.zeros(6), model.anchors_at(qq))[0][1])
        lo, hi = (qq[5], hi) if f > fy else (lo, qq[5])
    return 0.5 * (lo + hi)


def _fill_nan(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    y = y.copy()
    for c in range(y.shape[1]):
        ok = np.isfinite(y[:, c])
        if ok.any() and not ok.all():
            y[~ok, c] = np.interp(t[~ok], t[ok], y[ok, c])
    return y


@dataclass
class MovingHorizonRun:
    """The estimator run over a whole recording (``estimate``): the refined and low-latency
    estimates as Stage-1 records on the force-plate instants, the estimator's events and the
    CPU time of each poll that updated [s] and the data time [s] of the sample that let it
    run (``update_t_s``)."""

    refined: SKTResult
    low_latency: SKTResult
    events: list[EstimatorEvent]
    update_cpu_s: np.ndarray
    restarts: int
    update_t_s: np.ndarray | None = None


def _stage1_record(model: JumperModel, blocks: list[EstimateBlock], events: list,
                   cpu_s: float) -> SKTResult:
    """Concatenated estimate blocks as a Stage-1 record (``muscles`` holds a, u, f; events
    as dicts with 't', 'level', 'reason' and their values)."""
    events = [{'t': e.t, 'level': e.level, 'reason': e.message, **e.values} for e in events]
    if not blocks:
        empty = np.zeros((0, 6))
        return SKTResult(t=np.zeros(0), q=empty, qd=empty, qdd=empty, tau=np.zeros((0, 3)),
                         s=np.zeros((0, 3)), bias=np.zeros(0), residual=np.zeros((0, 7)),
                         x0=np.zeros(2), status='lost_control', events=events, cpu_s=cpu_s)
    cat = {f: np.concatenate([getattr(b, f) for b in blocks])
           for f in ('t', 'q', 'qd', 'qdd', 'tau', 'f', 'a', 'u', 's')}
    plate = np.concatenate([np.repeat(b.plate[None], b.t.size, 0) for b in blocks])
    moment_bias = plate[:, PLATE['b']][:, 2] + plate[:, PLATE['cop']][:, 0] * cat['s'][:, 1]
    res = SKTResult(t=cat['t'], q=cat['q'], qd=cat['qd'], qdd=cat['qdd'], tau=cat['tau'],
                    s=cat['s'], bias=moment_bias, residual=np.zeros((cat['t'].size, 7)),
                    x0=model.anchors_at(cat['q'][0]), status='ok', events=events,
                    cpu_s=cpu_s, muscles={'a': cat['a'], 'u': cat['u'], 'f': cat['f']})
    res.liftoff_s = liftoff_time(res.t, res.s[:, 1],
                                 OBSERVATION_NOISE.force_sd_bw * model.p.body_weight)
    return res


def time_order(t_angles: np.ndarray, t_wrench: np.ndarray) -> list[tuple[float, int, int]]:
    """The two streams' samples merged in time order: (t [s], stream (0 angles, 1 wrench),
    index in its stream); at equal times angles first."""
    return sorted([(float(t), 0, i) for i, t in enumerate(t_angles)]
                  + [(float(t), 1, i) for i, t in enumerate(t_wrench)])


def estimate(model: JumperModel, t_angles: np.ndarray, angles: np.ndarray,
             t_wrench: np.ndarray, wrench: np.ndarray,
             settings: MovingHorizonSettings | None = None) -> MovingHorizonRun:
    """The streaming estimator fed a whole recording in time order (offline = live: the same
    object, the same updates). Samples at equal times: angles first."""
    c0 = time.process_time()
    est = MovingHorizonEstimator(model, settings)
    order = time_order(t_angles, t_wrench)
    blocks: list[EstimateBlock] = []
    cpu, when = [], []
    for t, k, i in order:
        if k == 0:
            est.add_angles(t, angles[i])
        else:
            est.add_wrench(t, wrench[i])
        n = est.updates
        c = time.process_time()
        blocks += est.poll()
        if est.updates != n:
            cpu.append(time.process_time() - c)
            when.append(t)
    blocks += est.finish()
    total = time.process_time() - c0
    refined = _stage1_record(model, [b for b in blocks if b.kind == 'refined'], est.events,
                             total)
    low = _stage1_record(model, [b for b in blocks if b.kind == 'low_latency'], est.events,
                         total)
    return MovingHorizonRun(refined=refined, low_latency=low, events=est.events,
                            update_cpu_s=np.array(cpu), restarts=est.restarts,
                            update_t_s=np.array(when))
