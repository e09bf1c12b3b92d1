"""Stage 2 of NMT: neuromuscular tracking (METHOD.md section 4, Eqs. 8-14).

Given the Stage-1 joint torques tau_ref[n, 3] (ankle, knee, hip; OpenSim generalized forces of
ankle_angle, knee_angle, hip_flexion) and the tracked joint kinematics theta, theta_dot,
theta_ddot [n, 3] on a uniform grid t[n], find the 9 musculotendon forces f[n, 9], activations
a[n, 9] and excitations u[n, 9] in [0, 1]:

* Eq. 10: fdot = eta, tau = C(theta) f; the LQT of Eq. 11 gives eta = R^-1 (g - W f) (Eq. 14)
  with W, g from the backward Riccati/adjoint sweep (``lqt``; Eqs. 12-13).
* Eq. 9 (``activation``): the model's force F(a, l_MT, v_MT) depends directly on a, and
  adot = drift(a) + gain(a) u, so the excitation follows from the force rate eta.

Modules, lowest first: ``settings`` (weights and options, ``data/stage2.yaml``),
``activation`` (the activation law, Eq. 9), ``lqt`` (Eqs. 12-14: exact-step sweeps, discrete
LQT), ``bounded_qp`` (Eq. 11 with 0 <= u <= 1), ``references`` (the internal grid and what is
precomputed on it), ``plans`` (window plans), ``results`` (records), ``forward_pass``
(advancing the muscles over a plan), ``receding_horizon`` (windows in turn), ``streaming``
(push), ``tracker`` (``NeuromuscularTracker``, what the rest of the code uses).

Saturation (``Stage2Settings.saturation``; DEPARTS FROM THE PAPER in the default 'plan'):

* 'clip' - the paper: the unconstrained LQT, Eq. 9 clipped to [0, 1] (``forward_pass``). The
  LQT does not know the bounds: on a maximum-height jump (prime movers at u = 1 for much of
  the push-off) it loads the cheap muscles (HAMS r = 0.1, RF 0.3) beyond what they can give
  and redistributes too late - measured on the reference jump's true torques: torque RMS
  4.5 / 13.8 / 11.7 % of peak (ankle / knee / hip), NMT jump 8 % low.
* 'plan' - the LQT of Eq. 11 WITH the excitation bounds 0 <= u <= 1 (a constrained LQT), in
  two steps per plan (``plans``). (1) ``bounded_qp.solve_bounded_lqt``: Eq. 11 discretised on
  the internal grid (trapezoid tracking, interval-rate effort, the same Q, R, P) with the
  activations as unknowns and every activation step between the exact steps at u = 0 and
  u = 1 - a convex QP, solved by a primal-dual interior point whose Newton steps are discrete
  LQTs factorised by the Riccati (block Cholesky) recursion; ~15 iterations, ~10 ms for the
  0.25 s jump. Its active set says which muscles sit at a bound over which intervals. (2) the
  LQT of that active set, ``lqt.discrete_lqt``: Eqs. 12-14 in discrete form (Riccati,
  adjoint, feedback law) for the free muscles, the saturated ones entering as known inputs
  that follow their own activation dynamics at u = 0 / 1 (their C f moves into the reference,
  their effort weight into the state cost). The forward pass then holds the saturated muscles
  at their bound and moves the free ones by the feedback law. Why this and not simpler
  variants (prototypes measured on the reference jump during development, not kept): taking
  the saturated muscles out of the continuous LQT (time-varying R: effort weight x1e4 over
  their saturated intervals, their forces of the previous pass as a known input) and
  iterating the saturation pattern from pass to pass (a primal-dual active-set iteration; a
  muscle released when the costate asks for less than its bound) does not converge - the
  pattern cycles and the cost oscillates (best pass 0.8 / 3.3 / 2.0 %, cost 2x the
  constrained optimum); and even on the right active set the continuous exact-step LQT is
  1-2 % F0 off the discrete optimum at 1 ms steps (its frozen per-interval coefficients err
  O(h^2) with a large constant in the co-contraction directions: 1.6 % F0 even without
  bounds, against 0.02 % for the discrete form), which made windowed and full horizon differ
  by 3.4 % F0. The discrete LQT on the QP's active set reproduces the QP to 1e-4 % F0;
  without active bounds it is the discrete counterpart of Eqs. 12-14. Result on the reference
  jump's true torques: 0.4 / 1.4 / 1.1 %, forces within 6.3 % F0 of the truth (RF; the rest
  <= 3.4 %), NMT jump 1 % low, 0.05 s CPU.

Two modes share the recipe (``receding_horizon``): full horizon (the paper: one plan over
[0, tf]) and receding windows of length H (a plan per window start t_k with P = 0 at
t_k + H, applied over [t_k, t_k + stride)). ``streaming.push`` is the streaming entry point;
the batch windowed mode equals ``push`` fed it in chunks (tested). With the bounds in the
problem the windows agree with the full horizon much sooner (saturation pins most of the
solution): 0.05 % F0 at H = 100 ms on the reference jump. Results are returned on the input
grid; saturation statistics count every internal interval.
"""
from nmt_ros.tracking.stage2.results import (
    MuscleState,
    SaturationReport,
    Stage2Result,
    Stage2Step,
)
from nmt_ros.tracking.stage2.settings import Stage2Settings, load_stage2_settings
from nmt_ros.tracking.stage2.streaming import StreamState
from nmt_ros.tracking.stage2.tracker import NeuromuscularTracker

__all__ = ['MuscleState', 'NeuromuscularTracker', 'SaturationReport', 'Stage2Result',
           'Stage2Settings', 'Stage2Step', 'StreamState', 'load_stage2_settings']
