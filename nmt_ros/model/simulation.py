"""Forward simulation of the jumper model: fixed-step RK4 and stiff Radau, one module.

* ``rk4_step``, ``rk4_integrate``: classical RK4 on a uniform grid. The live trackers step in
  sync with the data (a fixed number of substeps per force-plate sample), so a fixed step is
  what they need, and the contact (~365 rad/s) and tracking (1000 rad/s) time constants sit
  well inside RK4's stability region at the steps used (lambda * h < 0.5 for h <= 1/2160 s).
* ``simulate_excitations``: the musculoskeletal model (Eq. 1 with the muscles' torques, and
  activation dynamics, Eq. 8) driven by excitations u(t), either ``method='radau'`` (stiff,
  implicit, with the model's exact Jacobian and tight tolerances: the truth) or
  ``method='rk4'`` (fixed step, the excitation held over each step: fast, for the
  piecewise-constant excitations of Stage 2).
* ``simulate_torques``: the skeleton (Eq. 1) driven by joint torques tau(t) (RK4), with an
  optional stop condition (the IVD baseline's open-loop simulation).
* ``held``: zero-order hold of sampled inputs.

Lift-off is the contact module's rule on the simulated vertical ground force
(``LIFTOFF_FORCE_N``: the model's own, noise-free force).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from nmt_ros.model.contact import LIFTOFF_FORCE_N, liftoff_event, liftoff_time
from nmt_ros.model.jumper import JumperModel

Rhs = Callable[[float, np.ndarray], np.ndarray]
Signal = Callable[[float], np.ndarray]

#: Longest RK4 step of the simulations [s]: the step 4 substeps make at 1080 Hz; slower
#: sample rates get more substeps per sample (``steps_per_sample``: 44 at 100 Hz).
MAX_STEP_S = 0.25 / 1080.0


def rk4_step(rhs: Rhs, t: float, y: np.ndarray, h: float) -> np.ndarray:
    """One classical Runge-Kutta step of ydot = rhs(t, y) from t [s] over h [s]."""
    k1 = rhs(t, y)
    k2 = rhs(t + h / 2, y + h / 2 * k1)
    k3 = rhs(t + h / 2, y + h / 2 * k2)
    k4 = rhs(t + h, y + h * k3)
    return y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def steps_per_sample(rate_hz: float, max_step_s: float, at_least: int = 1) -> int:
    """Fixed steps per sample interval 1/rate_hz [s] so that no step exceeds ``max_step_s``
    [s] (and at least ``at_least``): what keeps an explicit integrator inside its stability
    region whatever the data's rate (a 100 Hz force plate needs ten times the steps per
    sample of a 1080 Hz one)."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f'sample rate {rate_hz} Hz must be positive')
    if not max_step_s > 0:
        raise ValueError(f'max_step_s {max_step_s} s must be positive')
    return max(int(at_least), int(np.ceil(1.0 / (rate_hz * max_step_s) - 1e-9)))


