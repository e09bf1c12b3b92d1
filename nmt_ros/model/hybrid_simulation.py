"""Forward simulation over flights and landings: Eq. 1 + 8 with the contact anchors re-placed
at every touchdown (a hybrid system).

The horizontal contact spring of each point pulls it toward its anchor ``x0_i``
(``contact.point_force``). The anchor is where the point is when it lands: at each
**touchdown** of a contact point, the instant its vertical force rises through
``TOUCHDOWN_FORCE_N`` (1 N, the lift-off rule's threshold) after it was airborne, its anchor is
set to the point's ground x at that instant. "Airborne" means its force fell below
``REARM_FORCE_N`` (0.5 N) since its last touchdown: the hysteresis keeps one crossing from
counting twice when the integrator restarts exactly on the threshold.

The integration is SciPy's Radau (stiff, implicit, order 5) with the model's exact Jacobian,
including the feedback of the excitations on the state (``Control.jacobian``), and the
touchdowns as terminal events: at each one the integration stops, the anchor moves and it
restarts. The excitations are a function of time and state, ``u = control(t, x)`` (in [0, 1]):
open-loop, or a feedback law; they are recorded at the output instants by calling the same
function, so the recorded excitations are exactly those that drove the model.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.integrate import solve_ivp

from nmt_ros.model.contact import LIFTOFF_FORCE_N
from nmt_ros.model.jumper import JumperModel

#: Vertical point force [N] whose upward crossing after flight is a touchdown.
TOUCHDOWN_FORCE_N = LIFTOFF_FORCE_N
#: Vertical point force [N] below which a point counts as airborne again (hysteresis).
REARM_FORCE_N = 0.5


class Control(Protocol):
    """Excitations u[9] in [0, 1] as a function of time t [s] and state x = [q, qd, a]."""

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray: ...

    def jacobian(self, t: float, x: np.ndarray) -> np.ndarray | None:
        """du/dx [9, 21] at (t, x), or None when u does not depend on x."""


@dataclass
class Touchdown:
    """A contact point landing: time [s], point index (0 heel, 1 toe), new anchor x [m]."""

    t: float
    point: int
    anchor_m: float


@dataclass
class HybridSimulation:
    """Samples of a hybrid forward simulation."""

    t: np.ndarray            # [n] s
    x: np.ndarray            # [n, 21] (q, qd, a)
    u: np.ndarray            # [n, 9] excitations at t
    anchors: np.ndarray      # [n, 2] anchors x0 in force at t (m)
    x_end: np.ndarray        # [21] state at t_end
    anchors_end: np.ndarray  # [2] anchors at t_end
    touchdowns: list[Touchdown] = field(default_factory=list)
    steps: int = 0           # accepted integrator steps
    success: bool = True
    message: str = ''


class _Evaluator:
    """Numeric evaluation of one CasADi function through its buffer interface (no DM
    conversions: ~4x less overhead per call than ``Function.__call__``); sparse outputs are
    scattered into dense arrays. Not re-entrant: the returned arrays are overwritten by the
    next call."""

    def __init__(self, fn: object) -> None:
        self._args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self._res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._buf, self._trigger = fn.buffer()
        for i, a in enumerate(self._args):
            self._buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self._res):
            self._buf.set_res(i, memoryview(r))
        sp = fn.sparsity_out(0)
        self._shape = (sp.size1(), sp.size2())
        self._dense = sp.is_dense()
        if not self._dense:
            rows, cols = sp.get_triplet()
            self._rows, self._cols = np.asarray(rows), np.asarray(cols)

    def __call__(self, *args: np.ndarray) -> np.ndarray:
        for dst, a in zip(self._args, args):
            dst[:] = np.ravel(a)
        self._trigger()
        out = self._res[0]
        if self._dense:
            return out.reshape(self._shape, order='F').copy() if self._shape[1] > 1 \
                else out.copy()
        dense = np.zeros(self._shape)
        dense[self._rows, self._cols] = out
        return dense


def vertical_point_forces(model: JumperModel, x: np.ndarray) -> np.ndarray:
    """Vertical force [N] of each contact point [2] at state x (independent of the anchors)."""
    f = np.asarray(model.contact_forces(x[:6], x[6:12], np.zeros(2)))
    return f[1, :]


def simulate_hybrid(model: JumperModel, x_init: np.ndarray, anchors: np.ndarray,
                    control: Control, t_start: float, t_end: float,
                    t_eval: np.ndarray | None = None, airborne: tuple[bool, bool] | None = None,
                    rtol: float = 1e-6, atol: float = 1e-8, max_step: float = 0.01,
                    ) -> HybridSimulation:
    """Integrate from ``x_init`` at ``t_start`` to ``t_end`` [s], output at ``t_eval`` [s].

    ``anchors`` [2]: the anchors in force at the start (m). ``airborne``: which points are
    airborne at the start (armed for a touchdown); by default those whose vertical force is
    below ``REARM_FORCE_N``. ``rtol``/``atol``: Radau's tolerances; ``max_step`` [s].
    """
    fode = _Evaluator(model.musculoskeletal_ode)
    fjac = _Evaluator(model.musculoskeletal_jacobian)
    fforce = _Evaluator(model.contact_forces)
    m = model.p.muscles
    beta = m.tau_act / m.tau_deact
    x = np.asarray(x_init, dtype=float).copy()
    anchors = np.asarray(anchors, dtype=float).copy()
    t_eval = np.empty(0) if t_eval is None else np.asarray(t_eval, dtype=float)
    if airborne is None:
        armed = vertical_point_forces(model, x) < REARM_FORCE_N
    else:
        armed = np.array(airborne, dtype=bool)
    ts, xs, anc = [], [], []
    touchdowns: list[Touchdown] = []
    steps = 0
    t = float(t_start)
    while True:
        x0 = anchors.copy()

        def rhs(tt: float, y: np.ndarray, x0: np.ndarray = x0) -> np.ndarray:
            return fode(y, control(tt, y), x0)

        def jac(tt: float, y: np.ndarray, x0: np.ndarray = x0) -> np.ndarray:
            u = control(tt, y)
            j = fjac(y, u, x0)
            du = control.jacobian(tt, y)
            if du is not None:
                gain = (1.0 - (1.0 - beta) * y[12:]) / m.tau_act      # d adot / d u
                j[12:, :] += gain[:, None] * du
            return j

        events = [_force_event(fforce, i, TOUCHDOWN_FORCE_N, +1) if armed[i]
                  else _force_event(fforce, i, REARM_FORCE_N, -1) for i in range(2)]
        sel = t_eval[(t_eval >= t - 1e-12) & (t_eval <= t_end + 1e-12)]
        grid = np.union1d(sel, [t_end])          # t_end too: the final state
        sol = solve_ivp(rhs, (t, t_end), x, method='Radau', jac=jac, rtol=rtol, atol=atol,
                        max_step=max_step, t_eval=grid, events=events)
        steps += int(sol.nlu)
        if sol.status == -1:
            return _finish(ts, xs, anc, x, anchors, touchdowns, steps, control, False,
                           f'{sol.message} at t = {t:.4f} s')
        hit = [(float(sol.t_events[i][0]), i) for i in range(2) if len(sol.t_events[i])]
        t_hit = min(hit)[0] if hit else None
        requested = np.isin(sol.t, sel)
        if t_hit is not None:
            requested &= sol.t < t_hit
        if requested.any():
            ts.append(sol.t[requested])
            xs.append(sol.y[:, requested].T)
            anc.append(np.repeat(anchors[None], int(requested.sum()), axis=0))
        if t_hit is None:
            return _finish(ts, xs, anc, sol.y[:, -1].copy(), anchors, touchdowns, steps,
                           control, True, 'completed')
        # restart at the event: the state there, anchors and arming updated
        i_hit = min(hit)[1]
        x = sol.y_events[i_hit][0].copy()
        t = t_hit
        for tt, i in hit:
            if tt != t_hit:
                continue
            if armed[i]:
                pts = np.asarray(model.positions(x[:6])[4])
                anchors[i] = pts[0, i]
                touchdowns.append(Touchdown(t=t, point=i, anchor_m=float(anchors[i])))
            armed[i] = not armed[i]


def _force_event(forces: _Evaluator, point: int, level: float, direction: int):
    """solve_ivp event: point's vertical force minus ``level`` [N], crossed in ``direction``
    (``forces``: the model's contact_forces; the vertical force needs no anchors)."""
    zero = np.zeros(2)

    def event(_t: float, y: np.ndarray) -> float:
        return float(forces(y[:6], y[6:12], zero)[1, point] - level)

    event.terminal = True
    event.direction = direction
    return event


def _finish(ts: list, xs: list, anc: list, x_end: np.ndarray, anchors: np.ndarray,
            touchdowns: list[Touchdown], steps: int, control: Control, success: bool,
            message: str) -> HybridSimulation:
    t = np.concatenate(ts) if ts else np.empty(0)
    x = np.vstack(xs) if xs else np.empty((0, x_end.size))
    a = np.vstack(anc) if anc else np.empty((0, 2))
    u = np.array([control(ti, xi) for ti, xi in zip(t, x)]) if t.size else np.empty((0, 9))
    return HybridSimulation(t=t, x=x, u=u, anchors=a, x_end=x_end, anchors_end=anchors.copy(),
                            touchdowns=touchdowns, steps=steps, success=success,
                            message=message)
