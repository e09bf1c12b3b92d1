"""Uniform cubic B-splines: the trajectories of the moving-horizon estimator.

A signal x(t) [k channels] is sum_j c_j B(t / dt - j) with control points c_j on a uniform
knot grid t_j = t_ref + j dt. On segment j (t_j <= t < t_j+1, local u = (t - t_j) / dt in
[0, 1)) four control points c_j..c_j+3 are active with the weights

    B0 = (1 - u)^3 / 6,  B1 = (3u^3 - 6u^2 + 4) / 6,  B2 = (-3u^3 + 3u^2 + 3u + 1) / 6,
    B3 = u^3 / 6,

so x is twice continuously differentiable: q, qd and qdd of the skeleton (Eq. 1) and a, adot,
addot of the activations (Eq. 8a) come from one set of control points, linearly. That makes
every residual of the estimator touch four consecutive control points: the normal equations
are banded (``normal_equations``).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numba
import numpy as np


def basis(u: np.ndarray, dt: float, orders: int = 4) -> np.ndarray:
    """Weights [P, orders, 4 control points]: value and the first ``orders`` - 1 time
    derivatives (1/s^k, at most the 3rd) of the four control points active at local
    coordinates ``u`` [P] in [0, 1)."""
    if not 1 <= orders <= 4:
        raise ValueError('orders must be 1 to 4')
    u = np.ascontiguousarray(u, dtype=float)
    out = _basis_rows(u.reshape(-1), dt, dt ** 2, dt ** 3, orders)
    return out.reshape(u.shape + (orders, 4))


@numba.njit(cache=True)
def _weights(x: float, dt: float, dt2: float, dt3: float, order: int, w: np.ndarray) -> None:
    """The four weights of ``order`` (0: value .. 3: 3rd derivative) at local coordinate x,
    into w [4]: the cubic B-spline's (1 - x)^3, 3x^3 - 6x^2 + 4, -3x^3 + 3x^2 + 3x + 1, x^3
    and their derivatives, over dt^order, over 6. The one definition of the weights
    (``basis``, ``evaluate``); the cube through ``pow`` and these operations in this order
    are numpy's of the formulas as written (bit for bit the weights before 2026-12-07)."""
    x2, x3 = x * x, x * x * x
    if order == 0:
        w[0] = math.pow(1 - x, 3.0)
        w[1] = 3 * x3 - 6 * x2 + 4
        w[2] = -3 * x3 + 3 * x2 + 3 * x + 1
        w[3] = x3
    elif order == 1:
        w[0] = -3 * ((1 - x) * (1 - x)) / dt
        w[1] = (9 * x2 - 12 * x) / dt
        w[2] = (-9 * x2 + 6 * x + 3) / dt
        w[3] = (3 * x2) / dt
    elif order == 2:
        w[0] = (6 * (1 - x)) / dt2
        w[1] = (18 * x - 12) / dt2
        w[2] = (-18 * x + 6) / dt2
        w[3] = (6 * x) / dt2
    else:
        w[0] = -6.0 / dt3
        w[1] = 18.0 / dt3
        w[2] = -18.0 / dt3
        w[3] = 6.0 / dt3
    for k in range(4):
        w[k] = w[k] / 6.0


@numba.njit(cache=True)
def _basis_rows(u: np.ndarray, dt: float, dt2: float, dt3: float, orders: int) -> np.ndarray:
    out = np.empty((u.size, orders, 4))
    for p in range(u.size):
        for o in range(orders):
            _weights(u[p], dt, dt2, dt3, o, out[p, o])
    return out


@dataclass(frozen=True)
class KnotGrid:
    """Knots t_ref + j dt [s]; segment j uses control points j..j+3 (global indices)."""

    t_ref: float
    dt: float

    def locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(segment index [P] int, local coordinate u [P]) of instants t [P] (s)."""
        x = (np.asarray(t, dtype=float) - self.t_ref) / self.dt
        j = np.floor(x + 1e-9).astype(np.int64)
        return j, np.clip(x - j, 0.0, 1.0)

    def segment_of(self, t: float) -> int:
        """Segment index containing instant t."""
        return int(np.floor((t - self.t_ref) / self.dt + 1e-9))

    def time(self, j: int | np.ndarray) -> np.ndarray | float:
        """Start time(s) of segment(s) j."""
        return self.t_ref + np.asarray(j) * self.dt


def evaluate(C: np.ndarray, first: int, grid: KnotGrid, t: np.ndarray, orders: int = 3,
             ) -> np.ndarray:
    """Spline values [P, orders, k] at instants t from control points C [n, k] whose first
    one has global index ``first``; orders = 1 (value), 2 (+ rate) or 3 (+ acceleration)."""
    j, u = grid.locate(t)
    idx = (j - first)[:, None] + np.arange(4)[None, :]
    if idx.min() < 0 or idx.max() >= C.shape[0]:
        raise IndexError('instants outside the control points given')
    if not 1 <= orders <= 3:
        raise ValueError('orders must be 1, 2 or 3')
    return _evaluate(np.ascontiguousarray(C, dtype=float), j - first, u, grid.dt,
                     grid.dt ** 2, orders)


@numba.njit(cache=True)
def _evaluate(C: np.ndarray, j: np.ndarray, u: np.ndarray, dt: float, dt2: float,
              orders: int) -> np.ndarray:
    """``evaluate`` compiled (numba; as numpy, ``basis`` and an einsum, it was 5 % of the
    moving-horizon estimator's time in per-call overhead): ``_weights`` summed over the
    four control points in order, as the einsum did."""
    P, V = u.size, C.shape[1]
    out = np.zeros((P, orders, V))
    w = np.empty(4)
    for p in range(P):
        for o in range(orders):
            _weights(u[p], dt, dt2, 0.0, o, w)
            for k in range(4):
                row = j[p] + k
                for v in range(V):
                    out[p, o, v] += w[k] * C[row, v]
    return out
