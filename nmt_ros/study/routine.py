"""Routines: minutes of ground truth on the musculoskeletal model (issue 11).

A routine is one continuous forward simulation of the model (Eq. 1 + 8, stiff Radau, anchors
re-placed at every touchdown: ``model.hybrid_simulation``) driven phase by phase:

* **quiet stance**: the stance regulator (LQR through the excitations) tracking a slowly
  wandering sway target (``study.stance``): the body sways by its own dynamics;
* **countermovement jump** (``cmj``): a collocation plan (``study.jump_planning``) from the
  state the simulation reached, ending at lift-off with the COM's ballistic apex at the
  target height (``fraction`` of ``max_jump_m`` above standing), tracked by a time-varying
  LQR; then a landing plan from the simulated flight state (touchdown, landing, recovery to
  the stance equilibrium at rest), tracked likewise; then stance again;
* **drop jump** (``drop``): released at rest in the air with the feet ``drop_height_m`` above
  the ground (stepping off a box onto the force plate), fall, landing and push-off planned as
  one phase to the target height, flight, landing and recovery as above. It starts in the air,
  so it can only open a routine: a routine with a drop jump opens with it.

Each plan starts from the simulated state (continuity at every join); the feedback keeps the
simulated model on the plan (achieved apex within a fraction of a millimetre of the plan's),
and if the achieved height misses the target by more than ``height_tolerance_m`` the push-off
is re-planned with the target corrected by the miss (secant) from the same state.

Heights: the apex of the whole-body COM minus its standing-upright height (the project's jump
height, ``JumperModel.standing_com_height``). The maximal jump ``max_jump_m`` is this model's
maximal squat jump, the reference jump of ``nmt reference`` (25.9 cm; test_routine checks it
against the shipped bags/reference_jump/reference.json).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import partial
import time

import numpy as np

from nmt_ros.model.hybrid_simulation import HybridSimulation, Touchdown, simulate_hybrid
from nmt_ros.model.jumper import JumperModel
from nmt_ros.study.feedback import FeedbackLaw, joint_weights, tvlqr
from nmt_ros.study.jump_planning import PhasePlanner, Plan, PlanWeights
from nmt_ros.study.stance import (
    Stance,
    StanceSettings,
    quiet_stance,
    stance_regulator,
    sway_directions,
    sway_signal,
)

RATE_HZ = 1080.0


@dataclass(frozen=True)
class RoutineSettings:
    """What the routine holds and how it is generated (defaults: the shipped routine)."""

    duration_s: float = 60.0
    jumps: int = 5
    seed: int = 0
    drop: bool = True                    # open with a drop jump
    max_jump_m: float = 0.2589           # this model's maximal (squat) jump, above standing
    fraction_range: tuple[float, float] = (0.35, 1.0)
    drop_fraction: float = 0.5
    drop_height_m: float = 0.30          # lowest foot point above the ground at release
    first_stance_s: float = 8.0          # at least, before the first countermovement jump
    min_stance_s: float = 4.0            # at least, between cycles and at the end
    push_s: float = 0.9                  # countermovement + push-off plan (s)
    drop_contact_s: float = 0.45         # drop jump: touchdown to lift-off (s)
    landing_com_m: float = 0.03          # COM above standing height at toe touchdown (m)
    recovery_s: float = 1.2              # touchdown to rest in the stance equilibrium (s)
    height_tolerance_m: float = 0.004    # re-plan the push-off beyond this miss
    max_replans: int = 2
    track_q: float = 1000.0              # tracking weights of the time-varying LQR
    track_r: float = 100.0
    plan_tol: float = 1e-6
    quick: bool = False                  # coarser grids (tests), not the shipped truth
    stance: StanceSettings = field(default_factory=StanceSettings)
    weights: PlanWeights = field(default_factory=PlanWeights)


@dataclass
class Cycle:
    """Facts of one jump cycle (times in routine time, s; heights above standing, m)."""

    kind: str
    target_height_m: float
    start_s: float
    liftoff_s: float = float('nan')
    apex_s: float = float('nan')
    achieved_height_m: float = float('nan')
    planned_height_m: float = float('nan')
    touchdowns_s: list[float] = field(default_factory=list)
    landing_s: float = float('nan')
    end_s: float = float('nan')
    replans: int = 0
    plan_cpu_s: float = 0.0
    plan_iterations: int = 0

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, float | np.floating) else v)
                for k, v in asdict(self).items()}


@dataclass
class Routine:
    """The routine's truth samples (1080 Hz from t = 0) and facts."""

    t: np.ndarray            # [n] s
    x: np.ndarray            # [n, 21] (q, qd, a)
    u: np.ndarray            # [n, 9] excitations that drove the model
    anchors: np.ndarray      # [n, 2] contact anchors in force (m)
    cycles: list[Cycle]
    stances: list[tuple[float, float]]    # quiet-stance windows (s)
    touchdowns: list[Touchdown]
    stance: Stance
    settings: RoutineSettings
    cpu_s: dict = field(default_factory=dict)


