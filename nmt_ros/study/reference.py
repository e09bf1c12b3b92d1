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
from nmt_ros.tracking.collocation import (
    QDD_SCALE,
    Block,
    Defect,
    Interpolated,
    NodeSum,
    Path,
    Transcription,
    dynamics_residual,
)

NX = 21  # q[6], qd[6], a[9]


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
    """Builds the NLP once for given settings; ``solve`` runs IPOPT from an initial guess.

    The NLP is the collocation transcription (``tracking.collocation``) of: nodes x = [q, qd,
    a] and scaled accelerations, globals the excitation nodes [9, n_nodes] and t_f; the
    excitations at the grid nodes interpolated from the excitation nodes.
    """

    def __init__(self, model: JumperModel, settings: POSettings = POSettings()) -> None:
        self.model = model
        self.settings = settings
        self.squat = solve_static_squat(model, settings.squat_joint_deg)
        self._build()

    def _node(self, v: dict[str, ca.SX]) -> dict[str, ca.SX]:
        """What the NLP needs at one node (one definition, mapped over the grid)."""
        m = self.model
        p = m.p
        x0 = ca.DM(self.squat.x0)
        x, qdd, u = v['x'], v['qdd'], v['u']
        q, qd, a = x[:6], x[6:12], x[12:]
        tau_m = m.muscle_torques(q, qd, a)[0]
        pts = m.positions(q)[4]                     # [2 x 2]: heel, toe
        vel_pts = ca.jacobian(ca.vec(pts), q) @ qd  # [heel x, heel y, toe x, toe y]
        theta_dot = m.joint_angles(qd)
        com = m.com(q)
        vcom = m.com_velocity(q, qd)
        c = p.contact
        return {
            'residual': dynamics_residual(m, q, qd, qdd, tau_m, x0),          # Eq. 1
            'xdot': ca.vertcat(qd, qdd, m.activation_dynamics(u, a)),         # Eq. 8
            'toe_y': pts[1, 1], 'heel_vy': vel_pts[1],
            'knee_rate': theta_dot[1], 'hip_rate': theta_dot[2], 'com_vy': vcom[1],
            'elastic': sum(c.k_y * c.delta * contact_law.softplus(-pts[1, i] / c.delta)
                           for i in range(2)),
            'apex': com[1] + vcom[1] ** 2 / (2 * p.gravity),   # ballistic apex of the COM
        }

    def _build(self) -> None:
        s = self.settings
        n = s.n_intervals
        after_start = range(1, n + 1)
        # Path constraints from node 1 on: at node 0 the state is fixed, and a constraint with
        # no free variable breaks IPOPT's constraint qualification.
        # The toe stays down until the last ~4 % of the push: lift-off needs a few intervals
        # (a one-interval lift-off forces an arbitrary, mesh-dependent snap of the foot).
        n_free = max(1, round(n * s.liftoff_fraction))
        last = np.zeros(n + 1)
        last[n] = -1.0                                 # maximise the apex at t_f
        self.transcription = tr = Transcription(
            n, 'tf', [Block('x', NX), Block('qdd', 6, scale=QDD_SCALE)], self._node,
            [Defect('x', 'xdot'), Path('residual'),
             Path('toe_y', range(1, n + 1 - n_free), -np.inf, s.toe_clearance),
             Path('heel_vy', after_start, s.heel_min_vy, np.inf),
             Path('knee_rate', after_start, 0.0, np.inf),   # knee_angle (-flexion) increases
             Path('hip_rate', after_start, -np.inf, 0.0),   # hip_flexion decreases: extension
             Path('com_vy', after_start, 0.0, np.inf),
             Path('elastic', [n], -np.inf, s.end_force_max)],
            costs=[NodeSum('apex', last)],
            global_blocks=[Block('u_nodes', 9, s.n_nodes), Block('tf', 1)],
            interpolated=[Interpolated('u', 'u_nodes', interpolation_matrix(
                s.n_nodes, np.linspace(0.0, 1.0, n + 1)))],
            quadratic_cost=lambda var, _par: (
                s.tf_weight * var['tf'] + s.effort_weight * ca.sumsqr(var['u_nodes'])
                / var['u_nodes'].numel()))
        self._apex_fn = ca.Function('apex', [tr.z], [tr.values['apex'][:, -1]])
        self.solver = tr.solver('jump_po', {
            'expand': True, 'print_time': False,
            'ipopt': {'tol': s.tol, 'max_iter': s.max_iter, 'print_level': s.print_level,
                      'mu_strategy': 'adaptive', 'linear_solver': 'mumps'}})
        self._x_init = np.concatenate([self.squat.q, np.zeros(6), self.squat.a])
        a_lo, a_hi = np.r_[np.full(12, -np.inf), np.zeros(9)], np.r_[np.full(12, np.inf),
                                                                     np.ones(9)]
        self._lbx, self._ubx = tr.bounds(
            {'x': a_lo, 'u_nodes': 0.0, 'tf': s.tf_bounds[0]},
            {'x': a_hi, 'u_nodes': 1.0, 'tf': s.tf_bounds[1]})
        start = tr.index('x')[0]                       # the squat at t = 0
        self._lbx[start] = self._ubx[start] = self._x_init

    def held_squat_guess(self, tf: float = 0.3) -> np.ndarray:
        """Initial guess: the squat held still, excitations that hold it (PO_NOTES.md)."""
        return self.transcription.pack({
            'x': self._x_init, 'qdd': 0.0,
            'u_nodes': np.tile(self.squat.u[:, None], (1, self.settings.n_nodes)), 'tf': tf})

    def perturbed_guess(self, rng: np.random.Generator) -> np.ndarray:
        """A multi-start guess: held squat with random excitation nodes and final time."""
        z = self.held_squat_guess(tf=float(rng.uniform(*self.settings.tf_bounds)))
        idx = self.transcription.index('u_nodes')
        z[idx.ravel(order='F')] = rng.uniform(0.0, 1.0, idx.size)
        return z

    def guess_from(self, result: POResult) -> np.ndarray:
        """Initial guess interpolated from another solution (mesh refinement/continuation)."""
        tr = self.transcription
        tau_new = np.linspace(0.0, 1.0, tr.nodes)
        tau_old = result.t / result.tf
        xs = np.column_stack([np.interp(tau_new, tau_old, result.x[:, i]) for i in range(NX)])
        qdd = np.column_stack([np.interp(tau_new, tau_old, result.qdd[:, i])
                               for i in range(6)])
        nodes_old = np.linspace(0.0, 1.0, result.excitation_nodes.shape[1])
        nodes_new = np.linspace(0.0, 1.0, self.settings.n_nodes)
        u = np.stack([np.interp(nodes_new, nodes_old, row) for row in result.excitation_nodes])
        return tr.pack({'x': xs, 'qdd': qdd, 'u_nodes': u, 'tf': result.tf})

    def solve(self, z0: np.ndarray | None = None) -> POResult:
        z0 = self.held_squat_guess() if z0 is None else z0
        tr = self.transcription
        c0, w0 = time.process_time(), time.perf_counter()
        sol = tr.solve(self.solver, z0, lbx=self._lbx, ubx=self._ubx)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        v = tr.unpack(sol.z)
        tf = float(v['tf'][0, 0])
        return POResult(
            settings=self.settings, success=sol.success, status=sol.status,
            iterations=sol.iterations, cpu_s=cpu, wall_s=wall, tf=tf,
            excitation_nodes=v['u_nodes'], t=np.linspace(0.0, tf, tr.nodes), x=v['x'],
            qdd=v['qdd'], apex_m=float(self._apex_fn(sol.z)), objective=sol.f,
            squat=self.squat)


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

