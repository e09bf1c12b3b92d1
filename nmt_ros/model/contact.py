"""Foot-ground contact: smooth heel and toe springs, and the paper's contact outputs ``s``.

Per contact point i (ground frame, y = 0 is the undeformed ground), with smooth positive parts
so that the law is C-infinity in the state (the trackers differentiate it, Eq. 4):

    Fy_i = k_y delta softplus(-y_i / delta) * smoothpos(1 - c_hc ydot_i)      (Hunt-Crossley-like)
    Fx_i = mu Fy_i tanh(Fx_el / (mu Fy_i + f_eps)),  Fx_el = -k_x (x_i - x0_i) - c_x xdot_i

``x0`` (the anchors) are the points' ground x at the start of the contact phase: an elastic
"no-slip" spring, saturated smoothly at the friction limit, holds the foot without the creep of
purely velocity-based friction. The outputs (METHOD.md Eq. 2b)

    s = [fore-aft force, vertical force, moment of the ground forces about the foot COM]

are in N, N, N m (moment counter-clockwise positive about +z).

Lift-off (``LiftoffDetector``, ``liftoff_time``, ``liftoff_event``): the first downward
crossing of a vertical-force threshold after the force has exceeded it. The threshold says
whose force it is:

* ``LIFTOFF_FORCE_N`` = 1 N for the model's own, noise-free force (the truth, simulations):
  the smooth springs never reach 0 N (softplus: 139 N per point at zero penetration, 1 N at
  about 5 mm clearance, falling e-fold per further mm), so 1 N (0.14 % BW) marks the foot
  leaving the ground;
* the force plate's noise SD (2 % BW, ``tracking/observation_noise.py``) for a tracker that
  follows noisy force-plate data (its settings' ``liftoff_force_bw``): the tracked model keeps
  a small contact force in flight while it follows the noisy ~0 N observations, so its force
  falls below the noise level, not to 1 N.
"""
from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from nmt_ros.model.parameters import ContactParameters

#: Lift-off threshold [N] on the model's own vertical ground force (noise-free: truth, sims).
LIFTOFF_FORCE_N = 1.0


def softplus(x: ca.SX) -> ca.SX:
    """log(1 + exp(x)), written to stay finite for large |x|."""
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))


def point_force(pos: ca.SX, vel: ca.SX, x0: ca.SX, c: ContactParameters) -> ca.SX:
    """Ground force [Fx, Fy] [N] on one foot point at ``pos`` [m] moving at ``vel`` [m/s]."""
    penetration = c.delta * softplus(-pos[1] / c.delta)
    w = c.damping_smoothing
    damping = w * softplus((1.0 - c.c_hc * vel[1]) / w)
    fy = c.k_y * penetration * damping
    fx_el = -c.k_x * (pos[0] - x0) - c.c_x * vel[0]
    limit = c.mu * fy
    fx = limit * ca.tanh(fx_el / (limit + c.f_eps))
    return ca.vertcat(fx, fy)


def contact_outputs(points: list[ca.SX], forces: list[ca.SX], foot_com: ca.SX) -> ca.SX:
    """s = [sum Fx, sum Fy, sum (p_i - c_foot) x F_i] (METHOD.md Eq. 2b)."""
    fx = sum(f[0] for f in forces)
    fy = sum(f[1] for f in forces)
    moment = sum((pt[0] - foot_com[0]) * f[1] - (pt[1] - foot_com[1]) * f[0]
                 for pt, f in zip(points, forces))
    return ca.vertcat(fx, fy, moment)


class LiftoffDetector:
    """The lift-off rule on vertical ground-force samples fed in time order (batch or online).

    The body is loaded once a sample exceeds ``threshold_n`` [N]; it lifts off at the first
    later sample that does not (NaN counts as not above). Lift-off is *known* at that sample
    (``known_s``, what an online tracker can act on); its instant ``liftoff_s`` [s] is
    interpolated linearly between that sample and the one before. Both stay NaN until then.
    """

    def __init__(self, threshold_n: float) -> None:
        self.threshold_n = float(threshold_n)
        self.loaded = False
        self.liftoff_s = float('nan')
        self.known_s = float('nan')
        self._last: tuple[float, float] | None = None   # the previous block's last sample

    def update(self, t: np.ndarray, fy: np.ndarray) -> int | None:
        """Feed samples t [s], fy [N]; the index in them at which lift-off became known, or
        None (not yet, or known before this block)."""
        if np.isfinite(self.known_s):
            return None
        t = np.asarray(t, dtype=float)
        fy = np.asarray(fy, dtype=float)
        if t.size == 0:
            return None
        above = fy > self.threshold_n
        start = 0
        if not self.loaded:
            if not above.any():
                self._last = (t[-1], fy[-1])
                return None
            start = int(np.argmax(above))
            self.loaded = True
        below = np.flatnonzero(~above[start:])
        if below.size == 0:
            self._last = (t[-1], fy[-1])
            return None
        i = start + int(below[0])
        t0, f0 = (t[i - 1], fy[i - 1]) if i > 0 else self._last
        t1, f1 = t[i], fy[i]
        self.liftoff_s = float(t0 + (t1 - t0) * (f0 - self.threshold_n) / (f0 - f1))
        self.known_s = float(t1)
        return i


def liftoff_time(t: np.ndarray, fy: np.ndarray, threshold_n: float = LIFTOFF_FORCE_N) -> float:
    """Lift-off instant [s] of a whole record (the rule of ``LiftoffDetector``); NaN if the
    force never exceeds ``threshold_n`` [N] or never falls back below it."""
    detector = LiftoffDetector(threshold_n)
    detector.update(t, fy)
    return detector.liftoff_s


def liftoff_event(vertical_force: Callable[[np.ndarray], float],
                  threshold_n: float = LIFTOFF_FORCE_N) -> Callable[[float, np.ndarray], float]:
    """The lift-off rule in continuous time, as a ``scipy.integrate.solve_ivp`` event: the
    first root of ``vertical_force(y) - threshold_n`` [N] crossed downward (a downward crossing
    comes after the force exceeded the threshold, as in ``LiftoffDetector``)."""

    def event(_t: float, y: np.ndarray) -> float:
        return vertical_force(y) - threshold_n

    event.direction = -1
    return event
