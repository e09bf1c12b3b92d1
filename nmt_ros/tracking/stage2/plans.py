"""Window plans: what the LQT asks of the muscles over one window of the reference.

Two modes share the recipe: full horizon (the paper: one plan over [0, tf]) and receding
windows of length H (a plan per window start t_k with P = 0 at t_k + H, applied over
[t_k, t_k + stride)). A plan is made either

* 'clip' (the paper's LQT): Eqs. 12-13 by the exact-step sweep (``lqt.backward_sweep``), with
  the exact closed-loop step data of Eq. 14 per interval; the plans of all window starts do
  not depend on the muscle state and are swept together; or
* 'plan' (saturation-aware, DEPARTS FROM THE PAPER): (1) the bounded LQT (``bounded_qp``:
  Eq. 11 on the internal grid with every activation step between the exact steps at u = 0
  and u = 1, a convex QP) from the current activations decides which
  muscles sit at u = 0 / 1 over which intervals (its active set); (2) the discrete LQT of that
  active set (``lqt.discrete_lqt``: Riccati, adjoint and feedback law of the same discretised
  Eq. 11) - the held muscles' forces enter as known inputs of their own activation dynamics,
  only the free muscles are optimised. Each plan depends on the activations its window starts
  from, so windows are planned one after the other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmt_ros.tracking.stage2 import lqt
from nmt_ros.tracking.stage2.activation import ActivationLaw
from nmt_ros.tracking.stage2.bounded_qp import (
    BoundedLqtQp,
    BoundedLqtSolution,
    bounded_lqt_qp,
    interior_point,
)
from nmt_ros.tracking.stage2.references import Stage2Reference
from nmt_ros.tracking.stage2.settings import Stage2Settings


@dataclass(frozen=True)
class WindowPlan:
    """What the live tracker needs to advance the muscles over intervals [start, start + k].

    W, g of Eqs. 12-13 (scaled: Wt = R^-1/2 W R^-1/2, gt = R^-1/2 g) at the k + 1 samples,
    and the reference rows. ``horizon_end`` = global index of the sample where this plan's
    backward sweep started (P = 0 there).

    'clip' plans (the paper's LQT): ``closed_loop`` holds the exact closed-loop step data of
    the k intervals. Saturation-aware plans ('plan'): ``discrete`` holds the discrete LQT in
    activation coordinates over the plan's active set - per interval the feedback K [k, m, m],
    k [k, m] (a free muscle's activation step is v = k - K a), and the step a_i+1 = E a_i +
    B v + c (E [k, m], c [k, m], free [k, m]: B = diag(free)); ``pattern`` [k, m] is +1 / -1
    where the muscle is held at u = 1 / 0, 0 where free. W, g are then the discrete ones,
    converted to force units with dF/da.
    """

    start: int
    horizon_end: int
    h: float
    wt: np.ndarray           # [k+1, m, m]
    gt: np.ndarray           # [k+1, m]
    r_sqrt: np.ndarray       # [m, m]
    r_inv_sqrt: np.ndarray   # [m, m]
    closed_loop: dict[str, np.ndarray]
    rows: dict[str, np.ndarray]
    discrete: dict[str, np.ndarray] | None = None
    pattern: np.ndarray | None = None   # [k, m] int8
    plan_iterations: int = 0            # interior-point iterations of the bounded LQT
    plan_cost: float = float('nan')     # its cost (discretised Eq. 11) over the horizon
    plan_converged: bool = True         # the interior point met its tolerance

    @property
    def k(self) -> int:
        return self.wt.shape[0] - 1

    @property
    def W(self) -> np.ndarray:
        """W [k+1, m, m] (physical units)."""
        return self.r_sqrt @ self.wt @ self.r_sqrt

    @property
    def g(self) -> np.ndarray:
        """g [k+1, m] (physical units)."""
        return self.gt @ self.r_sqrt.T


class WindowPlanner:
    """Makes ``WindowPlan``s for one set of settings, LQT weights and muscles."""

    def __init__(self, settings: Stage2Settings, Q: np.ndarray, R: np.ndarray, P: np.ndarray,
                 f0: np.ndarray, activation: ActivationLaw) -> None:
        """Q [3, 3], R diagonal [m], P [3, 3] of Eq. 11; f0 [m] peak isometric forces (N);
        the force term K_f from ``settings.k_f`` (``lqt.with_force_term``)."""
        self.settings = settings
        self.Q, self.R, self.P = Q, R, P
        self.k_force = settings.force_weight(f0)
        self.f0 = f0
        self.activation = activation

    @property
    def constrained(self) -> bool:
        """True for the saturation-aware LQT (``settings.saturation == 'plan'``)."""
        return self.settings.saturation == 'plan'

    def window_samples(self, ref: Stage2Reference, window_length: float | None = None,
                       window_stride: float | None = None) -> tuple[int, int]:
        """(window length, stride) in intervals of the reference's (internal) grid, from
        lengths in s (default: the settings')."""
        return self.window_intervals(ref.grid.h, ref.substeps, window_length, window_stride)

    def window_intervals(self, h: float, substeps: int, window_length: float | None = None,
                         window_stride: float | None = None) -> tuple[int, int]:
        """(window length, stride) in intervals of an internal grid of step h [s] with
        ``substeps`` intervals per input interval, from lengths in s (default: the
        settings')."""
        length_s = self.settings.window_length if window_length is None else window_length
        stride_s = self.settings.window_stride if window_stride is None else window_stride
        length = max(1, int(round(length_s / h)))
        stride = substeps if stride_s is None else max(1, int(round(stride_s / h)))
        if stride > length:
            raise ValueError(f'window stride ({stride} samples) exceeds its length ({length})')
        return length, stride

    def clip_plans(self, ref: Stage2Reference, starts: np.ndarray, length: int, stride: int,
                   final: bool = False) -> list[WindowPlan]:
        """Receding-horizon plans for global window starts, batched ('clip' mode only: a
        saturation-aware plan depends on the muscle state at its start, see ``plan``).

        Each window needs the reference up to start + length; with ``final`` (end of the
        recording) windows may end at the last sample instead.
        """
        if self.constrained:
            raise ValueError("saturation='plan': plan each window from its state (plan)")
        starts = np.atleast_1d(np.asarray(starts, dtype=int))
        if starts.size == 0:
            return []
        if starts.min() < ref.offset:
            raise ValueError('window starts before the kept reference')
        if not final and starts.max() + length > ref.end:
            raise ValueError('window needs reference samples not received yet')
        return self._clip_plans(ref, starts, length, stride)

    def _clip_plans(self, ref: Stage2Reference, starts: np.ndarray, length: int, stride: int,
                    ) -> list[WindowPlan]:
        """Unconstrained plans ('clip' mode): one batched sweep for all window starts."""
        local = np.asarray(starts, dtype=int) - ref.offset
        wt, gt = lqt.backward_sweep(ref.grid, local, length, min(stride, length) + 1)
        ends = np.minimum(local + length, ref.n - 1)
        ks = np.minimum(stride, ends - local)
        cl = lqt.closed_loop_coefficients(wt, ref.grid.h)
        plans = []
        for j, (s, k) in enumerate(zip(local, ks)):
            plans.append(WindowPlan(
                start=int(s + ref.offset), horizon_end=int(ends[j] + ref.offset), h=ref.grid.h,
                wt=wt[j, :k + 1], gt=gt[j, :k + 1], r_sqrt=ref.grid.r_sqrt,
                r_inv_sqrt=ref.grid.r_inv_sqrt,
                closed_loop={name: arr[j, :k] for name, arr in cl.items()},
                rows=ref.rows(int(s + ref.offset), int(s + k + 1 + ref.offset))))
        return plans

    def bounded_qp(self, ref: Stage2Reference, a0: np.ndarray, start: int,
                   stop: int) -> BoundedLqtQp:
        """The QP of the bounded LQT (Eq. 11 with 0 <= u <= 1) on global samples
        [start, stop] from the activations a0 [m].

        Discrete Eq. 11 on the internal grid, activations as unknowns, each step between the
        exact activation steps at u = 0 and u = 1 (``bounded_qp.bounded_lqt_qp``).
        """
        r = ref.rows(start, stop + 1)
        s = slice(start - ref.offset, stop + 1 - ref.offset)
        lo, hi = self.activation.bounds(ref.grid.h)
        C_y, y_ref, Q_y, P_y = lqt.with_force_term(r['C'], r['tau_ref'], self.Q, self.P,
                                                   self.k_force)
        return bounded_lqt_qp(ref.grid.h, C_y, y_ref, Q_y, self.R, ref.phi[s], ref.psi[s], a0,
                              lo, hi, P=P_y)

    def bounded_plan(self, ref: Stage2Reference, a0: np.ndarray, start: int,
                     stop: int) -> BoundedLqtSolution:
        """The bounded LQT on global samples [start, stop] from the activations a0 [m]
        (``bounded_qp``, solved by ``bounded_qp.interior_point``)."""
        st = self.settings
        return interior_point(self.bounded_qp(ref, a0, start, stop), tol=st.plan_tol,
                              max_iterations=st.plan_max_iterations)

    def plan(self, ref: Stage2Reference, start: int, a: np.ndarray, length: int,
             stride: int) -> WindowPlan:
        """The plan of the window starting at global sample ``start`` with activations a [m]
        (its horizon: ``length`` intervals or up to the last sample; applied over ``stride``
        intervals).

        'clip' mode: the paper's LQT on the window. 'plan' mode, the saturation-aware LQT:
        (1) the bounded LQT (``bounded_plan``) from the current activations decides which
        muscles sit at u = 0 / 1 over which intervals (its active set); (2) the discrete LQT
        (``lqt.discrete_lqt``: Riccati, adjoint and feedback law of the same discretised
        Eq. 11) over that active set - the held muscles' forces enter as known inputs of
        their own activation dynamics, only the free muscles are optimised. (The forward pass
        then holds the saturated muscles at their bound and moves the free ones by the
        feedback law, ``forward_pass.apply_plan``.)
        """
        stop = min(start + length, ref.end)
        if start < ref.offset or stop <= start:
            raise ValueError('window outside the kept reference')
        if not self.constrained:
            return self._clip_plans(ref, np.array([start]), length, stride)[0]
        qp = self.bounded_plan(ref, a, start, stop)
        pos = qp.position()
        margin = self.settings.saturation_margin
        pattern = np.where(pos >= 1 - margin, 1, np.where(pos <= margin, -1, 0)).astype(np.int8)
        h = ref.grid.h
        E, c = self.activation.held_steps(pattern, h)
        free = pattern == 0
        rows = ref.rows(start, stop + 1)
        sl = slice(start - ref.offset, stop + 1 - ref.offset)
        phi, psi = ref.phi[sl], ref.psi[sl]
        C_y, y_ref, Q_y, P_y = lqt.with_force_term(rows['C'], rows['tau_ref'], self.Q,
                                                   self.P, self.k_force)
        dl = lqt.discrete_lqt(h, C_y, y_ref, Q_y, self.R, phi, psi, E, free, c, P=P_y)
        k = min(stride, stop - start)
        # W, g in force units (f = phi a + psi) for the output
        ph = np.maximum(np.abs(phi[:k + 1]), 1e-9 * self.f0) * np.where(phi[:k + 1] < 0, -1, 1)
        W = dl.S[:k + 1] / (ph[:, :, None] * ph[:, None, :])
        g = (dl.s[:k + 1] + np.einsum('kij,kj->ki', dl.S[:k + 1], psi[:k + 1] / ph)) / ph
        r_is = ref.grid.r_inv_sqrt
        return WindowPlan(start=start, horizon_end=stop, h=h, wt=r_is @ W @ r_is,
                          gt=g @ r_is.T, r_sqrt=ref.grid.r_sqrt, r_inv_sqrt=r_is,
                          closed_loop={}, rows={name: arr[:k + 1] for name, arr in rows.items()},
                          discrete={'K': dl.K[:k], 'k': dl.k[:k], 'E': E[:k], 'c': c[:k],
                                    'free': free[:k]},
                          pattern=pattern[:k], plan_iterations=qp.iterations,
                          plan_cost=qp.cost, plan_converged=qp.converged)