def rk4_integrate(rhs: Rhs, y0: np.ndarray, t0: float, h: float, n_steps: int,
                  substeps: int = 1, stop: Callable[[float, np.ndarray], bool] | None = None,
                  ) -> tuple[np.ndarray, np.ndarray, bool]:
    """Integrate n_steps of size h [s], recording every ``substeps`` steps.

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


@dataclass
class Simulation:
    """A forward simulation of the model."""

    t: np.ndarray          # [n] s
    x: np.ndarray          # [n, 21] (q, qd, a) driven by excitations; [n, 12] (q, qd) by torques
    u: np.ndarray          # [n, 9] excitations or [n, 3] joint torques (N m) at t
    s: np.ndarray          # [n, 3] contact outputs (N, N, N m) at t
    x0: np.ndarray         # contact anchors [2] (m)
    liftoff_s: float       # the contact rule's lift-off on the simulated vertical force (s)
    success: bool          # integrated to the end (no failure, no stop)
    message: str


def held(t_samples: np.ndarray, values: np.ndarray) -> Signal:
    """u(t): ``values[i]`` from ``t_samples[i]`` [s] until the next sample (zero-order hold;
    the first sample before it, the last one after the end)."""
    t_samples = np.asarray(t_samples, dtype=float)
    values = np.asarray(values, dtype=float)

    def signal(t: float) -> np.ndarray:
        i = int(np.searchsorted(t_samples, t + 1e-12, side='right')) - 1
        return values[min(max(i, 0), len(t_samples) - 1)]

    return signal


def simulate_excitations(model: JumperModel, x_init: np.ndarray, x0: np.ndarray,
                         excitation: Signal, t_end: float, *, method: str = 'radau',
                         t_eval: np.ndarray | None = None, rtol: float = 1e-9,
                         atol: float = 1e-10, rate_hz: float = 1080.0, substeps: int = 4,
                         liftoff_force: float = LIFTOFF_FORCE_N,
                         max_step_s: float = MAX_STEP_S) -> Simulation:
    """Eq. 1 + Eq. 8 from x_init = [q, qd, a] driven by ``excitation(t) -> u[9]`` until t_end [s].

    ``method='radau'``: stiff implicit integration with the model's exact Jacobian, relative
    and absolute tolerances ``rtol``/``atol``, output at ``t_eval`` [s] (or the solver's steps);
    lift-off as a root of the event (``liftoff_event``). ``method='rk4'``: RK4 with
    ``substeps`` steps per sample, recorded at ``rate_hz`` up to the last whole sample before
    t_end; the excitation is evaluated at each step's start and held over the step (a
    zero-order hold on the integration grid, which suits piecewise-constant excitations);
    lift-off by ``liftoff_time`` on the recorded forces; at slow rates more substeps, so
    that no step exceeds ``max_step_s`` [s]. ``liftoff_force`` [N].
    """
    if method == 'radau':
        return _radau(model, x_init, x0, excitation, t_end, t_eval, rtol, atol, liftoff_force)
    if method == 'rk4':
        return _rk4_held(model, x_init, x0, excitation, t_end, rate_hz,
                         steps_per_sample(rate_hz, max_step_s, substeps), liftoff_force)
    raise ValueError(f"method must be 'radau' or 'rk4', not {method!r}")


def _radau(model: JumperModel, x_init: np.ndarray, x0: np.ndarray, excitation: Signal,
           t_end: float, t_eval: np.ndarray | None, rtol: float, atol: float,
           liftoff_force: float) -> Simulation:
    fode = model.musculoskeletal_ode
    fjac = model.musculoskeletal_jacobian
    fs = model.contact_outputs

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        return np.asarray(fode(y, excitation(t), x0)).ravel()

    def jac(t: float, y: np.ndarray) -> np.ndarray:
        return np.asarray(fjac(y, excitation(t), x0))

    liftoff = liftoff_event(lambda y: float(np.asarray(fs(y[:6], y[6:12], x0))[1, 0]),
                            liftoff_force)
    sol = solve_ivp(rhs, (0.0, t_end), x_init, method='Radau', jac=jac, rtol=rtol,
                    atol=atol, t_eval=t_eval, events=liftoff, dense_output=False)
    ev = sol.t_events[0]
    t_lo = float(ev[0]) if len(ev) else float('nan')
    u = np.array([excitation(t) for t in sol.t])
    x = sol.y.T
    s, = model.batch(fs, x[:, :6], x[:, 6:12], x0)
    return Simulation(t=sol.t, x=x, u=u, s=s, x0=np.asarray(x0, dtype=float),
                      liftoff_s=t_lo, success=bool(sol.success), message=str(sol.message))


def _rk4_held(model: JumperModel, x_init: np.ndarray, x0: np.ndarray, excitation: Signal,
              t_end: float, rate_hz: float, substeps: int, liftoff_force: float) -> Simulation:
    fode = model.musculoskeletal_ode
    h = 1.0 / (rate_hz * substeps)
    hold = {'t': None, 'u': None}

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        t_step = np.floor(t / h + 1e-9) * h
        if hold['t'] != t_step:
            hold['t'], hold['u'] = t_step, excitation(t_step)
        return np.asarray(fode(y, hold['u'], x0)).ravel()

    t, y, _ = rk4_integrate(rhs, x_init, 0.0, h, _whole_samples(t_end, rate_hz) * substeps,
                            substeps)
    s, = model.batch(model.contact_outputs, y[:, :6], y[:, 6:12], x0)
    u = np.array([excitation(ti) for ti in t])
    return Simulation(t=t, x=y, u=u, s=s, x0=np.asarray(x0, dtype=float),
                      liftoff_s=liftoff_time(t, s[:, 1], liftoff_force), success=True,
                      message='RK4')


def simulate_torques(model: JumperModel, q0: np.ndarray, qd0: np.ndarray, x0: np.ndarray,
                     torque: Signal, t_end: float, *, rate_hz: float = 1080.0,
                     substeps: int = 4, stop: Callable[[float, np.ndarray], bool] | None = None,
                     liftoff_force: float = LIFTOFF_FORCE_N, t0: float = 0.0,
                     max_step_s: float = MAX_STEP_S) -> Simulation:
    """Eq. 1 from (q0, qd0) at t0 [s] driven by joint torques ``torque(t) -> tau[3]`` [N m]
    (RK4, ``substeps`` steps per sample, more at slow rates: no step above ``max_step_s``
    [s]; recorded at ``rate_hz`` up to the last whole sample before t_end [s]). Ends early,
    recorded, when ``stop(t, [q, qd])`` becomes true (success False, message 'stopped')."""
    fd = model.forward_dynamics

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        return np.concatenate([y[6:], np.asarray(fd(y[:6], y[6:], torque(t), x0)).ravel()])

    substeps = steps_per_sample(rate_hz, max_step_s, substeps)
    h = 1.0 / (rate_hz * substeps)
    t, y, stopped = rk4_integrate(rhs, np.concatenate([q0, qd0]), t0, h,
                                  _whole_samples(t_end - t0, rate_hz) * substeps, substeps,
                                  stop=stop)
    s, = model.batch(model.contact_outputs, y[:, :6], y[:, 6:], x0)
    return Simulation(t=t, x=y, u=np.array([torque(ti) for ti in t]), s=s,
                      x0=np.asarray(x0, dtype=float),
                      liftoff_s=liftoff_time(t, s[:, 1], liftoff_force), success=not stopped,
                      message='stopped' if stopped else 'completed')


def _whole_samples(t_end: float, rate_hz: float) -> int:
    """The number of whole samples at ``rate_hz`` [Hz] in [0, t_end] [s]."""
    return int(np.floor(t_end * rate_hz + 1e-9))
