"""The body as a picture: one description that the live view and the rendered movie both draw.

From the generalized coordinates ``q[6] = [th1..th4, r1, r2]`` (rad, m), the musculotendon
forces ``f[9]`` (N) and the planar ground wrench ``[Fx, Fy, Mz about the foot COM]`` (N, N m)
it makes, in the ground frame (x forward, y up, m):

- the stick figure: each segment as a polyline through the model's own joint centres and
  contact points (``JumperModel.positions``): foot = heel, ankle, toe; shank = knee to ankle;
  thigh = hip to knee; HAT = hip to twice its COM offset (a trunk line through the COM);
- the whole-body centre of mass;
- each muscle along its path: its path points (``model.muscle_geometry``, the OpenSim path
  the length polynomials were fitted to) placed by the same segment frames (plus the knee's
  translation below the knee, at most ~1 cm, which the pin knee of the skeleton leaves out),
  with its force,
  force / F0, a colour (blue at 0, red at F0) and a line width (``muscle_width_m``);
- the ground force as an arrow from the centre of pressure (where the ground wrench's line
  of action meets y = 0), ``GRF_SCALE_M_PER_BW`` long per body weight.

No ROS and no drawing library here: ``nmt_ros.view.scene`` turns a ``BodyPose`` into a
Foxglove ``SceneUpdate`` and ``nmt_ros.study.body_movie`` into matplotlib artists.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmt_ros.model.jumper import JumperModel, default_model
from nmt_ros.model.muscle_geometry import MuscleGeometry, load_muscle_geometry
from nmt_ros.model.parameters import SEGMENTS
from nmt_ros.model.skeleton import JOINT_MAP

#: Length of the ground-force arrow per body weight [m / BW].
GRF_SCALE_M_PER_BW = 0.3
#: Below this vertical force [N] the ground wrench has no centre of pressure worth drawing.
MIN_COP_FORCE_N = 20.0
#: Index of each segment's angle in q and the model output that is its frame origin.
SEGMENT_ORIGIN = {'foot': 'ankle', 'shank': 'knee', 'thigh': 'hip', 'hat': 'hip'}


def muscle_color(fraction: np.ndarray | float) -> np.ndarray:
    """RGBA [..., 4] in 0..1 of a muscle at ``fraction`` = F / F0: blue (0) to red (>= 1)."""
    x = np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)[..., None]
    low, high = np.array([0.15, 0.35, 0.95, 0.9]), np.array([0.95, 0.1, 0.1, 0.9])
    return (1.0 - x) * low + x * high


def muscle_width_m(fraction: np.ndarray | float) -> np.ndarray:
    """Line width [m] of a muscle at ``fraction`` = F / F0 (8 mm idle to 48 mm at F0)."""
    return 0.008 + 0.040 * np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)


def center_of_pressure_x(foot_com: np.ndarray, wrench: np.ndarray,
                         min_force_n: float = MIN_COP_FORCE_N) -> np.ndarray:
    """x [n] (m) where the line of action of the ground force meets the ground (y = 0).

    ``foot_com[n, 2]`` (m), ``wrench[n, 3]`` = [Fx, Fy, Mz about the foot COM] (N, N m). With
    the force applied at (x, 0): Mz = (x - cx) Fy - (0 - cy) Fx, so x = cx + (Mz - cy Fx) / Fy.
    NaN where Fy < ``min_force_n``.
    """
    foot_com = np.atleast_2d(foot_com)
    wrench = np.atleast_2d(wrench)
    fx, fy, mz = wrench[:, 0], wrench[:, 1], wrench[:, 2]
    loaded = fy >= min_force_n
    x = np.full(fy.shape, np.nan)
    x[loaded] = foot_com[loaded, 0] + (mz[loaded] - foot_com[loaded, 1] * fx[loaded]) / fy[loaded]
    return x


@dataclass(frozen=True)
class MuscleLine:
    """A muscle drawn along its path at one instant."""

    name: str
    points: np.ndarray          # [k, 2] ground frame (m), the active path points in order
    force_n: float              # NaN when unknown
    fraction: float             # force / F0 (NaN when unknown)
    color: np.ndarray           # RGBA [4] in 0..1
    width_m: float


@dataclass(frozen=True)
class BodyPose:
    """Everything drawn at one instant (ground frame, m)."""

    segments: dict[str, np.ndarray]     # name -> polyline [k, 2]
    joints: dict[str, np.ndarray]       # ankle, knee, hip -> [2]
    contact_points: np.ndarray          # [2, 2] heel, toe
    com: np.ndarray                     # [2]
    muscles: tuple[MuscleLine, ...]
    cop: np.ndarray | None              # [2] centre of pressure, None when unloaded
    ground_force: np.ndarray | None     # [2] N (Fx, Fy), None when unknown
    grf_tip: np.ndarray | None          # [2] end of the ground-force arrow


class BodyDescription:
    """Turns states (and forces) into ``BodyPose``s with the model's kinematics."""

    def __init__(self, model: JumperModel | None = None,
                 geometry: MuscleGeometry | None = None) -> None:
        self.model = model if model is not None else default_model()
        self.geometry = geometry if geometry is not None else load_muscle_geometry(self.model.p)
        self.f0 = np.asarray(self.model.p.muscles.f0, dtype=float)
        self.body_weight_n = float(self.model.p.body_weight)
        # every path point of every muscle in one array, so a pose is a few numpy operations
        self._points = [pt for name in self.geometry.names for pt in self.geometry.points[name]]
        self._segment_index = np.array([SEGMENTS.index(pt.segment) for pt in self._points])
        self._fixed = np.array([pt.xyz if pt.xyz is not None else np.zeros(3)
                                for pt in self._points])
        self._moving = [k for k, pt in enumerate(self._points) if pt.moving_coordinate is not None]
        self._below_knee = np.array([pt.segment in self.geometry.BELOW_KNEE
                                     for pt in self._points])
        self._conditional = [k for k, pt in enumerate(self._points)
                             if pt.active_coordinate is not None]
        self._slices, start = {}, 0
        for name in self.geometry.names:
            count = len(self.geometry.points[name])
            self._slices[name] = slice(start, start + count)
            start += count

    # ------------------------------------------------------------------ vectorised pieces
    def positions(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Model positions for ``q[n, 6]``: ankle, knee, hip [n, 2], coms [n, 2, 4],
        contact_points [n, 2, 2] (columns heel, toe), com [n, 2]."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        ankle, knee, hip, coms, contacts, com = self.model.batch(self.model.positions, q)
        return {'ankle': ankle, 'knee': knee, 'hip': hip, 'coms': coms,
                'contact_points': contacts, 'com': com}

    def muscle_paths_3d(self, q: np.ndarray, positions: dict[str, np.ndarray] | None = None,
                        ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per muscle: path points [n, k, 3] in the ground frame (x, y; z lateral as in the
        segment frame) and whether each is on the path [n, k], for ``q[n, 6]``."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pos = self.positions(q) if positions is None else positions
        theta = q @ JOINT_MAP.T
        n = q.shape[0]
        local = np.broadcast_to(self._fixed, (n,) + self._fixed.shape).copy()
        active = np.ones((n, len(self._points)), dtype=bool)
        for k in self._moving:
            local[:, k] = self._points[k].local(theta)
        for k in self._conditional:
            active[:, k] = self._points[k].active(theta)
        th = q[:, self._segment_index]                                    # [n, P]
        origin = np.stack([pos[SEGMENT_ORIGIN[seg]] for seg in SEGMENTS], axis=1)
        origin = origin[:, self._segment_index]                           # [n, P, 2]
        c, s = np.cos(th), np.sin(th)
        xyz = np.stack([origin[..., 0] + c * local[..., 0] - s * local[..., 1],
                        origin[..., 1] + s * local[..., 0] + c * local[..., 1],
                        local[..., 2]], axis=-1)
        if self.geometry.knee is not None:
            # the knee's translation carries the shank and the foot (muscle_geometry)
            shift = self.geometry.knee.shift(theta)                       # shank frame
            cs, ss = np.cos(q[:, 1]), np.sin(q[:, 1])
            xyz[:, self._below_knee, 0] += (cs * shift[:, 0] - ss * shift[:, 1])[:, None]
            xyz[:, self._below_knee, 1] += (ss * shift[:, 0] + cs * shift[:, 1])[:, None]
        return {name: (xyz[:, sl], active[:, sl]) for name, sl in self._slices.items()}

    def path_lengths(self, q: np.ndarray) -> np.ndarray:
        """3-D length [n, 9] (m) of each muscle's polyline through its active points."""
        paths = self.muscle_paths_3d(q)
        lengths = []
        for name in self.geometry.names:
            xyz, active = paths[name]
            total = np.zeros(xyz.shape[0])
            for i in range(xyz.shape[0]):
                pts = xyz[i][active[i]]
                total[i] = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
            lengths.append(total)
        return np.stack(lengths, axis=1)

    # ------------------------------------------------------------------ poses
    def poses(self, q: np.ndarray, forces: np.ndarray | None = None,
              wrench: np.ndarray | None = None) -> list[BodyPose]:
        """One ``BodyPose`` per row of ``q[n, 6]``; ``forces[n, 9]`` (N) and ``wrench[n, 3]``
        (N, N, N m about the foot COM) are optional (rows of NaN = unknown)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        n = q.shape[0]
        if q.shape[1] != 6:
            raise ValueError(f'q must have 6 columns [th1..th4, r1, r2], got {q.shape}')
        forces = (np.full((n, len(self.f0)), np.nan) if forces is None
                  else np.atleast_2d(np.asarray(forces, dtype=float)))
        wrench = (np.full((n, 3), np.nan) if wrench is None
                  else np.atleast_2d(np.asarray(wrench, dtype=float)))
        if forces.shape != (n, len(self.f0)) or wrench.shape != (n, 3):
            raise ValueError(f'forces must be [{n}, {len(self.f0)}] and wrench [{n}, 3], got '
                             f'{forces.shape} and {wrench.shape}')
        pos = self.positions(q)
        paths = self.muscle_paths_3d(q, pos)
        fraction = forces / self.f0
        colors = muscle_color(np.nan_to_num(fraction))
        widths = muscle_width_m(np.nan_to_num(fraction))
        foot_com = pos['coms'][:, :, 0]
        cop_x = center_of_pressure_x(foot_com, np.nan_to_num(wrench, nan=0.0))
        result = []
        for i in range(n):
            heel, toe = pos['contact_points'][i, :, 0], pos['contact_points'][i, :, 1]
            ankle, knee, hip = pos['ankle'][i], pos['knee'][i], pos['hip'][i]
            hat_com = pos['coms'][i, :, 3]
            segments = {'foot': np.stack([heel, ankle, toe, heel]),
                        'shank': np.stack([knee, ankle]),
                        'thigh': np.stack([hip, knee]),
                        'hat': np.stack([hip, 2.0 * hat_com - hip])}
            muscles = []
            for j, name in enumerate(self.geometry.names):
                xyz, active = paths[name]
                muscles.append(MuscleLine(
                    name=name, points=xyz[i][active[i]][:, :2].copy(),
                    force_n=float(forces[i, j]), fraction=float(fraction[i, j]),
                    color=colors[i, j], width_m=float(widths[i, j])))
            known = bool(np.all(np.isfinite(wrench[i, :2])))
            cop = None if np.isnan(cop_x[i]) else np.array([cop_x[i], 0.0])
            tip = (None if cop is None else
                   cop + wrench[i, :2] * GRF_SCALE_M_PER_BW / self.body_weight_n)
            result.append(BodyPose(
                segments=segments, joints={'ankle': ankle, 'knee': knee, 'hip': hip},
                contact_points=np.stack([heel, toe]), com=pos['com'][i],
                muscles=tuple(muscles), cop=cop,
                ground_force=wrench[i, :2].copy() if known else None, grf_tip=tip))
        return result

    def pose(self, q: np.ndarray, forces: np.ndarray | None = None,
             wrench: np.ndarray | None = None) -> BodyPose:
        """``poses`` for one instant (``q[6]``, ``forces[9]``, ``wrench[3]``)."""
        return self.poses(np.asarray(q)[None],
                          None if forces is None else np.asarray(forces)[None],
                          None if wrench is None else np.asarray(wrench)[None])[0]
