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
    u = np.asarray(u, dtype=float)
    u2, u3 = u * u, u * u * u
    rows = [np.stack([(1 - u) ** 3, 3 * u3 - 6 * u2 + 4, -3 * u3 + 3 * u2 + 3 * u + 1, u3], -1)]
    if orders > 1:
        rows.append(np.stack([-3 * (1 - u) ** 2, 9 * u2 - 12 * u, -9 * u2 + 6 * u + 3, 3 * u2],
                             -1) / dt)
    if orders > 2:
        rows.append(np.stack([6 * (1 - u), 18 * u - 12, -18 * u + 6, 6 * u], -1) / dt ** 2)
    if orders > 3:
        rows.append(np.broadcast_to(np.array([-6.0, 18.0, -18.0, 6.0]) / dt ** 3,
                                    u.shape + (4,)))
    return np.stack(rows, 1) / 6.0


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
    moving-horizon estimator's time in per-call overhead): the weights as ``basis`` forms
    them, operation for operation (a cube through ``pow`` as numpy's, the 1/dt^k then the
    1/6), summed over the four control points in order as the einsum does."""
    P, V = u.size, C.shape[1]
    out = np.zeros((P, orders, V))
    w = np.empty(4)
    for p in range(P):
        x = u[p]
        x2, x3 = x * x, x * x * x
        for o in range(orders):
            if o == 0:
                w[0] = math.pow(1 - x, 3.0)
                w[1] = 3 * x3 - 6 * x2 + 4
                w[2] = -3 * x3 + 3 * x2 + 3 * x + 1
                w[3] = x3
            elif o == 1:
                w[0] = -3 * ((1 - x) * (1 - x)) / dt
                w[1] = (9 * x2 - 12 * x) / dt
                w[2] = (-9 * x2 + 6 * x + 3) / dt
                w[3] = (3 * x2) / dt
            else:
                w[0] = (6 * (1 - x)) / dt2
                w[1] = (18 * x - 12) / dt2
                w[2] = (-18 * x + 6) / dt2
                w[3] = (6 * x) / dt2
            for k in range(4):
                b = w[k] / 6.0
                row = j[p] + k
                for v in range(V):
                    out[p, o, v] += b * C[row, v]
    return out
