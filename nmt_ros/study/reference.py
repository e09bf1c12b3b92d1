"""The "actual" maximum-height jump: parameter optimisation (PO) of 20 excitation nodes/muscle.

Paper (METHOD.md section 1.2): excitations at 20 nodes per muscle chosen to maximise jump
height from a static squat (ASA + SQP, 21,000 evaluations, > 24 h). Here: direct collocation
with exact derivatives (CasADi + IPOPT, the machinery of OpenSim Moco), following the
formulation known to converge for this kind of model (PO_NOTES.md):

* trapezoidal collocation on N intervals of a free final time t_f, implicit skeletal dynamics
  (accelerations are variables; M qdd - (I + S + T (tau_muscle + tau_pas)) = 0, rows scaled);
* excitations: 20 nodes per muscle, linear interpolation in normalised time t / t_f;
* objective: maximise the ballistic apex y_com(t_f) + vy_com(t_f)^2 / (2 g);
* path constraints: toe within ``toe_clearance`` of the ground before the last node (one
  push-off), heel vertical speed >= ``heel_min_vy`` (no slam), knee and hip only extend and the
  COM never moves down (no countermovement), vertical elastic ground force <= 1 N at t_f.

The optimiser's trajectory is only a candidate: the truth is the forward simulation of the
optimal excitations with a stiff integrator (``simulate_excitations``), accepted only if its
apex agrees with the optimiser's.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
import time

import casadi as ca
import numpy as np

from nmt_ros.model import contact as contact_law
from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.simulation import Simulation, simulate_excitations
from nmt_ros.model.squat import StaticSquat, solve_static_squat

NX = 21  # q[6], qd[6], a[9]
QDD_SCALE = 100.0  # rad/s^2 or m/s^2 per unit of an acceleration variable


@dataclass(frozen=True)
class POSettings:
    """Settings of the jump optimisation (defaults: the shipped reference)."""

    n_intervals: int = 100
    n_nodes: int = 20                 # excitation nodes per muscle (the paper's 20)
    tf_bounds: tuple[float, float] = (0.15, 0.40)  # s
    toe_clearance: float = 0.002      # m
    liftoff_fraction: float = 0.04    # last fraction of t_f in which the toe may rise
    heel_min_vy: float = -0.02        # m/s
    end_force_max: float = 1.0        # N, elastic vertical ground force at t_f
    # Tiny regularisation that makes the optimum unique: without it, idling in the squat
    # before the push (any duration) and muscles with no effect form flat directions.
    tf_weight: float = 0.01           # m of apex per s of t_f
    effort_weight: float = 1e-4       # m of apex per unit mean squared excitation node
    squat_joint_deg: tuple[float, float, float] = (25.0, -70.0, 80.0)
    tol: float = 1e-8
    max_iter: int = 3000
    print_level: int = 0


@dataclass
class POResult:
    """One optimisation: solution on the collocation grid and bookkeeping."""

    settings: POSettings
    success: bool
    status: str
    iterations: int
    cpu_s: float
    wall_s: float
    tf: float
    excitation_nodes: np.ndarray      # [9, n_nodes]
    t: np.ndarray                     # [N+1] s
    x: np.ndarray                     # [N+1, 21]
    qdd: np.ndarray                   # [N+1, 6]
    apex_m: float                     # ballistic COM apex predicted by the optimiser
    objective: float
    squat: StaticSquat = field(repr=False, default=None)

    def summary(self) -> dict:
        return {'success': self.success, 'status': self.status, 'iterations': self.iterations,
                'cpu_s': self.cpu_s, 'wall_s': self.wall_s, 'tf_s': self.tf,
                'apex_m': self.apex_m, 'settings': asdict(self.settings)}


def interpolation_matrix(n_nodes: int, tau: np.ndarray) -> np.ndarray:
    """Weights W [n_nodes, len(tau)] of linear interpolation at normalised times tau in [0, 1]."""
    nodes = np.linspace(0.0, 1.0, n_nodes)
    eye = np.eye(n_nodes)
    return np.stack([np.interp(tau, nodes, eye[i]) for i in range(n_nodes)])


def excitation_at(excitation_nodes: np.ndarray, tf: float, t: np.ndarray | float) -> np.ndarray:
    """u(t) [.., 9]: linear interpolation of the nodes over [0, tf], held after tf."""
    tau = np.clip(np.asarray(t, dtype=float) / tf, 0.0, 1.0)
    w = interpolation_matrix(excitation_nodes.shape[1], np.atleast_1d(tau))
    u = (excitation_nodes @ w).T
    return u[0] if np.ndim(t) == 0 else u


class JumpOptimizer:
    """Builds the NLP once for given settings; ``solve`` runs IPOPT from an initial guess."""

    def __init__(self, model: JumperModel, settings: POSettings = POSettings()) -> None:
        self.model = model
        self.settings = settings
        self.squat = solve_static_squat(model, settings.squat_joint_deg)
        self._build()

    def _node_function(self) -> ca.Function:
        """Per-node constraint expressions of the NLP (one definition, mapped over the grid)."""
        m = self.model
        p = m.p
        x = ca.SX.sym('x', NX)
        qdd = ca.SX.sym('qdd', 6)
        u = ca.SX.sym('u', 9)
        x0 = ca.DM(self.squat.x0)
        q, qd, a = x[:6], x[6:12], x[12:]
        tau_m = m.muscle_torques(q, qd, a)[0]
        residual = m.dynamics_residual(q, qd, qdd, tau_m, x0)
        scale = ca.DM([1 / 100.0] * 4 + [1 / p.body_weight] * 2)
        adot = m.activation_dynamics(u, a)
        pts = m.positions(q)[4]                     # [2 x 2]: heel, toe
        vel_pts = ca.jacobian(ca.vec(pts), q) @ qd  # [heel x, heel y, toe x, toe y]
        theta_dot = m.joint_angles(qd)
        com = m.com(q)
        vcom = m.com_velocity(q, qd)
        c = p.contact
        elastic = sum(c.k_y * c.delta * contact_law.softplus(-pts[1, i] / c.delta)
                      for i in range(2))
        out = [scale * residual, adot, pts[1, 1], vel_pts[1], theta_dot[1], theta_dot[2],
               vcom[1], com[1], elastic]
        return ca.Function('po_node', [x, qdd, u], [ca.vertcat(*out)])

    def _build(self) -> None:
        s = self.settings
        n = s.n_intervals
        g = self.model.p.gravity
        node = self._node_function()
        xs = ca.MX.sym('X', NX, n + 1)
        qdd_vars = ca.MX.sym('QDD', 6, n + 1)   # accelerations in units of QDD_SCALE
        qdds = QDD_SCALE * qdd_vars
        unodes = ca.MX.sym('U', 9, s.n_nodes)
        tf = ca.MX.sym('tf')
        w_interp = ca.DM(interpolation_matrix(s.n_nodes, np.linspace(0.0, 1.0, n + 1)))
        us = unodes @ w_interp
        out = node.map(n + 1, 'serial')(xs, qdds, us)
        res_dyn, adot = out[0:6, :], out[6:15, :]
        toe_y, heel_vy, knee_dot, hip_dot, vy_com, y_com, elastic = (out[15 + i, :]
                                                                     for i in range(7))
        xdot = ca.vertcat(xs[6:12, :], qdds, adot)
        h = tf / n
        colloc = xs[:, 1:] - xs[:, :-1] - 0.5 * h * (xdot[:, 1:] + xdot[:, :-1])

        g_list, lbg, ubg = [], [], []

        def add(expr: ca.MX, lo: float, hi: float) -> None:
            expr = ca.vec(expr)
            g_list.append(expr)
            lbg.append(np.full(expr.shape[0], lo))
            ubg.append(np.full(expr.shape[0], hi))

        add(colloc, 0.0, 0.0)
        add(res_dyn, 0.0, 0.0)
        # Path constraints from node 1 on: at node 0 the state is fixed, and a constraint with
        # no free variable breaks IPOPT's constraint qualification.
        # The toe stays down until the last ~4 % of the push: lift-off needs a few intervals
        # (a one-interval lift-off forces an arbitrary, mesh-dependent snap of the foot).
        n_free = max(1, round(n * s.liftoff_fraction))
        add(toe_y[:, 1:n + 1 - n_free], -np.inf, s.toe_clearance)
        add(heel_vy[:, 1:], s.heel_min_vy, np.inf)
        add(knee_dot[:, 1:], 0.0, np.inf)  # knee_angle (-flexion) only increases: extension
        add(hip_dot[:, 1:], -np.inf, 0.0)  # hip_flexion only decreases: extension
        add(vy_com[:, 1:], 0.0, np.inf)
        add(elastic[:, -1], -np.inf, s.end_force_max)

        apex = y_com[:, -1] + vy_com[:, -1] ** 2 / (2 * g)
        z = ca.vertcat(ca.vec(xs), ca.vec(qdd_vars), ca.vec(unodes), tf)
        self._shapes = (n, s.n_nodes)
        self._apex_fn = ca.Function('apex', [z], [apex])
        cost = (-apex + s.tf_weight * tf
                + s.effort_weight * ca.sumsqr(unodes) / unodes.numel())
        nlp = {'x': z, 'f': cost, 'g': ca.vertcat(*g_list)}
        opts = {'expand': True, 'print_time': False,
                'ipopt': {'tol': s.tol, 'max_iter': s.max_iter, 'print_level': s.print_level,
                          'mu_strategy': 'adaptive', 'linear_solver': 'mumps'}}
        self.solver = ca.nlpsol('jump_po', 'ipopt', nlp, opts)
        self._lbg = np.concatenate(lbg)
        self._ubg = np.concatenate(ubg)
        # Bounds on the variables.
        x_init = np.concatenate([self.squat.q, np.zeros(6), self.squat.a])
        lbx_x = np.tile(np.r_[np.full(6, -np.inf), np.full(6, -np.inf), np.zeros(9)], n + 1)
        ubx_x = np.tile(np.r_[np.full(6, np.inf), np.full(6, np.inf), np.ones(9)], n + 1)
        lbx_x[:NX] = x_init
        ubx_x[:NX] = x_init
        n_qdd = 6 * (n + 1)
        n_u = 9 * s.n_nodes
        self._lbx = np.concatenate([lbx_x, np.full(n_qdd, -np.inf), np.zeros(n_u),
                                    [s.tf_bounds[0]]])
        self._ubx = np.concatenate([ubx_x, np.full(n_qdd, np.inf), np.ones(n_u),
                                    [s.tf_bounds[1]]])
        self._x_init = x_init

    def held_squat_guess(self, tf: float = 0.3) -> np.ndarray:
        """Initial guess: the squat held still, excitations that hold it (PO_NOTES.md)."""
        n, k = self._shapes
        xs = np.tile(self._x_init, n + 1)
        us = np.tile(self.squat.u[:, None], (1, k)).T.ravel()
        return np.concatenate([xs, np.zeros(6 * (n + 1)), us, [tf]])

    def perturbed_guess(self, rng: np.random.Generator) -> np.ndarray:
        """A multi-start guess: held squat with random excitation nodes and final time."""
        z = self.held_squat_guess(tf=float(rng.uniform(*self.settings.tf_bounds)))
        n, k = self._shapes
        start = NX * (n + 1) + 6 * (n + 1)
        z[start:start + 9 * k] = rng.uniform(0.0, 1.0, 9 * k)
        return z

    def guess_from(self, result: POResult) -> np.ndarray:
        """Initial guess interpolated from another solution (mesh refinement/continuation)."""
        n, k = self._shapes
        tau_new = np.linspace(0.0, 1.0, n + 1)
        tau_old = result.t / result.tf
        xs = np.column_stack([np.interp(tau_new, tau_old, result.x[:, i]) for i in range(NX)])
        qdd = np.column_stack([np.interp(tau_new, tau_old, result.qdd[:, i])
                               for i in range(6)])
        nodes_old = np.linspace(0.0, 1.0, result.excitation_nodes.shape[1])
        nodes_new = np.linspace(0.0, 1.0, k)
        u = np.stack([np.interp(nodes_new, nodes_old, row) for row in result.excitation_nodes])
        return np.concatenate([xs.ravel(), qdd.ravel() / QDD_SCALE, u.T.ravel(), [result.tf]])

    def solve(self, z0: np.ndarray | None = None) -> POResult:
        z0 = self.held_squat_guess() if z0 is None else z0
        c0, w0 = time.process_time(), time.perf_counter()
        sol = self.solver(x0=z0, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        stats = self.solver.stats()
        z = np.asarray(sol['x']).ravel()
        n, k = self._shapes
        xs = z[:NX * (n + 1)].reshape(n + 1, NX)
        off = NX * (n + 1)
        qdd = z[off:off + 6 * (n + 1)].reshape(n + 1, 6) * QDD_SCALE
        off += 6 * (n + 1)
        unodes = z[off:off + 9 * k].reshape(k, 9).T
        tf = float(z[-1])
        return POResult(
            settings=self.settings, success=bool(stats['success']),
            status=str(stats['return_status']), iterations=int(stats['iter_count']),
            cpu_s=cpu, wall_s=wall, tf=tf, excitation_nodes=unodes,
            t=np.linspace(0.0, tf, n + 1), x=xs, qdd=qdd,
            apex_m=float(self._apex_fn(z)), objective=float(sol['f']), squat=self.squat)


@dataclass
class ReferenceJump:
    """The reference ("actual") jump: PO results, the shipped truth, and consistency checks."""

    po: POResult                    # the final (refined) optimisation
    starts: list[POResult]          # multi-start solutions on the coarse mesh
    coarse: POResult                # best coarse solution (refined into ``po``)
    simulation: Simulation          # forward simulation of the optimal excitations = truth
    checks: dict
    cpu_s: float                    # CPU of all optimisations (build + solves)
    wall_s: float

    def excitation(self, t: np.ndarray | float) -> np.ndarray:
        return excitation_at(self.po.excitation_nodes, self.po.tf, t)


def make_reference(model: JumperModel, settings: POSettings = POSettings(), starts: int = 5,
                   coarse_intervals: int = 50, seed: int = 0, truth_rate_hz: float = 1080.0,
                   flight_s: float = 0.05, progress: callable | None = None) -> ReferenceJump:
    """Multi-start PO on a coarse mesh, refinement on ``settings.n_intervals``, then the truth.

    The truth is the stiff forward simulation of the refined optimal excitations, sampled at
    ``truth_rate_hz`` from t = 0 to lift-off + ``flight_s``.
    """
    say = progress or (lambda _msg: None)
    c0, w0 = time.process_time(), time.perf_counter()
    coarse_settings = POSettings(**{**asdict(settings), 'n_intervals': coarse_intervals})
    say(f'building the NLP (N = {coarse_intervals})')
    opt_c = JumpOptimizer(model, coarse_settings)
    rng = np.random.default_rng(seed)
    results = []
    for k in range(starts):
        z0 = opt_c.held_squat_guess() if k == 0 else opt_c.perturbed_guess(rng)
        r = opt_c.solve(z0)
        say(f'start {k + 1}/{starts}: {r.status}, {r.iterations} iterations, '
            f'apex {r.apex_m:.5f} m, t_f {r.tf:.4f} s')
        results.append(r)
    ok = [r for r in results if r.success]
    if not ok:
        raise RuntimeError('no start of the jump optimisation converged: '
                           + ', '.join(r.status for r in results))
    best = max(ok, key=lambda r: r.apex_m)
    say(f'refining on N = {settings.n_intervals}')
    opt_f = JumpOptimizer(model, settings)
    po = opt_f.solve(opt_f.guess_from(best))
    if not po.success:
        raise RuntimeError(f'mesh refinement of the jump optimisation failed: {po.status}')
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0

    say('forward simulation of the optimal excitations (Radau)')
    x_init = po.x[0]
    exc = lambda t: excitation_at(po.excitation_nodes, po.tf, t)  # noqa: E731
    probe = simulate_excitations(model, x_init, opt_f.squat.x0, exc, po.tf + 0.1)
    if not np.isfinite(probe.liftoff_s):
        raise RuntimeError('the forward simulation of the optimal excitations never lifts off')
    t_end = np.floor((probe.liftoff_s + flight_s) * truth_rate_hz) / truth_rate_hz
    t_eval = np.arange(0, int(round(t_end * truth_rate_hz)) + 1) / truth_rate_hz
    sim = simulate_excitations(model, x_init, opt_f.squat.x0, exc, float(t_eval[-1]),
                               t_eval=t_eval)
    i_lo = int(np.searchsorted(probe.t, probe.liftoff_s))
    lo_state = probe.x[i_lo]
    height = model.jump_height(lo_state[:6], lo_state[6:12])
    apexes = np.array([r.apex_m for r in ok])
    # The optimiser's own trajectory vs the forward simulation (discretisation error).
    x_opt = np.column_stack([np.interp(sim.t, po.t, po.x[:, i]) for i in range(NX)])
    contact = sim.t <= min(probe.liftoff_s, po.tf)
    checks = {
        'starts': starts, 'starts_converged': len(ok),
        'start_apex_spread_m': float(apexes.max() - apexes.min()),
        'coarse_apex_m': best.apex_m, 'refined_apex_m': po.apex_m,
        'mesh_refinement_apex_change_m': float(po.apex_m - best.apex_m),
        'simulated_apex_m': height['apex_m'],
        'simulation_vs_optimiser_apex_m': float(height['apex_m'] - po.apex_m),
        'simulation_vs_optimiser_angle_max_deg': float(np.degrees(
            np.abs(sim.x[contact, :4] - x_opt[contact, :4]).max())),
        'jump_height_m': height['height_m'],
        'rise_from_squat_m': float(height['apex_m'] - model.call(model.com, x_init[:6])[0][1]),
        'liftoff_s': probe.liftoff_s, 'tf_s': po.tf,
    }
    sim.liftoff_s = probe.liftoff_s
    return ReferenceJump(po=po, starts=results, coarse=best, simulation=sim, checks=checks,
                         cpu_s=cpu, wall_s=wall)

