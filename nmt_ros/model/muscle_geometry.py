"""Muscle path points in the segment frames: where each musculotendon runs (for drawing).

The dynamics use the fitted length polynomials (``paths.py``); this is the geometry those
polynomials were fitted to: the ``path_points`` section of the model data file (OpenSim
gait10dof18musc's path point sets in our segment frames, ``nmt_ros.osim.path_points``).
A point is fixed in its segment, or *conditional* (on the path while a joint coordinate is in
a range), or *moving* (its location a cubic spline of a joint coordinate, as OpenSim's
``MovingPathPoint`` with ``SimmSpline`` knots). Coordinates are the model's joint angles
``theta = [ankle_angle, knee_angle, hip_flexion]`` [rad].

The model's knee is a pin (the tibia origin fixed in the thigh at its default-pose place);
gait10dof18musc's knee also translates the tibia origin with the knee angle, t(knee) in the
femur frame, and with it everything below the knee. So that the paths are exactly the ones
the length polynomials were fitted to, every shank and foot point moves by
R(-knee) (t(knee) - t(0)) expressed in the shank frame (``KneeTranslation.shift``, at most
~1 cm): a point drawn sits where OpenSim's tibia (and the foot it carries) puts it.

A subject-scaled jumper (``model.subject``) keeps the data file's points; they are scaled per
segment by the ratio of the subject's segment length to the shipped jumper's (shank: knee to
ankle, thigh: hip to knee, foot: heel to toe contact, HAT: hip to HAT COM).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
import yaml

from nmt_ros.model.parameters import (
    DATA_FILE,
    JOINT_COORDINATES,
    MUSCLES,
    SEGMENTS,
    JumperParameters,
    load_parameters,
)


@dataclass(frozen=True)
class KneeTranslation:
    """t(knee) [m] of the tibia origin in the thigh frame (cubic splines of knee_angle)."""

    coordinate: int
    x: CubicSpline
    y: CubicSpline

    def shift(self, theta: np.ndarray) -> np.ndarray:
        """R(-knee) (t(knee) - t(0)) [n, 3] (z 0): a shank point's offset from the pin knee."""
        knee = theta[:, self.coordinate]
        dx, dy = self.x(knee) - self.x(0.0), self.y(knee) - self.y(0.0)
        c, s = np.cos(knee), np.sin(knee)
        return np.stack([c * dx + s * dy, -s * dx + c * dy, np.zeros_like(knee)], axis=1)


@dataclass(frozen=True)
class PathPoint:
    """One point of a muscle path in its segment's frame (x forward, y up, z lateral) [m]."""

    segment: str
    xyz: np.ndarray | None = None                  # [3], fixed points
    active_coordinate: int | None = None           # index into theta, conditional points
    active_range: tuple[float, float] = (-np.inf, np.inf)   # rad
    moving_coordinate: int | None = None           # index into theta, moving points
    splines: tuple[CubicSpline, ...] = ()          # x, y, z of the coordinate [m]

    def local(self, theta: np.ndarray) -> np.ndarray:
        """Location [n, 3] in the segment frame at joint angles ``theta[n, 3]`` [rad]."""
        n = theta.shape[0]
        if self.moving_coordinate is None:
            return np.broadcast_to(self.xyz, (n, 3))
        c = theta[:, self.moving_coordinate]
        return np.stack([s(c) for s in self.splines], axis=1)

    def active(self, theta: np.ndarray) -> np.ndarray:
        """Whether the point is on the path [n] at joint angles ``theta[n, 3]``."""
        if self.active_coordinate is None:
            return np.ones(theta.shape[0], dtype=bool)
        c = theta[:, self.active_coordinate]
        return (c >= self.active_range[0]) & (c <= self.active_range[1])


@dataclass(frozen=True)
class MuscleGeometry:
    """Path points of the nine muscles, ``MUSCLES`` order."""

    names: tuple[str, ...]
    points: dict[str, tuple[PathPoint, ...]]
    knee: KneeTranslation | None = None   # moves the shank and foot points (module docstring)

    #: Segments below the knee, carried by the knee's translation.
    BELOW_KNEE = ('shank', 'foot')


def _segment_lengths(p: JumperParameters) -> dict[str, float]:
    s = p.segments
    heel_toe = p.contact.points[1] - p.contact.points[0]
    return {'foot': float(np.hypot(*heel_toe)),
            'shank': float(np.hypot(*s['shank'].distal_joint)),
            'thigh': float(np.hypot(*s['thigh'].distal_joint)),
            'hat': float(np.hypot(*s['hat'].com))}


def _spline(knots: list[float], values: list[float], scale: float) -> CubicSpline:
    return CubicSpline(np.asarray(knots, float), scale * np.asarray(values, float),
                       bc_type='natural')


def load_muscle_geometry(params: JumperParameters | None = None) -> MuscleGeometry:
    """Path points for ``params`` (default: the shipped jumper), scaled as the module says."""
    params = params if params is not None else load_parameters()
    data = None
    for source in (params.source_file, DATA_FILE):
        with open(source, encoding='utf-8') as f:
            data = (yaml.safe_load(f) or {}).get('path_points')
        if data:
            break
    if not data:
        raise ValueError(f'{DATA_FILE} has no path_points section; run '
                         '`python -m nmt_ros.osim.path_points`')
    generic = _segment_lengths(load_parameters(DATA_FILE))
    own = _segment_lengths(params)
    scale = {seg: own[seg] / generic[seg] for seg in SEGMENTS}
    index = {c: i for i, c in enumerate(JOINT_COORDINATES)}
    knee = None
    if 'knee_translation' in data:
        k = data['knee_translation']
        knee = KneeTranslation(coordinate=index[k['coordinate']],
                               x=_spline(k['x_knots'], k['x'], scale['shank']),
                               y=_spline(k['y_knots'], k['y'], scale['shank']))
    points = {}
    for name in MUSCLES:
        if name not in data:
            raise ValueError(f'path_points has no entry for muscle {name!r}')
        entries = []
        for e in data[name]:
            seg = e['segment']
            if seg not in SEGMENTS:
                raise ValueError(f'path point of {name} on unknown segment {seg!r}')
            k = scale[seg]
            if 'moving' in e:
                m = e['moving']
                entries.append(PathPoint(
                    segment=seg, moving_coordinate=index[m['coordinate']],
                    splines=tuple(_spline(m[f'{a}_knots'], m[a], k) for a in 'xyz')))
                continue
            active = e.get('active')
            entries.append(PathPoint(
                segment=seg, xyz=k * np.asarray(e['xyz'], dtype=float),
                active_coordinate=None if active is None else index[active['coordinate']],
                active_range=((-np.inf, np.inf) if active is None
                              else (float(active['range'][0]), float(active['range'][1])))))
        points[name] = tuple(entries)
    return MuscleGeometry(names=MUSCLES, points=points, knee=knee)
