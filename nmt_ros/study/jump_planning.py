"""Predictive simulation of jump phases on the shared collocation transcription.

A jump cycle is planned in phases, each one NLP solved from the state the forward simulation
actually reached (so the truth stays continuous; the plan only guides the simulated model):

* ``push_off``: from (swaying) quiet stance, a countermovement and push-off ending at
  lift-off with the ballistic apex of the COM equal to a target; or, for a drop jump, from
  the air: fall, touchdown, landing and push-off to the target.
* ``landing``: from a state in flight: the rest of the flight, touchdown (toe first), landing
  and recovery to the quiet-stance equilibrium at rest.

Transcription (``tracking.collocation``): nodes x = [q, qd, a] (21), qdd (6, scaled) and the
excitations u (9, piecewise linear between nodes); globals the anchors x0 [2] (m); implicit
Eq. 1 (scaled residual) and Eq. 8. The grid is refined where contact changes (``Grid``):
fine steps (1 ms) around touchdown and through the push-off, coarse ones (10-15 ms) in slow
phases. The transcription's step is uniform in a stretched time s (h_s = 1); each node's
rate is multiplied by the local dt/ds (node constant ``c``), the trapezoidal rule of the
time-transformed ODE (second order, like the rule on the non-uniform grid).

Criterion (``PlanWeights``): effort (integral of sum u^2), smoothness of the excitations
(sum of (du)^2 / dt), accelerations (integral of |qdd|^2, which also penalises impacts), and
in landings the squared vertical ground force (in BW): a soft landing.

Contact anchors: in a push-off from stance they are the current ones (fixed). In the air the
anchors are decision variables; the touchdown of the toe is pinned to a node (``t_touchdown``,
from the COM's ballistic path to the landing height) and from then on the toe, and the heel
from ``heel_delay_s`` later, stay within ``anchor_slip_m`` of their anchors: the plan's anchors
are where the points land, as the hybrid simulation's rule places them.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
import time

import casadi as ca
import numpy as np

from nmt_ros.model import contact as contact_law
from nmt_ros.model.jumper import JumperModel
from nmt_ros.study.stance import Stance
from nmt_ros.tracking.collocation import (
    QDD_SCALE,
    Block,
    Defect,
    LeastSquares,
    Path,
    Transcription,
    dynamics_residual,
    solvers,
)

NX = 21
#: Landing: the heel touches down HEEL_DELAY_S after the toe (s); a point is on the ground
#: SETTLE_S after its touchdown (s) and stays within ANCHOR_SLIP_M of its anchor (m).
SETTLE_S = 0.012
HEEL_DELAY_S = 0.06
ANCHOR_SLIP_M = 0.002
#: In a drop jump the heel may rise from HEEL_OFF_S before lift-off (s).
HEEL_OFF_S = 0.15


@dataclass(frozen=True)
class PlanWeights:
    """Weights of the criterion (dimensionless multipliers of each term)."""

    effort: float = 1.0              # per s of sum u^2
    smoothness: float = 1e-3         # per (du)^2 / s
    acceleration: float = 1e-5       # per s of |qdd|^2 ((rad or m)/s^2)^2
    force: float = 0.05              # per s of (Fy / BW)^2 (landings)


@dataclass(frozen=True)
class Grid:
    """Node times [s] of a non-uniform grid and the stretch dt/ds at each node (h_s = 1).

    Built from a step h(t): ``coarse`` [s] everywhere except in ``windows`` (start, end,
    step) [s], blended smoothly (log-linear over ``blend_s``)."""

    t: np.ndarray
    c: np.ndarray

    @property
    def n(self) -> int:
        return self.t.size - 1

    @staticmethod
    def build(duration: float, coarse: float, windows: list[tuple[float, float, float]],
              blend_s: float = 0.02) -> Grid:
        ts = np.linspace(0.0, duration, 20001)
        log_h = np.full(ts.size, np.log(coarse))
        for a, b, h in windows:
            w = np.clip(np.minimum(ts - a, b - ts) / blend_s + 1.0, 0.0, 1.0)
            w = w * w * (3 - 2 * w)
            log_h = np.minimum(log_h, (1 - w) * np.log(coarse) + w * np.log(h))
        h = np.exp(log_h)
        s = np.concatenate([[0.0], np.cumsum(0.5 * (1 / h[1:] + 1 / h[:-1]) * np.diff(ts))])
        n = max(2, int(round(s[-1])))
        s_nodes = np.linspace(0.0, s[-1], n + 1)
        t_nodes = np.interp(s_nodes, s, ts)
        c = np.interp(t_nodes, ts, h) * (s[-1] / n)
        # node times exactly consistent with the stretched trapezoidal rule, end at duration
        t = np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]))])
        c *= duration / t[-1]
        t *= duration / t[-1]
        return Grid(t=t, c=c)

    def node_at(self, t: float) -> int:
        return int(np.argmin(np.abs(self.t - t)))

    def weights(self) -> np.ndarray:
        """Trapezoidal quadrature weights [n + 1] (s)."""
        dt = np.diff(self.t)
        w = np.zeros(self.t.size)
        w[:-1] += dt / 2
        w[1:] += dt / 2
        return w


@dataclass
class Plan:
    """A solved phase: node times (from the phase start) and values, and the solve record."""

    kind: str
    t: np.ndarray            # [n + 1] s
    x: np.ndarray            # [n + 1, 21]
    qdd: np.ndarray          # [n + 1, 6]
    u: np.ndarray            # [n + 1, 9]
    anchors: np.ndarray      # [2] m
    success: bool
    status: str
    iterations: int
    cpu_s: float
    facts: dict = field(default_factory=dict)


class PhasePlanner:
    """Builds and solves the NLP of one phase kind on a given grid (module docstring)."""

    def __init__(self, model: JumperModel, stance: Stance,
                 weights: PlanWeights = PlanWeights(), tol: float = 1e-6,
                 max_iter: int = 1500, print_level: int = 0) -> None:
        self.model = model
        self.stance = stance
        self.weights = weights
        self.tol = tol
        self.max_iter = max_iter
        self.print_level = print_level

    # ------------------------------------------------------------------ the node
    def _node(self, v: dict[str, ca.SX]) -> dict[str, ca.SX]:
        m = self.model
        p = m.p
        x, qdd, u, x0, c = v['x'], v['qdd'], v['u'], v['x0'], v['c']
        q, qd, a = x[:6], x[6:12], x[12:]
        tau_m = m.muscle_torques(q, qd, a)[0]
        pts = m.positions(q)[4]                     # [2 x 2]: heel, toe (columns)
        vel = ca.jacobian(ca.vec(pts), q) @ qd      # heel x, heel y, toe x, toe y
        forces = m.contact_forces(q, qd, x0)        # [2 x 2]
        com = m.com(q)
        vcom = m.com_velocity(q, qd)
        cp = p.contact
        elastic = sum(cp.k_y * cp.delta * contact_law.softplus(-pts[1, i] / cp.delta)
                      for i in range(2))
        bw = p.body_weight
        return {
            'residual': dynamics_residual(m, q, qd, qdd, tau_m, x0),                 # Eq. 1
            'xdot': c * ca.vertcat(qd, qdd, m.activation_dynamics(u, a)),          # Eq. 8
            'heel_y': pts[1, 0], 'toe_y': pts[1, 1],
            'heel_vy': vel[1], 'toe_vy': vel[3],
            'heel_slip': pts[0, 0] - x0[0], 'toe_slip': pts[0, 1] - x0[1],
            'heel_fy': forces[1, 0], 'toe_fy': forces[1, 1],
            'fy_bw': (forces[1, 0] + forces[1, 1]) / bw,
            'elastic': elastic, 'com_vy': vcom[1], 'com_vx': vcom[0],
            'apex': com[1] + vcom[1] ** 2 / (2 * p.gravity),
        }

    # ------------------------------------------------------------------ building blocks
    def _transcription(self, grid: Grid, constraints: list, force_cost: bool,
                       ) -> Transcription:
        w = self.weights
        quad_w = grid.weights()
        dt = np.diff(grid.t)
        wq = ca.DM(quad_w[None, :])
        wd = ca.DM((1.0 / dt)[None, :])
        sqrt_force = np.sqrt(w.force * quad_w) if force_cost else None

        def quadratic(var: dict, _par: dict) -> ca.MX:
            u = var['u']
            qdd = var['qdd'] * QDD_SCALE
            du = u[:, 1:] - u[:, :-1]
            return (w.effort * ca.sum2(ca.sum1(u ** 2) * wq)
                    + w.smoothness * ca.sum2(ca.sum1(du ** 2) * wd)
                    + w.acceleration * ca.sum2(ca.sum1(qdd ** 2) * wq))

        costs = []
        consts = {'c': grid.c[:, None]}
        if force_cost:
            consts['sqrt_wf'] = sqrt_force[:, None]
            costs.append(LeastSquares(lambda v: v['sqrt_wf'] * v['fy_bw']))
        return Transcription(
            grid.n, 1.0, [Block('x', NX), Block('qdd', 6, scale=QDD_SCALE), Block('u', 9)],
            self._node, [Defect('x', 'xdot'), Path('residual'), *constraints], costs=costs,
            global_blocks=[Block('x0', 2)], node_constants=consts,
            quadratic_cost=quadratic)

    def _bounds(self) -> tuple[dict, dict]:
        lo = np.r_[np.full(12, -np.inf), np.zeros(9)]
        hi = np.r_[np.full(12, np.inf), np.ones(9)]
        return {'x': lo, 'u': 0.0}, {'x': hi, 'u': 1.0}

    # ------------------------------------------------------------------ phases
    def push_off(self, x_start: np.ndarray, u_start: np.ndarray, anchors: np.ndarray,
                 apex_target: float, duration: float, *, airborne_until: float | None = None,
                 fine_push_s: float = 0.3, coarse: float = 0.012, fine: float = 0.0025,
                 toe_clearance: float = 0.002, guess: Plan | None = None) -> Plan:
        """Countermovement and push-off from stance (``airborne_until`` None), or fall,
        landing and push-off from the air (``airborne_until`` = the pinned toe touchdown
        [s]), ending at lift-off after ``duration`` [s] with the COM's ballistic apex at
        ``apex_target`` [m]."""
        windows = [(duration - fine_push_s, duration + 1.0, fine)]
        if airborne_until is not None:
            windows.append((airborne_until - 0.03, airborne_until + 0.05, 0.001))
        grid = Grid.build(duration, coarse, windows)
        n = grid.n
        n_free = max(2, int(np.ceil(0.012 / fine)))   # the toe may rise in the last ~12 ms
        last_down = n - n_free
        cons = [Path('heel_vy', range(1, n + 1), -0.02, np.inf) if airborne_until is None
                else Path('heel_vy', range(grid.node_at(airborne_until + HEEL_DELAY_S
                                                        + 0.03), n + 1), -0.02, np.inf),
                Path('elastic', [n], -np.inf, 1.0),
                Path('com_vy', [n], 0.0, np.inf),
                Path('com_vx', [n], -0.02, 0.02),
                Path('apex', [n], apex_target, apex_target)]
        fixed = {('x', 0): x_start, ('u', 0): u_start}
        if airborne_until is None:
            cons.append(Path('toe_y', range(1, last_down), -np.inf, toe_clearance))
        else:
            # the heel is down from touchdown + HEEL_DELAY_S until the push (HEEL_OFF_S
            # before lift-off) lifts it
            cons += self._touchdown_constraints(grid, airborne_until, last_down,
                                                toe_clearance,
                                                grid.node_at(duration - HEEL_OFF_S))
        key = ('push', n, airborne_until is not None, round(duration, 6),
               round(airborne_until or 0.0, 6), float(apex_target))
        lo, hi = self._bounds()
        if airborne_until is None:
            lo['x0'] = hi['x0'] = np.asarray(anchors, dtype=float).reshape(2, 1)
        if guess is not None:
            g = self._resample(guess, grid)
        elif airborne_until is not None:
            g = self._landing_guess(grid, x_start, u_start, airborne_until)
        else:
            g = self._held_guess(grid, x_start, u_start, anchors)
        plan, _ = self._solve('push', key, grid, lambda: self._transcription(
            grid, cons, force_cost=airborne_until is not None), g, lo, hi, fixed,
            np.full(NX, np.nan))
        plan.facts = {'apex_target_m': apex_target, 'duration_s': duration, 'nodes': n + 1}
        return plan

    def landing(self, x_start: np.ndarray, u_start: np.ndarray, anchors_guess: np.ndarray,
                t_touchdown: float, duration: float, *, fine: float = 0.0015,
                medium: float = 0.004, coarse: float = 0.015, flight: float = 0.005,
                guess: Plan | None = None) -> Plan:
        """From a flight state: touchdown pinned at ``t_touchdown`` [s] (from the start),
        landing and recovery to the quiet-stance equilibrium at rest at ``duration`` [s]."""
        # the flight too on a medium grid: the toe's path decides when it lands; fine steps
        # through the toe's and the heel's touchdowns
        t_heel = t_touchdown + HEEL_DELAY_S
        grid = Grid.build(duration, coarse, [(0.0, t_touchdown - 0.01, flight),
                                             (t_touchdown - 0.01, t_heel + 0.04, fine),
                                             (t_heel + 0.04, t_touchdown + 0.35, medium)])
        n = grid.n
        st = self.stance
        cons = self._touchdown_constraints(grid, t_touchdown, n + 1, 0.002)
        # End: the quiet stance at rest (posture, activations; anywhere along x).
        x_end = np.r_[st.q[:4], -np.inf, st.q[5], np.zeros(6), st.a]
        fixed = {('x', 0): x_start, ('u', 0): u_start, ('u', n): st.u, ('qdd', n): np.zeros(6)}
        key = ('landing', n, round(duration, 4), round(t_touchdown, 4))
        lo, hi = self._bounds()
        g = (self._resample(guess, grid) if guess is not None
             else self._landing_guess(grid, x_start, u_start, t_touchdown))
        # the end state is fixed except r1 (free)
        plan, _ = self._solve('landing', key, grid, lambda: self._transcription(
            grid, cons, force_cost=True), g, lo, hi, fixed, x_end)
        plan.facts = {'t_touchdown_s': t_touchdown, 'duration_s': duration, 'nodes': n + 1}
        return plan

    def _solve(self, kind: str, key: tuple, grid: Grid, build: Callable[[], Transcription],
               guess: dict, lower: dict, upper: dict, fixed: dict,
               x_end: np.ndarray) -> tuple[Plan, Transcription]:
        """Solve on the (cached) transcription: ``fixed`` node-block values {(block, node):
        value}, ``x_end`` the end state where finite."""
        tr = solvers.get(self.model, ('routine', kind) + key, build)
        if not hasattr(tr, '_routine_solver'):
            tr._routine_solver = tr.solver(f'routine_{kind}', {
                'expand': True, 'print_time': False,
                'ipopt': {'tol': self.tol, 'max_iter': self.max_iter,
                          'print_level': self.print_level,
                          'sb': 'yes', 'mu_strategy': 'adaptive', 'linear_solver': 'mumps'}})
        lbx, ubx = tr.bounds(lower, upper)
        for (block, node), value in fixed.items():
            idx = tr.index(block)[node]
            scale = QDD_SCALE if block == 'qdd' else 1.0
            lbx[idx] = ubx[idx] = np.asarray(value, dtype=float) / scale
        end = tr.index('x')[grid.n]
        keep = np.isfinite(x_end)
        lbx[end[keep]] = ubx[end[keep]] = x_end[keep]
        z0 = np.clip(tr.pack(guess), lbx, ubx)
        c0 = time.process_time()
        sol = tr.solve(tr._routine_solver, z0, lbx=lbx, ubx=ubx)
        cpu = time.process_time() - c0
        v = tr.unpack(sol.z)
        plan = Plan(kind=kind, t=grid.t.copy(), x=v['x'], qdd=v['qdd'], u=v['u'],
                    anchors=v['x0'].ravel(), success=sol.success, status=sol.status,
                    iterations=sol.iterations, cpu_s=cpu)
        return plan, tr

    def _touchdown_constraints(self, grid: Grid, t_td: float, k_end: int,
                               clearance: float, k_end_heel: int | None = None) -> list:
        """Touchdowns pinned to nodes, as the hybrid simulation places anchors: the toe at
        t_td [s], the heel ``HEEL_DELAY_S`` later. Each point stays below the touchdown force
        before its node, is exactly at its anchor there (the anchor is where it lands), then
        within ``ANCHOR_SLIP_M`` of it and on the ground from ``SETTLE_S`` later, until node
        ``k_end`` (toe) or ``k_end_heel`` (heel; default ``k_end``), exclusive."""
        k_end_heel = k_end if k_end_heel is None else k_end_heel
        cons = []
        for point, t_p, k_last in (('toe', t_td, k_end), ('heel', t_td + HEEL_DELAY_S,
                                                           k_end_heel)):
            k_p = grid.node_at(t_p)
            k_down = grid.node_at(t_p + SETTLE_S)
            if k_p > 1:
                cons.append(Path(f'{point}_fy', range(1, k_p), -np.inf,
                                 contact_law.LIFTOFF_FORCE_N))
            cons += [Path(f'{point}_slip', [k_p], 0.0, 0.0),
                     Path(f'{point}_slip', range(k_p + 1, k_last), -ANCHOR_SLIP_M,
                          ANCHOR_SLIP_M),
                     Path(f'{point}_y', range(k_down, k_last), -np.inf, clearance)]
        return cons

    # ------------------------------------------------------------------ guesses
    def _held_guess(self, grid: Grid, x_start: np.ndarray, u_start: np.ndarray,
                    anchors: np.ndarray) -> dict:
        return {'x': np.tile(x_start, (grid.n + 1, 1)), 'qdd': 0.0,
                'u': np.tile(u_start, (grid.n + 1, 1)), 'x0': anchors.reshape(2, 1)}

    def _landing_guess(self, grid: Grid, x_start: np.ndarray, u_start: np.ndarray,
                       t_touchdown: float) -> dict:
        """Ballistic fall to the touchdown, a crouch, a return to stance (kinematic)."""
        st = self.stance
        t = grid.t
        g = self.model.p.gravity
        x = np.tile(st.x, (t.size, 1))
        r1 = x_start[4] + x_start[10] * np.minimum(t, t_touchdown)
        x[:, 4] = r1
        fly = t <= t_touchdown
        s = np.clip(t / t_touchdown, 0, 1)[:, None]
        x[fly, :4] = (1 - s[fly]) * x_start[:4] + s[fly] * st.q[:4]
        ballistic = x_start[5] + x_start[11] * t - g * t ** 2 / 2
        x[fly, 5] = np.maximum(ballistic[fly], st.q[5])
        dip = np.sin(np.pi * np.clip((t - t_touchdown) / 0.6, 0, 1)) ** 2
        knee = np.radians(25.0) * dip
        x[:, 2] += knee                 # thigh rotates back: knee flexes, trunk follows
        x[:, 3] += knee
        x[:, 5] -= 0.05 * dip
        x[:, 6:12] = np.gradient(x[:, :6], t, axis=0)
        qdd = np.gradient(x[:, 6:12], t, axis=0)
        anchors = self.stance.x0 + (r1[-1] - st.q[4])
        u = np.tile(st.u, (t.size, 1))
        u[0] = u_start
        return {'x': x, 'qdd': qdd, 'u': u, 'x0': anchors.reshape(2, 1)}

    def _resample(self, plan: Plan, grid: Grid) -> dict:
        """A previous plan as the guess on another grid (times scaled to the new duration)."""
        s = plan.t / plan.t[-1] * grid.t[-1]
        col = lambda a: np.column_stack([np.interp(grid.t, s, a[:, i])  # noqa: E731
                                         for i in range(a.shape[1])])
        return {'x': col(plan.x), 'qdd': col(plan.qdd), 'u': col(plan.u),
                'x0': plan.anchors.reshape(2, 1)}
