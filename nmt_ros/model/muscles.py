"""Hill-type musculotendon actuators: DeGroote-Fregly 2016 curves, rigid tendon, affine activation.

Force output (METHOD.md Eq. 8b) for activation ``a``, musculotendon length ``l_mt`` [m] and
lengthening speed ``v_mt`` [m/s], rigid tendon, constant-thickness pennation:

    l_M = sqrt((l_mt - l_s)^2 + (l_opt sin alpha_opt)^2),  cos(alpha) = (l_mt - l_s) / l_M
    v_M = v_mt cos(alpha),  l~ = l_M / l_opt,  v~ = v_M / (v_max l_opt)
    F_MT = F0 (a f_L(l~) f_V(v~) + f_PE(l~) + beta v~) cos(alpha)

The force depends directly on the activation and the activation rate is affine in the
excitation u (Zajac 1989 form, METHOD.md section 4):

    adot = [u - (b + (1 - b) u) a] / tau_act,   b = tau_act / tau_deact

so dF/dt is affine in u and Eq. 9 (feedback linearization with relative degree one) holds.
Curve constants are those of De Groote et al. (2016) as implemented by OpenSim's
DeGrooteFregly2016Muscle; they are properties of the published curve shapes.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from nmt_ros.model.parameters import MuscleParameters

# De Groote et al. 2016, Table S1 (active force-length: sum of three Gaussian-like terms).
_FL_B1 = (0.8150671134243542, 0.433004984392647, 0.1)
_FL_B2 = (1.055033428970575, 0.716775413397760, 1.0)
_FL_B3 = (0.162384573599574, -0.029947116970696, 0.353553390593274)
_FL_B4 = (0.063303448465465, 0.200356847296188, 0.0)
# Force-velocity (inverse-hyperbolic-sine form).
_FV_D = (-0.3211346127989808, -8.149, -0.374, 0.8825327733249912)
# Passive force-length: exponential, shape factor kPE and minimum normalised length.
_PE_K = 4.0
_PE_MIN_LENGTH = 0.2


def active_force_length(l_norm: ca.SX) -> ca.SX:
    """f_L(l~): active force-length multiplier (De Groote 2016)."""
    total = 0
    for b1, b2, b3, b4 in zip(_FL_B1, _FL_B2, _FL_B3, _FL_B4):
        total += b1 * ca.exp(-0.5 * (l_norm - b2) ** 2 / (b3 + b4 * l_norm) ** 2)
    return total


def force_velocity(v_norm: ca.SX) -> ca.SX:
    """f_V(v~): force-velocity multiplier, v~ > 0 lengthening, f_V(0) = 1, f_V(-1) = 0."""
    d1, d2, d3, d4 = _FV_D
    return d1 * ca.asinh(d2 * v_norm + d3) + d4


def passive_force_length(l_norm: ca.SX, strain_at_one: float) -> ca.SX:
    """f_PE(l~): passive fibre force multiplier, 0 at l~ = 0.2, 1 at l~ = 1 + strain."""
    offset = ca.exp(_PE_K * (_PE_MIN_LENGTH - 1.0) / strain_at_one)
    return (ca.exp(_PE_K * (l_norm - 1.0) / strain_at_one) - offset) / (ca.exp(_PE_K) - offset)


def fiber_kinematics(l_mt: ca.SX, v_mt: ca.SX, m: MuscleParameters) -> tuple[ca.SX, ...]:
    """Rigid-tendon fibre length l_M [m], cos(pennation), fibre speed v_M [m/s]."""
    height = ca.DM(m.l_opt * np.sin(m.alpha_opt))
    along = l_mt - ca.DM(m.l_slack)
    l_m = ca.sqrt(along ** 2 + height ** 2)
    cos_alpha = along / l_m
    return l_m, cos_alpha, v_mt * cos_alpha


def musculotendon_force(a: ca.SX, l_mt: ca.SX, v_mt: ca.SX, m: MuscleParameters) -> ca.SX:
    """F_MT [N] of the 9 actuators (Eq. 8b) for activations a, lengths [m], speeds [m/s]."""
    l_m, cos_alpha, v_m = fiber_kinematics(l_mt, v_mt, m)
    l_opt = ca.DM(m.l_opt)
    l_norm = l_m / l_opt
    v_norm = v_m / (m.v_max * l_opt)
    fiber = (a * active_force_length(l_norm) * force_velocity(v_norm)
             + passive_force_length(l_norm, m.passive_strain) + m.fiber_damping * v_norm)
    return ca.DM(m.f0) * fiber * cos_alpha


def activation_rate(u: ca.SX, a: ca.SX, m: MuscleParameters) -> ca.SX:
    """adot [1/s] (Eq. 8a, activation part): affine in the excitation u."""
    beta = m.tau_act / m.tau_deact
    return (u - (beta + (1.0 - beta) * u) * a) / m.tau_act


def activation_rate_affine(a: ca.SX, m: MuscleParameters) -> tuple[ca.SX, ca.SX]:
    """adot = A_a(a) + B_a(a) u: the drift and the (diagonal) input gain of Eq. 8a."""
    beta = m.tau_act / m.tau_deact
    return -beta * a / m.tau_act, (1.0 - (1.0 - beta) * a) / m.tau_act
