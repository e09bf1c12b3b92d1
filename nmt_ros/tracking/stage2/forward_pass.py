"""The forward pass: advancing the muscles over a plan's intervals (Eq. 14 -> Eq. 9 -> Eq. 8).

Saturation (``Stage2Settings.saturation``):

* 'clip' - the paper. On each interval [t_i, t_i+1] the LQT closed loop fdot = R^-1 (g - W f)
  is solved exactly from the ACTUAL force f_i (W frozen at the interval mean, g linear), giving
  the force f*_i+1 the LQT asks for. F is affine in a (F = a dF/da + F(0, l, v)), so f*_i+1
  fixes the activation a*_i+1, and the excitation held over the interval is the one for which
  the model's own activation ODE (solved exactly: linear in a for constant u) lands on a*_i+1 -
  Eq. 9 integrated over the interval (the instantaneous Eq. 9 value is returned as
  ``u_demand``). If it lies outside [0, 1], u is clipped, the muscles produce less than asked
  (the shortfall is recorded, ``SaturationReport``), and the feedback picks up from the actual
  force.
* 'plan' - the muscles the plan holds at a bound get that bound (their activation follows its
  exact step at u = 0 / 1); the free ones move by the discrete feedback law of the plan
  (activation step -> excitation as above; a target out of reach is still clipped and
  reported as unplanned).
"""
from __future__ import annotations

import numpy as np

from nmt_ros.tracking.stage2.activation import ActivationLaw, eq9_excitation
from nmt_ros.tracking.stage2.plans import WindowPlan
from nmt_ros.tracking.stage2.references import Stage2Reference
from nmt_ros.tracking.stage2.results import MuscleState, Stage2Step


def initial_state(ref: Stage2Reference, a0: np.ndarray) -> MuscleState:
    """Muscle state at the first reference sample from activations a0 [m]."""
    a0 = np.clip(np.asarray(a0, dtype=float), 0.0, 1.0)
    return MuscleState(index=ref.offset, t=float(ref.t[0]), a=a0,
                       f=a0 * ref.phi[0] + ref.psi[0])


def apply_plan(plan: WindowPlan, state: MuscleState, activation: ActivationLaw,
               f0: np.ndarray) -> tuple[MuscleState, Stage2Step]:
    """Advance the muscles over the plan's intervals (Eq. 14 -> Eq. 9 -> Eq. 8, exact).

    Each interval's LQT target (the force, hence activation, the feedback law asks for at
    the interval's end, from the actual state at its start) fixes the excitation held
    over the interval: the one whose exact activation step lands there (Eq. 9 integrated
    over the interval), clipped to [0, 1] if out of reach ('clip' plans: the paper's
    saturation; 'plan' plans: only what the plan did not foresee). Muscles a 'plan' plan
    holds at a bound get that bound. activation: the model's law; f0 [m] peak isometric
    forces (N), the scale of a vanishing dF/da.
    """
    if state.index != plan.start:
        raise ValueError(f'state at sample {state.index}, plan starts at {plan.start}')
    k, h, rows = plan.k, plan.h, plan.rows
    m = state.a.size
    a_out = np.empty((k + 1, m))
    f_out = np.empty((k + 1, m))
    u_out = np.empty((k, m))
    short = np.empty((k, m))
    saturated = np.zeros((k, m), dtype=bool)
    target = np.empty((k, m))
    phi, psi = rows['phi'], rows['psi']
    phi_safe = np.maximum(phi, 1e-9 * f0)
    a, f = state.a, state.f
    a_out[0], f_out[0] = a, f
    if plan.discrete is None:
        cl = plan.closed_loop
        r_s, r_is = plan.r_sqrt, plan.r_inv_sqrt
        # the LQT's target force of every interval's end, from the actual force at start
        gh = np.einsum('kji,kj->ki', cl['u'], plan.gt[:-1])
        gh1 = np.einsum('kji,kj->ki', cl['u'], plan.gt[1:])
        forcing = cl['hphi1'] * gh + cl['hphi2'] * (gh1 - gh)
        for i in range(k):
            ft = r_s @ f
            y1 = cl['decay'][i] * (ft @ cl['u'][i]) + forcing[i]
            target[i] = r_is @ (cl['u'][i] @ y1)
            a_star = (target[i] - psi[i + 1]) / phi_safe[i + 1]
            u_out[i], a, saturated[i] = activation.solve_step(a, a_star, h)
            f = a * phi[i + 1] + psi[i + 1]
            a_out[i + 1], f_out[i + 1] = a, f
        held = np.zeros((k, m), dtype=bool)
        ft = f_out[:k] @ r_s.T
        eta = (plan.gt[:k] - np.einsum('kij,kj->ki', plan.wt[:k], ft)) @ r_is.T
    else:
        dz = plan.discrete
        held = ~dz['free']
        u_bound = (plan.pattern > 0).astype(float)
        for i in range(k):
            v = dz['k'][i] - dz['K'][i] @ a
            a_star = np.where(held[i], dz['E'][i] * a + dz['c'][i], a + v)
            target[i] = a_star * phi[i + 1] + psi[i + 1]
            u, a_new, sat = activation.solve_step(a, a_star, h)
            if held[i].any():
                u = np.where(held[i], u_bound[i], u)
                a_new, _ = activation.step(a, u, h, derivative=False)
                sat = sat & ~held[i]
            u_out[i], saturated[i], a = u, sat, a_new
            f = a * phi[i + 1] + psi[i + 1]
            a_out[i + 1], f_out[i + 1] = a, f
        # the discrete Eq. 14: the force rate asked for over each interval
        eta = (target - f_out[:k]) / h
    short[:] = np.where(held, 0.0, np.abs(target - f_out[1:]))
    saturated |= held
    a_k = a_out[:k]
    drift, gain = activation.affine(a_k)
    dfdl = rows['dfdl_0'][:k] + a_k * (rows['dfdl_1'][:k] - rows['dfdl_0'][:k])
    dfdv = rows['dfdv_0'][:k] + a_k * (rows['dfdv_1'][:k] - rows['dfdv_0'][:k])
    u_demand = eq9_excitation(eta, phi_safe[:k], dfdl, dfdv, drift, gain, rows['v_mt'][:k],
                              rows['vdot_mt'][:k])
    new_state = MuscleState(index=plan.start + k, t=float(rows['t'][k]), a=a, f=f)
    return new_state, Stage2Step(start=plan.start, t=rows['t'][:k], a=a_k, f=f_out[:k],
                                 eta=eta, u=u_out, u_demand=u_demand, saturated=saturated,
                                 shortfall=short, W=plan.W[:k], g=plan.g[:k], planned=held)
