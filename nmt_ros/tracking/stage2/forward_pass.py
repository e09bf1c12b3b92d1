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

import numba
import numpy as np

from nmt_ros.tracking.stage2.activation import (
    SATURATION_TOL,
    ActivationLaw,
    eq9_excitation,
)
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
        c = np.ascontiguousarray
        a, f = _feedback_pass(c(dz['K']), c(dz['k']), c(dz['E']), c(dz['c']), c(held),
                              c(plan.pattern > 0), c(phi), c(psi), a, float(h),
                              activation.d0, activation.d1, activation.g0, activation.g1,
                              a_out, f_out, u_out, saturated, target)
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


@numba.njit(cache=True)
def _activation_step(a0: float, u: float, h: float, d0: float, d1: float, g0: float,
                     g1: float) -> tuple[float, float]:
    """``ActivationLaw.step`` for one muscle: (a(h), d a(h) / d u)."""
    kappa = -(d1 + g1 * u)
    c0 = d0 + g0 * u
    a_inf = c0 / kappa
    decay = np.exp(-kappa * h)
    da_inf = (g0 * kappa + c0 * g1) / kappa ** 2
    return a_inf + (a0 - a_inf) * decay, da_inf * (1 - decay) + (a0 - a_inf) * h * g1 * decay


@numba.njit(cache=True)
def _feedback_pass(K: np.ndarray, k: np.ndarray, E: np.ndarray, c: np.ndarray,
                   held: np.ndarray, at_one: np.ndarray, phi: np.ndarray, psi: np.ndarray,
                   a: np.ndarray, h: float, d0: np.ndarray, d1: np.ndarray, g0: np.ndarray,
                   g1: np.ndarray, a_out: np.ndarray, f_out: np.ndarray, u_out: np.ndarray,
                   saturated: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 'plan' branch of ``apply_plan``, compiled (m = 9 per step: numpy's per-call
    overhead was ~90 % of it). Per interval i: free muscles get the feedback law's activation
    a* = a + k_i - K_i a, held ones their bound's step E a + c; the excitation held over the
    interval is the one whose exact activation step lands on a* (bracketed Newton, Eq. 9
    integrated, ``ActivationLaw.solve_step``), clipped if out of reach; held muscles get u = 0
    or 1. Fills a_out, f_out [k+1], u_out, saturated, target [k]; returns the final (a, f)."""
    n, m = k.shape
    a = a.copy()
    f = a * phi[0] + psi[0]
    a_star = np.empty(m)
    lo = np.empty(m)
    hi = np.empty(m)
    a_lo = np.empty(m)
    a_hi = np.empty(m)
    u = np.empty(m)
    tgt = np.empty(m)
    val = np.empty(m)
    der = np.empty(m)
    low = np.empty(m, dtype=np.bool_)
    high = np.empty(m, dtype=np.bool_)
    for i in range(n):
        for r in range(m):
            if held[i, r]:
                a_star[r] = E[i, r] * a[r] + c[i, r]
            else:
                v = k[i, r]
                for j in range(m):
                    v -= K[i, r, j] * a[j]
                a_star[r] = a[r] + v
            target[i, r] = a_star[r] * phi[i + 1, r] + psi[i + 1, r]
        # solve_step: all muscles iterate together until the largest residual is below tol
        for r in range(m):
            a_lo[r] = _activation_step(a[r], 0.0, h, d0[r], d1[r], g0[r], g1[r])[0]
            a_hi[r] = _activation_step(a[r], 1.0, h, d0[r], d1[r], g0[r], g1[r])[0]
            low[r] = a_star[r] < a_lo[r] - SATURATION_TOL
            high[r] = a_star[r] > a_hi[r] + SATURATION_TOL
            tgt[r] = min(max(a_star[r], a_lo[r]), a_hi[r])
            lo[r] = 0.0
            hi[r] = 1.0
            u[r] = min(max((tgt[r] - a_lo[r]) / max(a_hi[r] - a_lo[r], 1e-300), 0.0), 1.0)
        for _ in range(8):
            worst = 0.0
            for r in range(m):
                val[r], der[r] = _activation_step(a[r], u[r], h, d0[r], d1[r], g0[r], g1[r])
                worst = max(worst, abs(val[r] - tgt[r]))
            if worst < 1e-13:
                break
            for r in range(m):
                res = val[r] - tgt[r]
                if res > 0:
                    hi[r] = u[r]
                else:
                    lo[r] = u[r]
                newton = u[r] - res / (der[r] if der[r] > 0 else 1.0)
                u[r] = newton if lo[r] <= newton <= hi[r] else 0.5 * (lo[r] + hi[r])
        for r in range(m):
            if low[r]:
                u[r] = 0.0
            elif high[r]:
                u[r] = 1.0
            sat = low[r] or high[r]
            if held[i, r]:
                u[r] = 1.0 if at_one[i, r] else 0.0
                sat = False
            a[r] = _activation_step(a[r], u[r], h, d0[r], d1[r], g0[r], g1[r])[0]
            u_out[i, r] = u[r]
            saturated[i, r] = sat
            f[r] = a[r] * phi[i + 1, r] + psi[i + 1, r]
            a_out[i + 1, r] = a[r]
            f_out[i + 1, r] = f[r]
    return a, f
