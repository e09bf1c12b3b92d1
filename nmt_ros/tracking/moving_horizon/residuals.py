"""The unknowns of the moving-horizon estimator and the residuals it fits (the layout).

Unknowns per control point (``LAYOUT``, NV = 18): q [6] (rad, m), activations a [9] and the
estimated ground wrench s [3] (N, N, N m about the foot COM). Unknowns of the whole window
(``PLATE``, NX = 4): the force plate's error model, offsets b [3] (N, N, N m) and a
centre-of-pressure offset d [m] (a plate whose COP is misplaced, or a foot COM misplaced on
it, reads the moment M + Fy d). Residuals, each divided by its SD (``segment_kernel``
computes them, compiled):

* angles: q_1..4(t_k) - theta_obs,k at the mocap samples;
* wrench: [Fx + b_x, Fy + b_y, M + d Fy + b_M] - s_obs,j at the force-plate samples (both
  Huber-weighted, NaN channels carry no weight);
* at two Gauss points per segment: Eq. 1 with the estimated wrench and the muscles' torques
  (``point_functions``), the contact points' kinematics (a loaded point stays at the
  springs' sinkage and does not slide), the excitations of Eq. 8a inverted (effort
  sqrt(w_u) u, smoothness sqrt(w_du) udot, both times sqrt(quadrature weight), a penalty
  on u and a outside [0, 1]) and the wrench's smoothness (its 2nd derivative).
"""
from __future__ import annotations

import numpy as np

LAYOUT = {'q': slice(0, 6), 'a': slice(6, 15), 's': slice(15, 18)}
NV = 18
PLATE = {'b': slice(0, 3), 'cop': slice(3, 4)}
NX = 4
NB = 4 * NV          # variables of one segment's control points
#: The two Gauss-Legendre points of a knot interval (local coordinate in [0, 1]).
GAUSS = 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0)