def _grid(t0: float, t1: float, last: bool = False) -> np.ndarray:
    """The 1080 Hz instants in [t0, t1) ([t0, t1] when ``last``)."""
    k0 = int(np.ceil(t0 * RATE_HZ - 1e-9))
    k1 = int(np.floor(t1 * RATE_HZ + 1e-9))
    k = np.arange(k0, k1 + 1)
    t = k / RATE_HZ
    return t if last else t[t < t1 - 1e-12]


class RoutineBuilder:
    """Simulates a routine phase by phase (module docstring)."""

    def __init__(self, model: JumperModel, settings: RoutineSettings = RoutineSettings(),
                 progress: Callable[[str], None] | None = None) -> None:
        self.model = model
        self.s = settings
        self.say = progress or (lambda _m: None)
        self.rng = np.random.default_rng(settings.seed)
        self.stance = quiet_stance(model, settings.stance)
        self.k_stance, self.p_stance = stance_regulator(model, self.stance, settings.stance)
        self.sway_dx, self.sway_du = sway_directions(model, self.stance, settings.stance)
        self.planner = PhasePlanner(model, self.stance, settings.weights, tol=settings.plan_tol)
        self.q_track = joint_weights(1e3, 1e3, 1e3, 1e3, 0.0, 0.0, 0.01, 1e-2) * (
            settings.track_q / 1e3)
        self.r_track = settings.track_r * np.eye(9)
        self.parts: list[HybridSimulation] = []
        self.cpu = {'plan': 0.0, 'simulate': 0.0, 'feedback': 0.0}
        self.templates: dict[str, Plan] = {}

    # ------------------------------------------------------------------ pieces
    def _simulate(self, law: FeedbackLaw, x: np.ndarray, anchors: np.ndarray, t0: float,
                  t1: float, last: bool = False, keep: bool = True) -> HybridSimulation:
        c0 = time.process_time()
        sim = simulate_hybrid(self.model, x, anchors, law, t0, t1, t_eval=_grid(t0, t1, last))
        self.cpu['simulate'] += time.process_time() - c0
        if not sim.success:
            raise RuntimeError(f'routine simulation failed: {sim.message}')
        if keep:
            self.parts.append(sim)
        return sim

    def _tracking_law(self, plan: Plan, t0: float, p_final: np.ndarray) -> FeedbackLaw:
        c0 = time.process_time()
        gains = tvlqr(self.model, plan.t, plan.x, plan.u, plan.anchors, self.q_track,
                      self.r_track, p_final)
        self.cpu['feedback'] += time.process_time() - c0
        return FeedbackLaw(plan.t + t0, plan.u, plan.x, gains)

    def stance_phase(self, x: np.ndarray, anchors: np.ndarray, t0: float, t1: float,
                     last: bool = False) -> HybridSimulation:
        """Quiet stance with sway on [t0, t1] from state x, feet on ``anchors``."""
        st = self.stance.placed_on(anchors)
        tn, c = sway_signal(self.rng, t0, t1, self.s.stance)
        law = FeedbackLaw(tn, st.u[None] + c[:, None] * self.sway_du,
                          st.x[None] + c[:, None] * self.sway_dx, self.k_stance, smooth=True)
        return self._simulate(law, x, anchors, t0, t1, last)

    def _plan(self, solve: Callable[..., Plan], what: str, template: str,
              cycle: Cycle, remember: bool = True) -> Plan:
        """A solved plan, counted and reported. ``solve(guess=...)`` starts from the last plan of
        the same kind (``templates[template]``), which is nearly always the fastest start;
        when that does not converge (a warm start can end infeasible where the planner's own
        guess converges), it starts again from the planner's own guess. ``remember``: the
        plan becomes the template (a push-off's is kept only once its height is accepted).
        RuntimeError if neither converges."""
        guess = self.templates.get(template)
        plan = solve(guess=guess)
        if not plan.success and guess is not None:
            self._count(plan, cycle)
            self.say(f'  {what} plan from the last one did not converge ({plan.status}, '
                     f'{plan.iterations} iterations): again from the default guess')
            plan = solve(guess=None)
        self._count(plan, cycle)
        if not plan.success:
            raise RuntimeError(f'the {what} plan did not converge: {plan.status} '
                               f'({plan.iterations} iterations)')
        self.say(f'  {what} plan: {plan.iterations} iterations, {plan.cpu_s:.1f} s CPU, '
                 f'{plan.t.size} nodes')
        if remember:
            self.templates[template] = plan
        return plan

    def _count(self, plan: Plan, cycle: Cycle) -> None:
        self.cpu['plan'] += plan.cpu_s
        cycle.plan_cpu_s += plan.cpu_s
        cycle.plan_iterations += plan.iterations

    def _apex(self, sim: HybridSimulation) -> tuple[float, float, float]:
        """(lift-off [s], apex time [s], apex height above standing [m]) of the first flight
        in a simulated push-off (the 1080 Hz samples; the COM's maximum in flight)."""
        m = self.model
        forces, = m.batch(m.contact_forces, sim.x[:, :6], sim.x[:, 6:12], sim.anchors)
        fy = forces[:, 1, :].sum(axis=1)
        loaded = np.flatnonzero(fy > 1.0)
        after = np.flatnonzero((fy <= 1.0) & (np.arange(fy.size) > (loaded[0] if loaded.size
                                                                    else 0)))
        if after.size == 0:
            return float('nan'), float('nan'), float('nan')
        i_lo = after[0]
        com, = m.batch(m.com, sim.x[:, :6])
        vel, = m.batch(m.com_velocity, sim.x[:, :6], sim.x[:, 6:12])
        ballistic = com[:, 1] + np.maximum(vel[:, 1], 0) ** 2 / (2 * m.p.gravity)
        return (float(sim.t[i_lo]), float('nan'),
                float(ballistic[i_lo] - m.standing_com_height))

    def push_phase(self, cycle: Cycle, x: np.ndarray, u: np.ndarray, anchors: np.ndarray,
                   t0: float) -> tuple[HybridSimulation, Plan]:
        """Plan and simulate a push-off (countermovement, or drop and rebound) to the cycle's
        target, re-planning from the same state while the miss exceeds the tolerance."""
        s = self.s
        m = self.model
        aim = cycle.target_height_m
        drop = cycle.kind == 'drop'
        for attempt in range(s.max_replans + 1):
            apex = m.standing_com_height + aim
            if drop:
                t_td = self._fall_time(x, 0.0)
                duration = t_td + s.drop_contact_s
                plan = self._plan(partial(self.planner.push_off, x, u, anchors, apex, duration,
                                          airborne_until=t_td, **self._push_grid()),
                                  'drop jump', 'drop', cycle, remember=False)
            else:
                plan = self._plan(partial(self.planner.push_off, x, u, anchors, apex, s.push_s,
                                          **self._push_grid()),
                                  'push-off', 'cmj', cycle, remember=False)
            law = self._tracking_law(plan, t0, 0.0 * self.q_track)
            sim = self._simulate(law, x, anchors, t0, t0 + plan.t[-1], keep=False)
            t_lo, _, height = self._apex(sim)
            miss = height - cycle.target_height_m
            self.say(f'  target {100 * cycle.target_height_m:.2f} cm, achieved '
                     f'{100 * height:.2f} cm (miss {1000 * miss:+.2f} mm)')
            if np.isfinite(miss) and abs(miss) <= s.height_tolerance_m:
                break
            if attempt == s.max_replans or not np.isfinite(miss):
                raise RuntimeError(f'{cycle.kind} at {t0:.2f} s: achieved height '
                                   f'{height:.4f} m for target {cycle.target_height_m:.4f} m')
            aim -= miss
            cycle.replans += 1
        self.templates['drop' if drop else 'cmj'] = plan
        self.parts.append(sim)
        cycle.liftoff_s = t_lo
        cycle.planned_height_m = aim
        cycle.touchdowns_s += [td.t for td in sim.touchdowns]
        return sim, plan

    def jump(self, cycle: Cycle, x: np.ndarray, u: np.ndarray, anchors: np.ndarray,
             t0: float) -> HybridSimulation:
        """A cycle's push-off, flight and landing from state x at t0 [s]; its landing
        simulation. When no landing can be planned from the flight a push-off left (seed 8's
        fourth jump: 9 cm after a 20 cm one, planned from that jump's push-off, left the foot
        42 deg plantarflexed with the heel 19 cm up and no landing converged from it, with
        or without the last landing as its guess, or 30 ms later in the flight), the push-off
        is planned again from the planner's own guess and the landing after it."""
        kind = 'drop' if cycle.kind == 'drop' else 'cmj'
        parts, touchdowns = len(self.parts), list(cycle.touchdowns_s)
        warm = kind in self.templates       # else the push-off was planned cold already
        sim, plan = self.push_phase(cycle, x, u, anchors, t0)
        try:
            return self.landing_phase(cycle, sim.x_end, plan.u[-1], sim.anchors_end,
                                      t0 + plan.t[-1])
        except RuntimeError as exc:
            if not warm:
                raise
            self.say(f'  {exc}: the push-off again from the default guess')
        del self.parts[parts:]
        cycle.touchdowns_s = list(touchdowns)
        cycle.replans += 1
        del self.templates[kind]
        sim, plan = self.push_phase(cycle, x, u, anchors, t0)
        return self.landing_phase(cycle, sim.x_end, plan.u[-1], sim.anchors_end,
                                  t0 + plan.t[-1])

    def _push_grid(self) -> dict:
        return ({'coarse': 0.02, 'fine': 0.005} if self.s.quick else {})

    def _fall_time(self, x: np.ndarray, t_offset: float) -> float:
        """Time [s] from state x until the COM falls ballistically to the landing height."""
        m = self.model
        com = m.call(m.com, x[:6])[0]
        v = m.call(m.com_velocity, x[:6], x[6:12])[0]
        y = m.standing_com_height + self.s.landing_com_m
        g = m.p.gravity
        disc = v[1] ** 2 + 2 * g * (com[1] - y)
        if disc < 0:
            raise RuntimeError('the COM never falls to the landing height (not in flight)')
        return float((v[1] + np.sqrt(disc)) / g) + t_offset

    def landing_phase(self, cycle: Cycle, x: np.ndarray, u: np.ndarray, anchors: np.ndarray,
                      t0: float) -> HybridSimulation:
        """Plan and simulate the rest of the flight, the landing and the recovery."""
        s = self.s
        t_td = self._fall_time(x, 0.0)
        grid = ({'coarse': 0.02} if s.quick else {})
        plan = self._plan(partial(self.planner.landing, x, u, anchors, t_td,
                                  t_td + s.recovery_s, **grid), 'landing', 'landing', cycle)
        law = self._tracking_law(plan, t0, self.p_stance)
        sim = self._simulate(law, x, anchors, t0, t0 + plan.t[-1])
        cycle.touchdowns_s += [td.t for td in sim.touchdowns]
        cycle.landing_s = next((td.t for td in sim.touchdowns), float('nan'))
        cycle.end_s = t0 + plan.t[-1]
        return sim

    # ------------------------------------------------------------------ schedule
    def schedule(self) -> list[Cycle]:
        """The cycles' kinds and targets (seeded)."""
        s = self.s
        n = s.jumps
        kinds = (['drop'] if s.drop and n >= 1 else []) + ['cmj'] * (n - (1 if s.drop else 0))
        n_cmj = kinds.count('cmj')
        lo, hi = s.fraction_range
        fractions = list(self.rng.permutation(np.linspace(lo, hi, n_cmj))) if n_cmj else []
        cycles = []
        for k in kinds:
            f = s.drop_fraction if k == 'drop' else float(fractions.pop(0))
            cycles.append(Cycle(kind=k, target_height_m=f * s.max_jump_m, start_s=float('nan')))
        return cycles

    def _cycle_length(self, kind: str) -> float:
        s = self.s
        flight = 2 * np.sqrt(2 * s.max_jump_m / self.model.p.gravity)
        if kind == 'drop':
            return 0.25 + s.drop_contact_s + flight + s.recovery_s
        return s.push_s + flight + s.recovery_s

    def stance_durations(self, cycles: list[Cycle]) -> list[float]:
        """Stance before each countermovement jump and at the end (seeded, filling the
        duration; at least ``first_stance_s`` first and ``min_stance_s`` elsewhere)."""
        s = self.s
        n_windows = sum(c.kind == 'cmj' for c in cycles) + 1
        busy = sum(self._cycle_length(c.kind) for c in cycles)
        spare = s.duration_s - busy - s.first_stance_s - (n_windows - 1) * s.min_stance_s
        if spare < 0:
            raise ValueError(f'{s.duration_s} s cannot hold {len(cycles)} jumps with the '
                             f'stances between them (need at least {s.duration_s - spare:.1f}'
                             f' s)')
        share = self.rng.dirichlet(np.full(n_windows, 4.0)) * spare
        return [s.first_stance_s + share[0]] + [s.min_stance_s + v for v in share[1:]]

    # ------------------------------------------------------------------ the routine
    def build(self) -> Routine:
        s = self.s
        m = self.model
        c_all = time.process_time()
        cycles = self.schedule()
        stances_s = self.stance_durations(cycles)
        st = self.stance
        t = 0.0
        anchors = st.x0.copy()
        windows: list[tuple[float, float]] = []
        if cycles and cycles[0].kind == 'drop':
            x = st.x.copy()
            pts = np.asarray(m.positions(x[:6])[4])
            x[5] += s.drop_height_m - pts[1].min()
            u = st.u.copy()
        else:
            x, u = st.x.copy(), st.u.copy()
        k_stance = 0
        for i, cycle in enumerate(cycles):
            if cycle.kind == 'cmj':
                t_end = t + stances_s[k_stance]
                k_stance += 1
                self.say(f'stance {t:.2f}-{t_end:.2f} s')
                sim = self.stance_phase(x, anchors, t, t_end)
                windows.append((t, t_end))
                x, anchors, t = sim.x_end, sim.anchors_end, t_end
                u = self.parts[-1].u[-1] if self.parts[-1].u.size else u
            cycle.start_s = t
            self.say(f'cycle {i + 1}/{len(cycles)}: {cycle.kind}, target '
                     f'{100 * cycle.target_height_m:.1f} cm at {t:.2f} s')
            sim = self.jump(cycle, x, u, anchors, t)
            x, anchors, t = sim.x_end, sim.anchors_end, cycle.end_s
        t_end = s.duration_s
        self.say(f'stance {t:.2f}-{t_end:.2f} s')
        self.stance_phase(x, anchors, t, t_end, last=True)
        windows.append((t, t_end))
        parts = self.parts
        tt = np.concatenate([p.t for p in parts])
        xx = np.vstack([p.x for p in parts])
        uu = np.vstack([p.u for p in parts])
        aa = np.vstack([p.anchors for p in parts])
        order = np.argsort(tt, kind='stable')
        if np.any(np.diff(tt[order]) <= 0):
            raise RuntimeError('routine samples overlap or repeat')
        expected = _grid(0.0, s.duration_s, last=True)
        if tt.size != expected.size or np.abs(tt[order] - expected).max() > 1e-9:
            raise RuntimeError('routine samples do not cover the 1080 Hz grid')
        self._measure_cycles(cycles, tt[order], xx[order], aa[order])
        self.cpu['total'] = time.process_time() - c_all
        touchdowns = [td for p in parts for td in p.touchdowns]
        return Routine(t=expected, x=xx[order], u=uu[order], anchors=aa[order],
                       cycles=cycles, stances=windows, touchdowns=touchdowns, stance=st,
                       settings=s, cpu_s=dict(self.cpu))

    def _measure_cycles(self, cycles: list[Cycle], t: np.ndarray, x: np.ndarray,
                        anchors: np.ndarray) -> None:
        """Achieved heights from the truth: the COM's highest sample in each cycle's first
        flight after its lift-off."""
        m = self.model
        com, = m.batch(m.com, x[:, :6])
        for c in cycles:
            sel = (t >= c.liftoff_s) & (t <= c.landing_s)
            if not sel.any():
                continue
            k = np.flatnonzero(sel)[np.argmax(com[sel, 1])]
            c.apex_s = float(t[k])
            c.achieved_height_m = float(com[k, 1] - m.standing_com_height)


def make_routine(model: JumperModel, settings: RoutineSettings = RoutineSettings(),
                 progress: Callable[[str], None] | None = None) -> Routine:
    """Simulate a routine (module docstring)."""
    return RoutineBuilder(model, settings, progress).build()
