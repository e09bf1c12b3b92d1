"""Musculotendon paths: lengths as fitted polynomials in the joint angles, moment arms.

    l_MT,i(theta) = sum_k c_ik prod_j theta_j ** e_ikj        (theta: OpenSim coordinates, rad)
    r_ij(theta) = -d l_MT,i / d theta_j                       (moment arm [m])
    tau = C(theta) f,  C = r'  (3 x 9)                          (METHOD.md Eq. 10b)

Because the moment arms are minus the length derivatives, muscle power and joint power agree
exactly: sum_i F_i ldot_MT,i + tau . thetadot = 0. Coefficients come from OpenSim's
PolynomialPathFitter on gait10dof18musc (``nmt_ros.osim.fit_paths``) and ship in the data file.
"""
from __future__ import annotations

import casadi as ca

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
        lengths.append(polynomial(coords, path.exponents, path.coefficients))
    return ca.vertcat(*lengths)


def moment_arms(theta: ca.SX, m: MuscleParameters) -> ca.SX:
    """r [9 x 3] [m]: r_ij = -d l_MT,i / d theta_j."""
    return -ca.jacobian(musculotendon_lengths(theta, m), theta)
