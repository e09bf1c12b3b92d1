"""The scene topic: ``BodyPose`` (``nmt_ros.study.body_scene``) as a Foxglove ``SceneUpdate``.

Foxglove's 3D frame is z up (REP 103: x forward, y left, z up); the model's sagittal plane
(x forward, y up, z toward the subject's right) maps to it as (x, y, z) -> (x, -z, y), so
the body stands in Foxglove's x-z plane and the layout's camera looks at it from the
subject's right (-y). Bones lie in that plane; muscles are drawn ``MUSCLE_OFFSET_M`` toward
the camera so they stay in front of the bones.

``SceneBuilder`` keeps the last seconds of generalized coordinates, muscle forces and ground
wrench (from the estimate topics, or the ``/truth/*`` ones when a stream has no estimates)
and makes one scene per ``period`` of header time, paced by the forces (the last estimate to
arrive) once there are any, each from the newest messages at or before its instant (so the
body, its muscles and the ground force belong together). Each scene entity carries in
its ``metadata`` the header stamps of the three messages it was made from and the forces it
shows, so a viewer (or a test) can tell exactly what it is looking at.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

import foxglove.messages as fm
import numpy as np

from msg_adapters.cdr_arrays import decode_joint_states, decode_wrenches
from msg_adapters.cdr_header import header_stamp_ns
from msg_adapters.validation import reorder_index
from nmt_ros.model.parameters import MUSCLES, Q_NAMES
from nmt_ros.study.body_scene import BodyDescription, BodyPose
from nmt_ros.topics import (
    MUSCLE_FORCES,
    SKELETAL_GENERALIZED_COORDINATES,
    SKELETAL_GROUND_WRENCH,
    TRUTH_GENERALIZED_COORDINATES,
    TRUTH_GROUND_WRENCH,
    TRUTH_MUSCLE_FORCES,
)

#: The scene topic (foxglove.SceneUpdate, protobuf).
SCENE_TOPIC = '/nmt/view/scene'
#: Frame id of the scene entities (the ground frame).
SCENE_FRAME = 'ground'
#: Muscles are drawn this far toward the viewer (Foxglove -y) [m].
MUSCLE_OFFSET_M = 0.03
BONE_THICKNESS_M = 0.025
JOINT_DIAMETER_M = 0.05


@dataclass(frozen=True)
class SceneSource:
    """The three topics a scene is made from."""

    name: str
    coordinates: str
    forces: str
    wrench: str


ESTIMATES = SceneSource('estimates', SKELETAL_GENERALIZED_COORDINATES, MUSCLE_FORCES,
                        SKELETAL_GROUND_WRENCH)
TRUTH = SceneSource('truth', TRUTH_GENERALIZED_COORDINATES, TRUTH_MUSCLE_FORCES,
                    TRUTH_GROUND_WRENCH)
SOURCES = {'estimates': ESTIMATES, 'truth': TRUTH}


def _point(xy: np.ndarray, depth: float = 0.0) -> fm.Point3:
    return fm.Point3(x=float(xy[0]), y=float(depth), z=float(xy[1]))


def _color(rgba: np.ndarray | tuple) -> fm.Color:
    r, g, b, a = (float(v) for v in rgba)
    return fm.Color(r=r, g=g, b=b, a=a)


def _timestamp(stamp_ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=int(stamp_ns // 1_000_000_000), nsec=int(stamp_ns % 1_000_000_000))


def _line(points: np.ndarray, thickness: float, color: np.ndarray | tuple,
          depth: float = 0.0) -> fm.LinePrimitive:
    return fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=float(thickness),
                            scale_invariant=False, points=[_point(p, depth) for p in points],
                            color=_color(color))


def _sphere(xy: np.ndarray, diameter: float, color: tuple) -> fm.SpherePrimitive:
    return fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=float(xy[0]), y=0.0,
                                                               z=float(xy[1])),
                                           orientation=fm.Quaternion(x=0, y=0, z=0, w=1)),
                              size=fm.Vector3(x=diameter, y=diameter, z=diameter),
                              color=_color(color))


def _arrow(tail: np.ndarray, tip: np.ndarray) -> fm.ArrowPrimitive:
    """An arrow from ``tail`` to ``tip`` (sagittal plane, m)."""
    d = np.asarray(tip) - np.asarray(tail)
    length = float(np.hypot(*d))
    # Foxglove's arrow points along +x; rotate about +y by -atan2(dy, dx) to reach (dx, 0, dy)
    half = -0.5 * math.atan2(d[1], d[0])
    head = min(0.08, 0.3 * length)
    return fm.ArrowPrimitive(
        pose=fm.Pose(position=fm.Vector3(x=float(tail[0]), y=-0.01, z=float(tail[1])),
                     orientation=fm.Quaternion(x=0.0, y=math.sin(half), z=0.0,
                                               w=math.cos(half))),
        shaft_length=max(length - head, 0.0), shaft_diameter=0.015, head_length=head,
        head_diameter=0.04, color=_color((0.1, 0.7, 0.2, 1.0)))


def scene_update(pose: BodyPose, stamp_ns: int, metadata: dict[str, str] | None = None,
                 ) -> fm.SceneUpdate:
    """One ``SceneUpdate`` with the entity ``body`` (bones, joints, COM, ground, muscles and
    the ground-force arrow) for ``pose`` at header time ``stamp_ns``."""
    bone = (0.85, 0.85, 0.8, 1.0)
    lines = [_line(points, BONE_THICKNESS_M, bone) for points in pose.segments.values()]
    x = pose.joints['ankle'][0]
    lines.append(_line(np.array([[x - 1.0, 0.0], [x + 1.0, 0.0]]), 0.005, (0.5, 0.5, 0.5, 1)))
    lines += [_line(m.points, m.width_m, m.color, -MUSCLE_OFFSET_M) for m in pose.muscles]
    spheres = [_sphere(p, JOINT_DIAMETER_M, (0.3, 0.3, 0.3, 1.0)) for p in pose.joints.values()]
    spheres.append(_sphere(pose.com, 0.07, (0.95, 0.75, 0.1, 1.0)))
    arrows = [] if pose.cop is None else [_arrow(pose.cop, pose.grf_tip)]
    meta = [fm.KeyValuePair(key=k, value=v) for k, v in (metadata or {}).items()]
    entity = fm.SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=SCENE_FRAME, id='body',
                            frame_locked=False, lines=lines, spheres=spheres, arrows=arrows,
                            metadata=meta)
    return fm.SceneUpdate(entities=[entity])


class SceneBuilder:
    """A stream's coordinates, forces and wrench -> a scene every ``period`` of stream time.

    ``source`` is ``'estimates'``, ``'truth'`` or ``'auto'`` (estimates as soon as the
    stream has carried estimated coordinates, until then truth). Messages arrive as CDR
    bytes (what the graph and the bags carry). The muscle forces come last in the graph (Stage
    2 runs on Stage 1's output), so once the stream has carried forces a scene is made when a
    forces message is due, with the newest coordinates and wrench stamped at or before it
    (kept for ``history_s`` of stream time); until then, when a coordinates message is due.
    """

    def __init__(self, body: BodyDescription | None = None, rate_hz: float = 30.0,
                 source: str = 'auto', history_s: float = 2.0) -> None:
        if source not in ('auto', *SOURCES):
            raise ValueError(f"scene source must be 'auto', 'estimates' or 'truth', not "
                             f'{source!r}')
        if not rate_hz > 0:
            raise ValueError(f'scene rate must be positive, got {rate_hz} Hz')
        self.body = body if body is not None else BodyDescription()
        self.period_ns = int(round(1e9 / rate_hz))
        self.history_ns = int(round(history_s * 1e9))
        self.source = source
        self.history: dict[str, deque[tuple[int, bytes]]] = {}
        self.next_ns: int | None = None
        self.seen_estimates = source == 'estimates'
        chosen = SOURCES.values() if source == 'auto' else [SOURCES[source]]
        #: Every topic the builder may use.
        self.topics = frozenset(t for s in chosen for t in (s.coordinates, s.forces, s.wrench))


    def active_source(self) -> SceneSource:
        if self.source != 'auto':
            return SOURCES[self.source]
        return ESTIMATES if self.seen_estimates else TRUTH

    def _newest_at(self, topic: str, stamp_ns: int) -> tuple[int, bytes] | None:
        """The newest message of ``topic`` stamped at or before ``stamp_ns``."""
        for entry in reversed(self.history.get(topic, ())):
            if entry[0] <= stamp_ns:
                return entry
        return None

    def update(self, topic: str, data: bytes) -> fm.SceneUpdate | None:
        """Take one message; a scene when it paces the scene and one is due."""
        if topic not in self.topics:
            return None
        if topic == ESTIMATES.coordinates and not self.seen_estimates:
            self.seen_estimates = True
            self.next_ns = None
        stamp = header_stamp_ns(data)
        history = self.history.setdefault(topic, deque())
        history.append((stamp, data))
        while history and history[0][0] < stamp - self.history_ns:
            history.popleft()
        source = self.active_source()
        pace = source.forces if source.forces in self.history else source.coordinates
        if topic != pace or (self.next_ns is not None and stamp < self.next_ns):
            return None
        late = self.next_ns is None or stamp - self.next_ns > self.period_ns
        self.next_ns = stamp + self.period_ns if late else self.next_ns + self.period_ns
        return self.make(source, stamp)

    def make(self, source: SceneSource, stamp_ns: int) -> fm.SceneUpdate | None:
        """The scene at ``stamp_ns`` from the newest messages of ``source`` stamped at or
        before it (None without coordinates)."""
        coords = self._newest_at(source.coordinates, stamp_ns)
        if coords is None:
            return None
        qs = decode_joint_states([coords[1]])
        q = qs.position[0, reorder_index(qs.names, Q_NAMES, source.coordinates)]
        meta = {'source': source.name, 'coordinates_stamp_ns': str(int(qs.stamp_ns[0]))}
        forces = wrench = None
        entry = self._newest_at(source.forces, stamp_ns)
        if entry is not None:
            fs = decode_joint_states([entry[1]])
            forces = fs.effort[0, reorder_index(fs.names, MUSCLES, source.forces)]
            meta['forces_stamp_ns'] = str(int(fs.stamp_ns[0]))
            meta.update({f'force_{m}_n': repr(float(v)) for m, v in zip(MUSCLES, forces)})
        entry = self._newest_at(source.wrench, stamp_ns)
        if entry is not None:
            ws = decode_wrenches([entry[1]])
            wrench = np.array([ws.force[0, 0], ws.force[0, 1], ws.torque[0, 2]])
            meta['wrench_stamp_ns'] = str(int(ws.stamp_ns[0]))
        pose = self.body.pose(q, forces, wrench)
        return scene_update(pose, int(qs.stamp_ns[0]), meta)
