"""Feedback through the excitations: linear-quadratic regulators of the musculoskeletal model.

The routines' truth is the forward simulation of the model (Eq. 1 + 8) driven by excitations
u(t, x) = clip(u_ff(t) + K(t) (x_ref(t) - x) + n(t), 0, 1): planned excitations ``u_ff`` and
states ``x_ref`` (a collocation plan, or an equilibrium), a state feedback ``K`` that keeps the
model on them over long stances and through landings, and an optional small exploratory input
``n`` (postural sway). Whatever the model then does is the truth.

* ``linearize``: A = df/dx [21 x 21], B = df/du [21 x 9] of xdot = f(x, u, x0) (exact, CasADi).
* ``lqr``: the continuous-time infinite-horizon gain (scipy's CARE), for stance.
* ``tvlqr``: a time-varying gain along a plan, by the discrete Riccati recursion on the plan's
  nodes (zero-order hold of u over each interval, matrix exponential), ending on the stance
  regulator's cost-to-go so the hand-over at the plan's end is seamless.
* ``FeedbackLaw``: u(t, x) as above, with its Jacobian du/dx for the stiff integrator.

Weights are on joint coordinates (``joint_weights``): the segment angles enter as ankle, knee,
hip and foot tilt, so a stance regulator can be stiff at knee and hip and compliant at the
ankle (ankle strategy).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
import scipy.linalg as sl

from nmt_ros.model.jumper import JumperModel

NX = 21
NU = 9


def linearize(model: JumperModel, x: np.ndarray, u: np.ndarray,
              x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A [21, 21], B [21, 9]) of xdot = f(x, u, x0) at (x, u) with anchors x0 [m]."""
    a_mat = np.asarray(model.musculoskeletal_jacobian(x, u, x0))
    m = model.p.muscles
    beta = m.tau_act / m.tau_deact
    b_mat = np.zeros((NX, NU))
    b_mat[12:, :] = np.diag((1.0 - (1.0 - beta) * np.asarray(x)[12:]) / m.tau_act)
    return a_mat, b_mat


def joint_weights(foot: float, ankle: float, knee: float, hip: float, r1: float, r2: float,
                  speed_scale: float, activation: float) -> np.ndarray:
    """State weight Q [21, 21] penalising foot tilt, joint angles and the ankle position
    (per rad^2, m^2) and their rates (``speed_scale`` [s^2] times the same), activations."""
    # rows: foot tilt th1, ankle th1 - th2, knee th2 - th3, hip th3 - th4, r1, r2
    t = np.zeros((6, 6))
    t[0, 0] = 1.0
    t[1, 0], t[1, 1] = 1.0, -1.0
    t[2, 1], t[2, 2] = 1.0, -1.0
    t[3, 2], t[3, 3] = 1.0, -1.0
    t[4, 4] = 1.0
    t[5, 5] = 1.0
    w = np.diag([foot, ankle, knee, hip, r1, r2])
    qq = t.T @ w @ t
    q = np.zeros((NX, NX))
    q[:6, :6] = qq
    q[6:12, 6:12] = speed_scale * qq
    q[12:, 12:] = activation * np.eye(NU)
    return q


