"""The jumper model assembled: one symbolic definition, compiled into CasADi functions.

``JumperModel`` builds every equation once from ``skeleton``, ``contact``, ``muscles``,
``paths`` and ``joint_limits`` and exposes them as ``casadi.Function`` objects (usable with
numbers, with SX/MX symbols inside an optimiser, and differentiable exactly), plus numpy
conveniences for batches of samples.

State and signal names (METHOD.md):
    q[6]   = [th1, th2, th3, th4, r1, r2]   (rad, m)     qd[6], qdd[6]
    tau[3] = joint torques [ankle, knee, hip] (N m)       theta_j[3] = OpenSim joint angles
    x0[2]  = ground x of the heel and toe anchors (m)     s[3] = contact outputs (N, N, N m)
    a[9], u[9] = activations, excitations               f[9] = musculotendon forces (N)
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from nmt_ros.model import contact, joint_limits, muscles, paths, skeleton
from nmt_ros.model.parameters import JumperParameters, load_parameters
from nmt_ros.model.point_map import PointMap

NQ = 6
NU = 3
NM = 9


class JumperModel:
    """Symbolic-once, numeric-everywhere model of the planar jumper (two legs lumped)."""

    def __init__(self, params: JumperParameters | None = None) -> None:
        self.p = params if params is not None else load_parameters()
        self.T = skeleton.T_MATRIX
        self._maps: dict[tuple[str, int], tuple[ca.Function, PointMap]] = {}
        self._build()

    # ------------------------------------------------------------------ symbolic build
    def _build(self) -> None:
        p = self.p
        q = ca.SX.sym('q', NQ)
        qd = ca.SX.sym('qd', NQ)
        qdd = ca.SX.sym('qdd', NQ)
        tau = ca.SX.sym('tau', NU)
        x0 = ca.SX.sym('x0', 2)
        a = ca.SX.sym('a', NM)
        u = ca.SX.sym('u', NM)
        self._sym = dict(q=q, qd=qd, qdd=qdd, tau=tau, x0=x0, a=a, u=u)

        kin = skeleton.kinematics(q, p)
        dyn = skeleton.dynamics(q, qd, p)
        theta = skeleton.joint_angles(q)
        theta_dot = skeleton.joint_angles(qd)
        T = ca.DM(self.T)

        # Contact (per point forces, generalized forces S, outputs s).
        forces = []
        gen_contact = ca.SX.zeros(NQ, 1)
        for i, pt in enumerate(kin.contact_points):
            vel = ca.jacobian(pt, q) @ qd
            f = contact.point_force(pt, vel, x0[i], p.contact)
            forces.append(f)
            gen_contact += skeleton.point_force_generalized(pt, q, f)
        s = contact.contact_outputs(kin.contact_points, forces, kin.com['foot'])
        tau_pas = joint_limits.passive_torques(theta, theta_dot, p.passive)
        com = skeleton.center_of_mass(q, p)

        # Eq. 1 pieces and forward dynamics: M qdd = I + S + T (tau + tau_pas).
        mass_matrix = dyn.mass_matrix
        rhs_free = dyn.inertial_gravity + gen_contact + T @ tau_pas  # M^-1 (.) = F part
        qdd_expr = ca.solve(mass_matrix, rhs_free + T @ tau)
        residual = mass_matrix @ qdd - rhs_free - T @ tau

        F = ca.Function
        self.positions = F('positions', [q], [
            kin.ankle, kin.knee, kin.hip, ca.horzcat(*kin.com.values()),
            ca.horzcat(*kin.contact_points), com],
            ['q'], ['ankle', 'knee', 'hip', 'coms', 'contact_points', 'com'])
        self.mass_matrix = F('mass_matrix', [q], [mass_matrix], ['q'], ['M'])
        self.inertial_gravity = F('I', [q, qd], [dyn.inertial_gravity], ['q', 'qd'], ['I'])
        self.contact_generalized = F('S', [q, qd, x0], [gen_contact], ['q', 'qd', 'x0'], ['S'])
        self.contact_forces = F('contact_forces', [q, qd, x0], [ca.horzcat(*forces)],
                                ['q', 'qd', 'x0'], ['F'])  # [2 x n_points]
        self.contact_outputs = F('s', [q, qd, x0], [s], ['q', 'qd', 'x0'], ['s'])
        self.passive_torques = F('tau_pas', [q, qd], [tau_pas], ['q', 'qd'], ['tau_pas'])
        self.forward_dynamics = F('forward_dynamics', [q, qd, tau, x0], [qdd_expr],
                                  ['q', 'qd', 'tau', 'x0'], ['qdd'])
        self.dynamics_residual = F('dynamics_residual', [q, qd, qdd, tau, x0], [residual],
                                   ['q', 'qd', 'qdd', 'tau', 'x0'], ['residual'])
        self.joint_angles = F('joint_angles', [q], [theta], ['q'], ['theta'])
        self.com = F('com', [q], [com], ['q'], ['com'])
        self.com_velocity = F('com_velocity', [q, qd], [ca.jacobian(com, q) @ qd],
                              ['q', 'qd'], ['com_velocity'])
        com_vel = ca.jacobian(com, q) @ qd
        self.com_acceleration = F('com_acceleration', [q, qd, qdd],
                                  [ca.jacobian(com_vel, q) @ qd + ca.jacobian(com, q) @ qdd],
                                  ['q', 'qd', 'qdd'], ['com_acceleration'])
        self.energy = F('energy', [q, qd],
                        [skeleton.mechanical_energy(q, qd, p)], ['q', 'qd'], ['E'])
        # Eq. 2a: Qd = F(Q) + G(Q) tau with F = [qd; M^-1 (I + S + T tau_pas)], G = [0; M^-1 T].
        m_inv_free = ca.solve(mass_matrix, rhs_free)
        m_inv_t = ca.solve(mass_matrix, T)
        self.drift_and_gain = F('drift_and_gain', [q, qd, x0],
                                [ca.vertcat(qd, m_inv_free), ca.vertcat(ca.DM.zeros(NQ, NU),
                                                                         m_inv_t)],
                                ['q', 'qd', 'x0'], ['F', 'G'])
        # Exact output Jacobians for Eq. 4 (ds/dQ) and for the trackers.
        self.contact_outputs_jacobian = F(
            'ds_dQ', [q, qd, x0], [s, ca.jacobian(s, q), ca.jacobian(s, qd)],
            ['q', 'qd', 'x0'], ['s', 'ds_dq', 'ds_dqd'])

        # Muscles (only if paths are present in the data file).
        self.has_muscles = set(p.muscles.paths) == set(p.muscles.names)
        if self.has_muscles:
            self._build_muscles(q, qd, tau, x0, a, u, theta, theta_dot, mass_matrix, rhs_free)

    def _build_muscles(self, q: ca.SX, qd: ca.SX, tau: ca.SX, x0: ca.SX, a: ca.SX, u: ca.SX,
                       theta: ca.SX, theta_dot: ca.SX, mass_matrix: ca.SX,
                       rhs_free: ca.SX) -> None:
        m = self.p.muscles
        F = ca.Function
        th = ca.SX.sym('theta', 3)
        thd = ca.SX.sym('theta_dot', 3)
        lmt_s = ca.SX.sym('l_mt', NM)
        vmt_s = ca.SX.sym('v_mt', NM)
        lmt_th = paths.musculotendon_lengths(th, m)
        r_th = paths.moment_arms(th, m)                      # [9 x 3]
        self.musculotendon_lengths = F('l_mt', [th], [lmt_th], ['theta'], ['l_mt'])
        self.moment_arms = F('moment_arms', [th], [r_th], ['theta'], ['r'])
        # C(theta) (3 x 9): tau = C f (Eq. 10b)
        self.moment_arm_matrix = F('C', [th], [r_th.T], ['theta'], ['C'])
        self.musculotendon_velocities = F('v_mt', [th, thd], [ca.jacobian(lmt_th, th) @ thd],
                                          ['theta', 'theta_dot'], ['v_mt'])
        f_expr = muscles.musculotendon_force(a, lmt_s, vmt_s, m)
        self.muscle_force = F('F_MT', [a, lmt_s, vmt_s], [f_expr], ['a', 'l_mt', 'v_mt'], ['f'])
        l_m, cos_alpha, v_m = muscles.fiber_kinematics(lmt_s, vmt_s, m)
        self.fiber_state = F('fiber', [lmt_s, vmt_s], [l_m, cos_alpha, v_m],
                             ['l_mt', 'v_mt'], ['l_m', 'cos_alpha', 'v_m'])
        # Eq. 9 pieces: fdot = dF/da adot + dF/dl l_mt_dot + dF/dv v_mt_dot,
        # adot = A_a + B_a u (elementwise); the partials are diagonal.
        drift_a, gain_a = muscles.activation_rate_affine(a, m)
        self.muscle_force_partials = F(
            'dF', [a, lmt_s, vmt_s],
            [f_expr, ca.diag(ca.jacobian(f_expr, a)), ca.diag(ca.jacobian(f_expr, lmt_s)),
             ca.diag(ca.jacobian(f_expr, vmt_s))],
            ['a', 'l_mt', 'v_mt'], ['f', 'dF_da', 'dF_dl', 'dF_dv'])
        self.activation_dynamics = F('adot', [u, a], [muscles.activation_rate(u, a, m)],
                                     ['u', 'a'], ['adot'])
        self.activation_affine = F('adot_affine', [a], [drift_a, gain_a], ['a'],
                                   ['drift', 'gain'])
        # Whole musculoskeletal system: state [q; qd; a], input u.
        lmt_q = self.musculotendon_lengths(theta)
        r_q = self.moment_arms(theta)
        vmt_q = -r_q @ theta_dot                     # l_mt_dot = -r theta_dot
        f_q = muscles.musculotendon_force(a, lmt_q, vmt_q, m)
        tau_m = r_q.T @ f_q
        self.muscle_torques = F('tau_muscle', [q, qd, a], [tau_m, f_q], ['q', 'qd', 'a'],
                                ['tau', 'f'])
        qdd_m = ca.solve(mass_matrix, rhs_free + ca.DM(self.T) @ tau_m)
        x = ca.vertcat(q, qd, a)
        xdot = ca.vertcat(qd, qdd_m, muscles.activation_rate(u, a, m))
        self.musculoskeletal_ode = F('ode', [x, u, x0], [xdot], ['x', 'u', 'x0'], ['xdot'])
        self.musculoskeletal_jacobian = F('ode_jac', [x, u, x0], [ca.jacobian(xdot, x)],
                                          ['x', 'u', 'x0'], ['dxdot_dx'])
        del tau

    # ------------------------------------------------------------------ numeric helpers
    def batch(self, fn: ca.Function, *args: np.ndarray) -> list[np.ndarray]:
        """Evaluate ``fn`` on n samples at once; args are [n, k] arrays (or [k] constants).

        Returns one array per output, [n, rows] for column outputs and [n, rows, cols] for
        matrices (``point_map.PointMap``: through the mapped function's buffers).
        """
        n = max(np.asarray(x).shape[0] for x in args if np.ndim(x) == 2)
        key = (fn.name(), id(fn))
        if key not in self._maps:
            self._maps[key] = (fn, PointMap(fn))    # fn kept: its id stays its own
        rows = [np.asarray(x, dtype=float) if np.ndim(x) == 2
                else np.broadcast_to(np.asarray(x, dtype=float), (n, np.size(x)))
                for x in args]
        return self._maps[key][1](*rows)

    def call(self, fn: ca.Function, *args: np.ndarray) -> list[np.ndarray]:
        """Evaluate ``fn`` once; returns numpy arrays (vectors flattened)."""
        outs = fn(*args)
        outs = outs if isinstance(outs, (list, tuple)) else [outs]
        res = []
        for k, o in enumerate(outs):
            arr = np.asarray(o)
            res.append(arr.ravel() if fn.size2_out(k) == 1 else arr)
        return res

    # ------------------------------------------------------------------ derived quantities
    @cached_property
    def ankle_height(self) -> float:
        """Height [m] of the ankle centre (r2) when the foot is at angle 0 and its lowest
        contact point touches the undeformed ground (y = 0): the standing pose's r2."""
        return -float(self.p.contact.points[:, 1].min())

    @cached_property
    def standing_com_height(self) -> float:
        """COM height [m] standing upright: all angles 0, foot points on the ground (y = 0)."""
        q = np.array([0, 0, 0, 0, 0, self.ankle_height], dtype=float)
        return float(self.call(self.com, q)[0][1])

    def anchors_at(self, q: np.ndarray) -> np.ndarray:
        """Contact anchors x0 [m] that make the horizontal springs unstretched at pose q."""
        pts = self.call(self.positions, q)[4]
        return np.asarray(pts)[0, :].copy()

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                         ground_wrench: np.ndarray, residual_at: str = 'hat',
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Joint torques from kinematics and a measured ground wrench on the foot.

        ``ground_wrench[n, 3]`` = [Fx, Fy, moment about the foot COM] (the outputs s) applied
        to the foot. Solves, per sample, the 6 equations of Eq. 1 for tau (3) and a residual
        wrench (3): ``residual_at='hat'`` puts the residual on the HAT (bottom-up inverse
        dynamics, the baseline of METHOD.md section 3); ``'foot'`` puts residual generalized
        forces on the foot's coordinates (th1, r1, r2), as OpenSim's InverseDynamicsTool does
        with the foot as the root (top-down). Returns (tau [n, 3], residual [n, 3]).
        """
        q, qd, qdd, w = (np.atleast_2d(np.asarray(x, dtype=float))
                         for x in (q, qd, qdd, ground_wrench))
        n = q.shape[0]
        mass, = self.batch(self.mass_matrix, q)
        inert, = self.batch(self.inertial_gravity, q, qd)
        tau_pas, = self.batch(self.passive_torques, q, qd)
        jac_foot, jac_hat = self._com_jacobians(q)
        q_ext = np.einsum('nij,ni->nj', jac_foot, w[:, :2])
        q_ext[:, 0] += w[:, 2]
        rhs = (np.einsum('nij,nj->ni', mass, qdd) - inert - q_ext
               - tau_pas @ self.T.T)
        basis = np.zeros((n, NQ, 6))
        basis[:, :, :3] = self.T
        if residual_at == 'hat':
            basis[:, :, 3:5] = np.transpose(jac_hat, (0, 2, 1))
            basis[:, 3, 5] += 1.0
        elif residual_at == 'foot':
            basis[:, [0, 4, 5], [3, 4, 5]] = 1.0
        else:
            raise ValueError(f"residual_at must be 'hat' or 'foot', not {residual_at!r}")
        sol = np.linalg.solve(basis, rhs[..., None])[..., 0]
        return sol[:, :3], sol[:, 3:]

    @cached_property
    def _com_jacobian_fn(self) -> ca.Function:
        q = self._sym['q']
        kin = skeleton.kinematics(q, self.p)
        return ca.Function('com_jacobians', [q], [ca.jacobian(kin.com['foot'], q),
                                                  ca.jacobian(kin.com['hat'], q)])

    def _com_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians [n, 2, 6] of the foot and HAT COMs."""
        jf, jh = self.batch(self._com_jacobian_fn, q)
        return jf, jh

    def jump_height(self, q_liftoff: np.ndarray, qd_liftoff: np.ndarray) -> dict[str, float]:
        """Ballistic apex of the COM from the state at lift-off.

        Returns ``apex_m`` (COM apex height), ``height_m`` (apex minus the standing-upright
        COM height: the project's jump height) and ``vy_m_s`` (vertical COM speed).
        """
        com = self.call(self.com, q_liftoff)[0]
        vel = self.call(self.com_velocity, q_liftoff, qd_liftoff)[0]
        g = self.p.gravity
        apex = com[1] + max(vel[1], 0.0) ** 2 / (2 * g)
        return {'apex_m': float(apex), 'height_m': float(apex - self.standing_com_height),
                'vy_m_s': float(vel[1]), 'com_y_m': float(com[1])}


_DEFAULT: JumperModel | None = None


def default_model() -> JumperModel:
    """The model built from the shipped data file (built once per process)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = JumperModel()
    return _DEFAULT
