"""Musculotendon paths: lengths as fitted polynomials in the joint angles, moment arms.

    l_MT,i(theta) = sum_k c_ik prod_j theta_j ** e_ikj        (theta: OpenSim coordinates, rad)
    r_ij(theta) = -d l_MT,i / d theta_j                       (moment arm [m])
    tau = C(theta) f,  C = r'  (3 x 9)                          (METHOD.md Eq. 10b)

Beyond the range where a polynomial is used (``path_ranges_deg`` in the data file: its fitting
grid, a little wider) it is not extrapolated (a 9th-order polynomial leaves the anatomy within
degrees of its grid: an estimator drifting to 140 deg of hip flexion met moment arms of either
sign and diverged); the path is continued to first order from the nearest point c of the
range,

    l_MT(theta) = l_MT(c) + grad l_MT(c) . (theta - c),     c = clip(theta, range),

so length and moment arms are continuous there and the moment arms stay at their values on
the range's edge.

Because the moment arms are minus the length derivatives, muscle power and joint power agree
exactly: sum_i F_i ldot_MT,i + tau . thetadot = 0. Coefficients come from OpenSim's
PolynomialPathFitter on gait10dof18musc (``nmt_ros.osim.fit_paths``) and ship in the data file.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from nmt_ros.model.parameters import JOINT_COORDINATES, MuscleParameters


def polynomial(coords: list[ca.SX], exponents: object, coefficients: object) -> ca.SX:
    """sum_k c_k prod_j coords_j ** e_kj."""
    total = 0
    for c, powers in zip(coefficients, exponents):
        term = float(c)
        for x, e in zip(coords, powers):
            if e:
                term = term * x ** int(e)
        total = total + term
    return total


def guarded_polynomial(coords: list[ca.SX], exponents: object, coefficients: object,
                       fit_range: object | None) -> ca.SX:
    """``polynomial`` inside ``fit_range`` ([n_coords, 2], rad; None: everywhere), its
    first-order continuation from the range's nearest point c outside it:
    P(c) + sum_j dP/dq_j(c) (q_j - c_j), where dP/dq_j at c_j = an edge is a polynomial in
    the other (clipped) coordinates with numeric coefficients (a small expression: the
    Jacobians the estimators take of the moment arms stay as cheap as the polynomial's)."""
    if fit_range is None:
        return polynomial(coords, exponents, coefficients)
    e = np.asarray(exponents, dtype=int).reshape(-1, len(coords))
    c = np.asarray(coefficients, dtype=float)
    rng = np.asarray(fit_range, dtype=float).reshape(-1, 2)
    clipped = [ca.fmin(ca.fmax(x, float(lo)), float(hi)) for x, (lo, hi) in zip(coords, rng)]
    total = polynomial(clipped, e, c)
    for j, x in enumerate(coords):
        use = e[:, j] > 0
        d_exp, d_coef = e[use].copy(), c[use] * e[use, j]
        d_exp[:, j] -= 1
        for edge, excess in ((rng[j, 0], ca.fmin(x - float(rng[j, 0]), 0.0)),
                             (rng[j, 1], ca.fmax(x - float(rng[j, 1]), 0.0))):
            at_edge = [float(edge) if k == j else clipped[k] for k in range(len(coords))]
            total = total + polynomial(at_edge, d_exp, d_coef) * excess
    return total


def musculotendon_lengths(theta: ca.SX, m: MuscleParameters) -> ca.SX:
    """l_MT [m] of the 9 muscles from theta = [ankle_angle, knee_angle, hip_flexion] [rad]."""
    if set(m.paths) != set(m.names):
        missing = sorted(set(m.names) - set(m.paths))
        raise ValueError(f'model data file has no fitted path for {missing}; run '
                         '`python -m nmt_ros.osim.fit_paths`')
    index = {name: i for i, name in enumerate(JOINT_COORDINATES)}
    lengths = []
    for name in m.names:
        path = m.paths[name]
        coords = [theta[index[c]] for c in path.coordinates]
        lengths.append(guarded_polynomial(coords, path.exponents, path.coefficients,
                                          path.fit_range))
    return ca.vertcat(*lengths)


def moment_arms(theta: ca.SX, m: MuscleParameters) -> ca.SX:
    """r [9 x 3] [m]: r_ij = -d l_MT,i / d theta_j."""
    return -ca.jacobian(musculotendon_lengths(theta, m), theta)