def lqr(a_mat: np.ndarray, b_mat: np.ndarray, q: np.ndarray,
        r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time LQR: (K [9, 21], P [21, 21]) with u = -K dx minimising
    int dx' Q dx + du' R du."""
    p = sl.solve_continuous_are(a_mat, b_mat, q, r)
    return np.linalg.solve(r, b_mat.T @ p), p


def _zoh(a_mat: np.ndarray, b_mat: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation over h [s]: (Ad, Bd)."""
    n, m = b_mat.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a_mat * h
    big[:n, n:] = b_mat * h
    e = sl.expm(big)
    return e[:n, :n], e[:n, n:]


def tvlqr(model: JumperModel, t: np.ndarray, x: np.ndarray, u: np.ndarray,
          anchors: np.ndarray, q: np.ndarray, r: np.ndarray,
          p_final: np.ndarray) -> np.ndarray:
    """Gains K [n, 9, 21] along a plan (nodes t [n] s, states x [n, 21], excitations u [n, 9],
    anchors [2] or [n, 2] m) by the discrete Riccati recursion, backward from ``p_final``
    (continuous-time cost-to-go at the end; the per-interval cost is Q h, R h)."""
    n = t.size
    anchors = np.broadcast_to(np.asarray(anchors, dtype=float), (n, 2))
    gains = np.zeros((n, NU, NX))
    p = p_final.copy()
    a_end, b_end = linearize(model, x[-1], u[-1], anchors[-1])
    gains[-1] = np.linalg.solve(r, b_end.T @ p)
    for k in range(n - 2, -1, -1):
        h = float(t[k + 1] - t[k])
        a_mat, b_mat = linearize(model, x[k], u[k], anchors[k])
        ad, bd = _zoh(a_mat, b_mat, h)
        rd = r * h
        s = rd + bd.T @ p @ bd
        kk = np.linalg.solve(s, bd.T @ p @ ad)
        p = q * h + ad.T @ p @ (ad - bd @ kk)
        p = 0.5 * (p + p.T)
        gains[k] = kk
    return gains


@dataclass
class FeedbackLaw:
    """u(t, x) = clip(u_ff(t) + K(t) (x_ref(t) - x) + n(t), 0, 1) (module docstring).

    ``t`` [n] s nodes; ``u_ff`` [n, 9], ``x_ref`` [n, 21] and ``gains`` [n, 9, 21] (or one
    [9, 21] for all) interpolated linearly between them (``smooth``: u_ff and x_ref by a
    not-a-knot cubic spline, for references sampled from smooth signals: the stiff
    integrator then takes long steps) and held outside; ``noise`` an optional n(t) -> [9].
    """

    t: np.ndarray
    u_ff: np.ndarray
    x_ref: np.ndarray
    gains: np.ndarray
    noise: object = None
    smooth: bool = False

    def __post_init__(self) -> None:
        self.t = np.atleast_1d(np.asarray(self.t, dtype=float))
        self.u_ff = np.atleast_2d(self.u_ff)
        self.x_ref = np.atleast_2d(self.x_ref)
        if self.gains.ndim == 2:
            self.gains = self.gains[None]
        self._spline = None
        if self.smooth and self.t.size >= 4:
            self._spline = CubicSpline(self.t, np.hstack([self.u_ff, self.x_ref]), axis=0)

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(u_ff [9], x_ref [21]) at t [s]."""
        if self._spline is not None:
            v = self._spline(min(max(t, self.t[0]), self.t[-1]))
            return v[:NU], v[NU:]
        return self._interp(self.u_ff, t), self._interp(self.x_ref, t)

    def _interp(self, arr: np.ndarray, t: float) -> np.ndarray:
        if arr.shape[0] == 1:
            return arr[0]
        i = int(np.searchsorted(self.t, t, side='right')) - 1
        if i < 0:
            return arr[0]
        if i >= self.t.size - 1:
            return arr[-1]
        w = (t - self.t[i]) / (self.t[i + 1] - self.t[i])
        return (1.0 - w) * arr[i] + w * arr[i + 1]

    def unclipped(self, t: float, x: np.ndarray) -> np.ndarray:
        u_ff, x_ref = self.reference(t)
        u = u_ff + self._interp(self.gains, t) @ (x_ref - x)
        if self.noise is not None:
            u = u + self.noise(t)
        return u

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return np.clip(self.unclipped(t, x), 0.0, 1.0)

    def jacobian(self, t: float, x: np.ndarray) -> np.ndarray:
        v = self.unclipped(t, x)
        active = (v > 0.0) & (v < 1.0)
        return -self._interp(self.gains, t) * active[:, None]
