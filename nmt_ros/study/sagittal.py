"""From a 3-D bilateral recording to the planar jumper's observations (pure numpy).

Sagittal plane (README "Conventions"): x forward, y up, z = x cross y toward the subject's
right, seen from the right. A lab frame is mapped to it by naming the lab axes that point
forward and up (:class:`SagittalFrame`); positions and vectors are projected on (x, y).

Segment angles: each segment is a line between two landmarks (distal to proximal for the
leg and trunk, heel to toe for the foot):

    foot: heel -> toe   shank: ankle -> knee   thigh: knee -> hip   hat: hips -> shoulders

whose sagittal direction angle ``phi = atan2(d_y, d_x)`` minus its angle ``phi_0`` in the
default pose (the README zero: upright as in OpenSim's default pose) is the absolute segment
angle, counter-clockwise positive (:func:`segment_angle`). The planar model has one leg for
two: its segment angles are the **mean of the left and right angles** (:func:`combine_legs`).
The jumper lumps the legs with equal masses and lengths, so the lumped segment's centre of
mass sits at the mean of the two legs' (to first order in their difference), whichever leg
carries the load; weighting by each leg's share of the vertical force would switch the
kinematics between legs with the load and is undefined in flight. The left-right difference is
reported, so a strongly asymmetric trial can be seen.

Ground wrench (Eq. 2b outputs ``s``): every plate's force F, point of application P and free
torque T (lab frame, 3-D) summed into fore-aft force, vertical force and the moment about the
z axis through the (planar, combined) foot's centre of mass C:

    s = [sum F.x_hat, sum F.y_hat, sum (T.z_hat + ((P - C) x F).z_hat)]

exact whatever the plates' heights and lateral positions (the z component of a moment about
a point depends only on the in-plane offsets). C = ankle centre + R(theta_foot) c_foot, the
foot COM of the (subject-scaled) planar model, as the trackers' model places it.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from nmt_ros.io.opensim_files import GroundLoad

_AXES = {'x': 0, 'y': 1, 'z': 2}


def axis_vector(spec: str) -> np.ndarray:
    """'+x', '-z', 'y' ... -> unit vector [3]."""
    s = spec.strip().lower()
    sign = -1.0 if s.startswith('-') else 1.0
    s = s.lstrip('+-')
    if s not in _AXES:
        raise ValueError(f'axis {spec!r} must be one of +x, -x, +y, -y, +z, -z')
    v = np.zeros(3)
    v[_AXES[s]] = sign
    return v


@dataclass(frozen=True)
class SagittalFrame:
    """The lab axes pointing forward and up (e.g. OpenSim's ground: '+x', '+y')."""

    forward: str = '+x'
    up: str = '+y'

    def __post_init__(self) -> None:
        if abs(float(axis_vector(self.forward) @ axis_vector(self.up))) > 0.5:
            raise ValueError(f'forward {self.forward} and up {self.up} must be different axes')

    @property
    def basis(self) -> np.ndarray:
        """[3, 3] rows x_hat (forward), y_hat (up), z_hat = x_hat cross y_hat (right)."""
        x, y = axis_vector(self.forward), axis_vector(self.up)
        return np.vstack([x, y, np.cross(x, y)])

    def project(self, v: np.ndarray) -> np.ndarray:
        """Lab vectors/points [..., 3] -> sagittal (x, y) [..., 2]."""
        return np.asarray(v, dtype=float) @ self.basis[:2].T

    def normal(self, v: np.ndarray) -> np.ndarray:
        """The component along z_hat [...] of lab vectors [..., 3]."""
        return np.asarray(v, dtype=float) @ self.basis[2]


def direction_angle(p_from: np.ndarray, p_to: np.ndarray) -> np.ndarray:
    """Sagittal direction angle [rad] of the lines p_from -> p_to ([..., 2] each)."""
    d = np.asarray(p_to, dtype=float) - np.asarray(p_from, dtype=float)
    return np.arctan2(d[..., 1], d[..., 0])


def segment_angle(phi: np.ndarray, phi_zero: float) -> np.ndarray:
    """Absolute segment angle [rad]: phi - phi_zero wrapped to (-pi, pi], then unwrapped."""
    a = np.angle(np.exp(1j * (np.asarray(phi, dtype=float) - phi_zero)))
    return np.unwrap(a)


def combine_legs(right: np.ndarray, left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One leg for two: the mean angle [n] and the left-right RMS difference [rad]."""
    right, left = np.asarray(right, dtype=float), np.asarray(left, dtype=float)
    diff = np.angle(np.exp(1j * (right - left)))
    mean = left + 0.5 * diff
    return mean, np.sqrt(np.mean(diff ** 2, axis=0))


def rotate(th: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R(th) v for angles th [n] and one vector v [2] -> [n, 2]."""
    c, s = np.cos(th), np.sin(th)
    return np.column_stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def foot_com(ankle: np.ndarray, theta_foot: np.ndarray, com_in_foot: np.ndarray) -> np.ndarray:
    """The planar foot's COM [n, 2] from the ankle centre [n, 2] and foot angle [n] (rad)."""
    return np.asarray(ankle, dtype=float) + rotate(theta_foot, np.asarray(com_in_foot))


def resample(t_from: np.ndarray, values: np.ndarray, t_to: np.ndarray) -> np.ndarray:
    """Cubic-spline values [n_from, ...] at times t_to (inside [t_from[0], t_from[-1]])."""
    t_to = np.asarray(t_to, dtype=float)
    if t_to.size and (t_to[0] < t_from[0] - 1e-9 or t_to[-1] > t_from[-1] + 1e-9):
        raise ValueError(f'cannot resample {t_from[0]:.4f}..{t_from[-1]:.4f} s onto '
                         f'{t_to[0]:.4f}..{t_to[-1]:.4f} s (no extrapolation)')
    if np.array_equal(t_from, t_to):
        return np.asarray(values, dtype=float).copy()
    return CubicSpline(t_from, values, axis=0)(t_to)


def sagittal_wrench(loads: Sequence[GroundLoad], frame: SagittalFrame, about: np.ndarray,
                    ) -> np.ndarray:
    """[n, 3]: fore-aft force, vertical force (N), moment about the points ``about`` [n, 2]
    (N m) of the plates' loads summed (lab frame force, point, free torque, each [n, 3])."""
    if not loads:
        raise ValueError('no force plate')
    about = np.asarray(about, dtype=float)
    out = np.zeros((about.shape[0], 3))
    for load in loads:
        f2 = frame.project(load.force)
        arm = frame.project(load.point) - about
        out[:, 0] += f2[:, 0]
        out[:, 1] += f2[:, 1]
        out[:, 2] += frame.normal(load.torque) + arm[:, 0] * f2[:, 1] - arm[:, 1] * f2[:, 0]
    return out


def fill_gaps(time: np.ndarray, values: np.ndarray, max_gap_s: float, what: str,
              ) -> tuple[np.ndarray, list[dict]]:
    """Fill interior NaN runs of ``values`` [n, k] no longer than ``max_gap_s`` by a cubic
    spline through the valid samples; returns the filled copy and one record per repair.

    A longer gap, or one touching the first or last sample, raises ValueError naming it.
    """
    v = np.asarray(values, dtype=float).copy()
    bad = ~np.all(np.isfinite(v), axis=1)
    if not bad.any():
        return v, []
    good = ~bad
    if good.sum() < 4:
        raise ValueError(f'{what}: fewer than 4 valid samples')
    repairs = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(int), [0]])))
    for start, stop in zip(edges[::2], edges[1::2]):
        span = f'{time[start]:.4f}..{time[stop - 1]:.4f} s ({stop - start} samples)'
        if start == 0 or stop == len(time):
            raise ValueError(f'{what}: missing at the {"start" if start == 0 else "end"} of the '
                             f'recording, {span}: cannot be interpolated; trim the recording')
        dur = time[stop] - time[start - 1]
        if dur > max_gap_s + 1e-9:
            raise ValueError(f'{what}: gap {span} spans {dur:.3f} s, longer than the '
                             f'{max_gap_s:.3f} s that may be interpolated (--max-gap)')
        repairs.append({'what': what, 't_start_s': float(time[start]),
                        't_end_s': float(time[stop - 1]), 'samples': int(stop - start)})
    v[bad] = CubicSpline(time[good], v[good], axis=0)(time[bad])
    return v, repairs
