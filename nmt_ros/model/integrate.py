"""Fixed-step explicit integration shared by the trackers and the open-loop simulations.

Classical RK4 on a uniform grid: the live trackers step in sync with the data (a fixed number
of substeps per force-plate sample), so a fixed step is what they need, and the contact
(~365 rad/s) and tracking (1000 rad/s) time constants sit well inside RK4's stability region
at the steps used (lambda * h < 0.5 for h <= 1/2160 s).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

Rhs = Callable[[float, np.ndarray], np.ndarray]


def rk4_step(rhs: Rhs, t: float, y: np.ndarray, h: float) -> np.ndarray:
    """One classical Runge-Kutta step of ydot = rhs(t, y)."""
    k1 = rhs(t, y)
    k2 = rhs(t + h / 2, y + h / 2 * k1)
    k3 = rhs(t + h / 2, y + h / 2 * k2)
    k4 = rhs(t + h, y + h * k3)
    return y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def rk4_integrate(rhs: Rhs, y0: np.ndarray, t0: float, h: float, n_steps: int,
                  substeps: int = 1, stop: Callable[[float, np.ndarray], bool] | None = None,
                  ) -> tuple[np.ndarray, np.ndarray, bool]:
    """Integrate n_steps of size h, recording every ``substeps`` steps.

    Returns (t [m], y [m, k], stopped): the recorded instants (t0 first) and states; if
    ``stop(t, y)`` becomes true the integration ends there (recorded) with stopped = True.
    """
    y = np.asarray(y0, dtype=float).copy()
    ts, ys = [t0], [y.copy()]
    for k in range(n_steps):
        t = t0 + k * h
        y = rk4_step(rhs, t, y, h)
        last = k == n_steps - 1
        halt = stop is not None and stop(t + h, y)
        if (k + 1) % substeps == 0 or last or halt:
            ts.append(t0 + (k + 1) * h)
            ys.append(y.copy())
        if halt:
            return np.array(ts), np.array(ys), True
    return np.array(ts), np.array(ys), False
