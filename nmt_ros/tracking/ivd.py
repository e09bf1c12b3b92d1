"""The inverse-dynamics (IVD) baseline (METHOD.md section 3) and its forward simulation.

Joint torques from the filtered observed segment angles (and their spline derivatives) and the
measured ground wrench applied to the foot, bottom-up (the residual wrench is left on the
HAT). Segment angles alone do not locate the foot: during contact the toe is taken as pinned
at its initial position (the usual "foot fixed on the plate" assumption), which gives the
ankle's position and its derivatives from the foot angle. The torques are then applied
open-loop in a forward simulation of the full model (contact springs included); the
field-default torques make it drift and leave the ground early (paper Fig. 3C).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import time

import numpy as np

from nmt_ros.model.jumper import JumperModel
from nmt_ros.model.simulation import simulate_torques
from nmt_ros.tracking.conditioning import ConditionedObservations
from nmt_ros.tracking.skeletal_tracker import SKTState


@dataclass
class IVDResult:
    """IVD torques on the observation grid and the open-loop forward simulation."""

    t: np.ndarray            # [n] s (force-plate instants during the observed contact)
    tau: np.ndarray          # [n, 3] N m
    residual: np.ndarray     # [n, 3] HAT residual wrench (N, N, N m)
    q: np.ndarray            # [n, 6] kinematics used (pinned toe)
    qd: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))   # [n, 6] their rates
    sim_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sim_q: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    sim_qd: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    sim_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sim_liftoff_s: float = float('nan')
    sim_status: str = ''
    cpu_s: float = 0.0


def pinned_toe_kinematics(model: JumperModel, theta: np.ndarray, theta_dot: np.ndarray,
                          theta_ddot: np.ndarray, toe_ground: np.ndarray,
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd [n, 6] with the toe point fixed at ``toe_ground`` (x, y) [m].

    r = p_toe - R(th1) c, with c the toe in the foot frame: rdot = -Rdot c, rddot = -Rddot c.
    """
    c = model.p.contact.points[1]
    th, w, al = theta[:, 0], theta_dot[:, 0], theta_ddot[:, 0]
    cs, sn = np.cos(th), np.sin(th)
    rc = np.column_stack([cs * c[0] - sn * c[1], sn * c[0] + cs * c[1]])   # R c
    prc = np.column_stack([-rc[:, 1], rc[:, 0]])                            # d(Rc)/dth
    r = toe_ground[None, :] - rc
    rd = -prc * w[:, None]
    rdd = -(prc * al[:, None] - rc * (w ** 2)[:, None])
    q = np.hstack([theta, r])
    qd = np.hstack([theta_dot, rd])
    qdd = np.hstack([theta_ddot, rdd])
    return q, qd, qdd


def inverse_dynamics_baseline(model: JumperModel, cond: ConditionedObservations,
                              initial: SKTState, rate_hz: float = 1080.0,
                              contact_threshold: float = 20.0) -> IVDResult:
    """IVD torques during the observed contact (filtered vertical force > threshold [N]).

    The first contact phase: from t = 0 when the trial starts loaded (the toe pinned where the
    initial state has it), else from the first loaded sample (a trial that starts in flight;
    the toe pinned on the ground at its anchor ``initial.x0``), to the next unloaded one.
    """
    c0 = time.process_time()
    t_all = np.arange(0, int(np.floor(cond.t_end * rate_hz + 1e-9)) + 1) / rate_hz
    fy = cond.wrench(t_all)[:, 1]
    loaded = fy > contact_threshold
    first = 0 if loaded[0] or not loaded.any() else int(np.argmax(loaded))
    rest = loaded[first:]
    n = first + (int(np.argmin(rest)) if not rest.all() else rest.size)
    t = t_all[first:max(n, first + 2)]
    smp = cond.sample(t)
    if first == 0:
        toe0 = np.asarray(model.call(model.positions, initial.q)[4])[:, 1]
    else:
        toe0 = np.array([float(initial.x0[1]), 0.0])
    q, qd, qdd = pinned_toe_kinematics(model, smp['theta'], smp['theta_dot'],
                                       smp['theta_ddot'], toe0)
    tau, resid = model.inverse_dynamics(q, qd, qdd, smp['s'], residual_at='hat')
    return IVDResult(t=t, tau=tau, residual=resid, q=q, qd=qd,
                     cpu_s=time.process_time() - c0)


def simulate_open_loop(model: JumperModel, result: IVDResult, initial: SKTState,
                       rate_hz: float = 1080.0, substeps: int = 4,
                       t_end: float | None = None, max_angle_deg: float = 120.0) -> IVDResult:
    """Forward simulation driven by the IVD torques (linear in time between samples).

    RK4 with ``substeps`` steps per sample (more at slow rates: ``simulate_torques``), from
    the tracker's initial state, or, when the torques begin later (a trial that starts in
    flight), from the IVD kinematics at their first sample. Ends at the end of the torques or
    when the model falls (a segment angle beyond ``max_angle_deg``).
    """
    t_end = float(result.t[-1]) if t_end is None else t_end

    def tau_at(t: float) -> np.ndarray:
        return np.array([np.interp(t, result.t, result.tau[:, j]) for j in range(3)])

    def fell(_t: float, y: np.ndarray) -> bool:
        return not np.isfinite(y).all() or np.degrees(np.abs(y[:4])).max() > max_angle_deg

    t0 = float(result.t[0])
    if t0 <= 0.0 or result.qd.shape[0] == 0:
        q0, qd0, t0 = initial.q, initial.qd, 0.0
    else:
        q0, qd0 = result.q[0], result.qd[0]
    sim = simulate_torques(model, q0, qd0, initial.x0, tau_at, t_end, rate_hz=rate_hz,
                           substeps=substeps, stop=fell, t0=t0)
    result.sim_t, result.sim_q, result.sim_qd = sim.t, sim.x[:, :6], sim.x[:, 6:]
    result.sim_s = sim.s
    result.sim_liftoff_s = sim.liftoff_s
    result.sim_status = 'completed' if sim.success else 'fell'
    return result
