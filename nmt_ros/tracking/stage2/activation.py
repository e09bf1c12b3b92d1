"""The model's activation dynamics in the form Stage 2 uses, and Eq. 9.

Activation (Eq. 8 of the model, affine in a and u): adot = (d0 + d1 a) + (g0 + g1 a) u, solved
exactly over an interval of constant u (``ActivationLaw.step``). Eq. 9 (METHOD.md section 4):
the model's force F(a, l_MT, v_MT) (DeGroote, rigid tendon) depends directly on a, so
fdot = dF/da (drift + gain u) + dF/dl ldot_MT + dF/dv vdot_MT and

    u = (eta - dF/da drift - dF/dl ldot_MT - dF/dv vdot_MT) / (dF/da gain)     (9)

(``eq9_excitation``). The forward pass applies it integrated over an interval: the constant u
whose exact activation step lands on the activation the LQT asks for (``solve_step``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmt_ros.model.jumper import JumperModel

#: Activation margin (activation units) beyond which a target counts as unreachable.
SATURATION_TOL = 1e-9


def eq9_excitation(eta: np.ndarray, dF_da: np.ndarray, dF_dl: np.ndarray, dF_dv: np.ndarray,
                   drift: np.ndarray, gain: np.ndarray, l_mt_dot: np.ndarray,
                   v_mt_dot: np.ndarray) -> np.ndarray:
    """Eq. 9 (elementwise, unclipped): u = (eta - F_a drift - F_l ldot - F_v vdot)/(F_a gain).

    eta [N/s], dF_da [N], dF_dl [N/m], dF_dv [N s/m], drift [1/s], gain [1/s],
    l_mt_dot [m/s], v_mt_dot [m/s^2]; u dimensionless.
    """
    return (eta - dF_da * drift - dF_dl * l_mt_dot - dF_dv * v_mt_dot) / (dF_da * gain)


@dataclass(frozen=True)
class ActivationLaw:
    """adot = (d0 + d1 a) + (g0 + g1 a) u [1/s], read off the model's ``activation_affine``."""

    d0: np.ndarray
    d1: np.ndarray
    g0: np.ndarray
    g1: np.ndarray

    @classmethod
    def from_model(cls, model: JumperModel) -> ActivationLaw:
        n = len(model.p.muscles.names)
        at = [model.call(model.activation_affine, np.full(n, x)) for x in (0.0, 0.5, 1.0)]
        (d_0, g_0), (d_h, g_h), (d_1, g_1) = at
        if not (np.allclose(d_h, 0.5 * (d_0 + d_1)) and np.allclose(g_h, 0.5 * (g_0 + g_1))):
            raise ValueError('activation drift and gain must be affine in a')
        return cls(d0=d_0, d1=d_1 - d_0, g0=g_0, g1=g_1 - g_0)

    def affine(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(drift, gain) [1/s] at activation a."""
        return self.d0 + self.d1 * a, self.g0 + self.g1 * a

    def step(self, a0: np.ndarray, u: np.ndarray, h: float, derivative: bool = True,
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """Exact a(h) for constant u over h [s], and d a(h) / d u (None unless ``derivative``)."""
        kappa = -(self.d1 + self.g1 * u)              # > 0 for u in [0, 1]
        c0 = self.d0 + self.g0 * u
        a_inf = c0 / kappa
        decay = np.exp(-kappa * h)
        a1 = a_inf + (a0 - a_inf) * decay
        if not derivative:
            return a1, None
        da_inf = (self.g0 * kappa + c0 * self.g1) / kappa ** 2
        return a1, da_inf * (1 - decay) + (a0 - a_inf) * h * self.g1 * decay

    def step_affine(self, u: float, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(slope, offset) [m] of the exact step for a constant u: a(h) = slope a0 + offset."""
        kappa = -(self.d1 + self.g1 * u)
        decay = np.exp(-kappa * h)
        return decay, (self.d0 + self.g0 * u) / kappa * (1 - decay)

    def bounds(self, h: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """Reachable activations after a step h [s]: (slope, offset) at u = 0 and at u = 1."""
        return self.step_affine(0.0, h), self.step_affine(1.0, h)

    def held_steps(self, pattern: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        """Activation step a_i+1 = E a_i + c of each interval (step h [s]) for muscles held at
        a bound (pattern +1: u = 1, -1: u = 0; E = 1, c = 0 where free)."""
        (s0, o0), (s1, o1) = self.bounds(h)
        E = np.where(pattern > 0, s1, np.where(pattern < 0, s0, 1.0))
        c = np.where(pattern > 0, o1, np.where(pattern < 0, o0, 0.0))
        return E, c

    def solve_step(self, a0: np.ndarray, a_target: np.ndarray, h: float,
                   max_iterations: int = 8, tol: float = 1e-13,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Constant u in [0, 1] whose exact step from a0 reaches a_target (saturated if not).

        Eq. 9 integrated over the interval h [s]. Returns (u, a(h), saturated). Bracketed
        Newton, vectorised (2-3 iterations for h <= 10 ms).
        """
        ends, _ = self.step(a0, np.stack([np.zeros_like(a0), np.ones_like(a0)]), h,
                            derivative=False)
        a_lo, a_hi = ends
        low = a_target < a_lo - SATURATION_TOL
        high = a_target > a_hi + SATURATION_TOL
        target = np.clip(a_target, a_lo, a_hi)
        lo, hi = np.zeros_like(a0), np.ones_like(a0)
        u = np.clip((target - a_lo) / np.maximum(a_hi - a_lo, 1e-300), 0.0, 1.0)
        for _ in range(max_iterations):
            val, der = self.step(a0, u, h)
            res = val - target
            if np.max(np.abs(res)) < tol:
                break
            hi = np.where(res > 0, u, hi)
            lo = np.where(res <= 0, u, lo)
            newton = u - res / np.where(der > 0, der, 1.0)
            u = np.where((newton >= lo) & (newton <= hi), newton, 0.5 * (lo + hi))
        u = np.where(low, 0.0, np.where(high, 1.0, u))
        a1, _ = self.step(a0, u, h, derivative=False)
        return u, a1, low | high
