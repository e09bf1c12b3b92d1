"""OpenSim-side measures of a subject's model and of its inverse kinematics, exchanged as files.

Run as subprocesses (OpenSim cannot share a process with casadi)::

    python -m nmt_ros.osim.subject measure --model M.osim --out OUT.json
    python -m nmt_ros.osim.subject kinematics --model M.osim --ik IK.mot --out OUT.npz
    python -m nmt_ros.osim.subject scaled-jumper --model gait10dof18musc.osim --spec S.json \
        --out OUT.json     (the cross-check of nmt_ros.model.subject: see scaled_jumper)
    python -m nmt_ros.osim.subject moment-arms --model M.osim --spec S.json --out OUT.json
                           (the subject's muscles lumped as the jumper's: group_moment_arms)

Models named as OpenSim's gait2392 / gait10dof18musc / Rajagopal (2015) lineage are
understood: bodies ``pelvis``, ``torso``, ``femur_{r,l}``, ``tibia_{r,l}``, ``talus_{r,l}``,
``calcn_{r,l}``, ``toes_{r,l}`` (arms optional), each joint found by its child body.

``measure`` (default pose, every coordinate at its default value) writes JSON with:
  ``total_mass_kg``; ``segment_masses_kg`` lumped as the planar jumper lumps them, two legs
  (foot = talus + calcn + toes, shank = tibia + patella, thigh = femur, hat = pelvis + torso +
  arms; bodies of no segment are listed under ``unassigned_bodies``);
  ``segment_lengths_m`` (mean of the two legs, 3-D distances): thigh = hip centre to knee
  centre, shank = knee centre to ankle centre, foot = ankle centre to MTP joint centre;
  ``markers_m``: every marker's position in ground [x, y, z];
  ``landmarks_m``: the landmarks below, in ground.

``kinematics`` poses the model at every row of an inverse-kinematics .mot (``inDegrees``
honoured; translations in m) and writes per row, in ground [n, 3] (m), the body-fixed
landmarks that define the sagittal segment lines of ``nmt_ros.study.sagittal``:
  ``{s}_hip`` (femur), ``{s}_knee`` (the knee joint's tibia frame: the knee centre both
  lines share, as in a marker analysis), ``{s}_ankle`` (tibia),
  ``{s}_subtalar`` (calcn), ``{s}_mtp`` (calcn), ``{s}_hip_pelvis`` (pelvis),
  ``{s}_shoulder`` (torso: the shoulder joint's parent frame, or where the model has no arms a
  point 0.45 m up the torso's y axis) for s in r, l; ``time`` [n]; ``default_<name>`` [3]
  the same landmarks in the default pose; ``coordinates`` the .mot labels used.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
import json
from pathlib import Path
import sys
import tempfile

import numpy as np
import opensim as osim

from nmt_ros.osim.fit_paths import quiet_opensim

SIDES = ('r', 'l')
#: Planar segment of each body (gait2392 / Rajagopal names, side suffix removed).
SEGMENT_OF_BODY = {
    'talus': 'foot', 'calcn': 'foot', 'toes': 'foot',
    'tibia': 'shank', 'patella': 'shank',
    'femur': 'thigh',
    'pelvis': 'hat', 'torso': 'hat', 'humerus': 'hat', 'ulna': 'hat', 'radius': 'hat',
    'hand': 'hat',
}
#: Torso-fixed stand-in for the shoulders when a model has no arms [m, torso frame].
TORSO_TOP_Y = 0.45


def _vec(v: osim.Vec3) -> np.ndarray:
    return np.array([v.get(0), v.get(1), v.get(2)])


def load(path: str | Path) -> tuple[osim.Model, osim.State]:
    quiet_opensim()
    model = osim.Model(str(path))
    state = model.initSystem()
    return model, state


def _joint_by_child(model: osim.Model) -> dict[str, osim.Joint]:
    out = {}
    for joint in model.getJointSet():
        out[joint.getChildFrame().findBaseFrame().getName()] = joint
    return out


def _require(joints: dict[str, osim.Joint], body: str, path: str) -> osim.Joint:
    if body not in joints:
        raise ValueError(f'{path}: no joint with child body {body!r} (bodies: '
                         f'{", ".join(sorted(joints))}); the model must use gait2392/Rajagopal '
                         'body names')
    return joints[body]


class Landmarks:
    """Body-fixed landmark frames of a model (see the module docstring)."""

    def __init__(self, model: osim.Model, path: str = 'model') -> None:
        joints = _joint_by_child(model)
        self.frames: dict[str, osim.Frame] = {}
        self.torso_top: osim.Frame | None = None
        for s in SIDES:
            hip = _require(joints, f'femur_{s}', path)
            knee = _require(joints, f'tibia_{s}', path)
            ankle = _require(joints, f'talus_{s}', path)
            subtalar = _require(joints, f'calcn_{s}', path)
            mtp = _require(joints, f'toes_{s}', path)
            self.frames[f'{s}_hip'] = hip.getChildFrame()
            self.frames[f'{s}_hip_pelvis'] = hip.getParentFrame()
            self.frames[f'{s}_knee'] = knee.getChildFrame()
            self.frames[f'{s}_ankle'] = ankle.getParentFrame()
            self.frames[f'{s}_subtalar'] = subtalar.getChildFrame()
            self.frames[f'{s}_mtp'] = mtp.getParentFrame()
            if f'humerus_{s}' in joints:
                self.frames[f'{s}_shoulder'] = joints[f'humerus_{s}'].getParentFrame()
        if not model.getBodySet().contains('torso'):
            raise ValueError(f'{path}: no body "torso"')
        self.torso = model.getBodySet().get('torso')

    def positions(self, state: osim.State) -> dict[str, np.ndarray]:
        """Landmark positions in ground [3] (m) at the realised state."""
        out = {name: _vec(f.getPositionInGround(state)) for name, f in self.frames.items()}
        for s in SIDES:
            if f'{s}_shoulder' not in out:
                out[f'{s}_shoulder'] = _vec(self.torso.findStationLocationInGround(
                    state, osim.Vec3(0.0, TORSO_TOP_Y, 0.0)))
        return out


def measure(path: str | Path) -> dict:
    """Masses, segment lengths, markers and landmarks of a model in its default pose."""
    model, state = load(path)
    model.realizePosition(state)
    masses = {seg: 0.0 for seg in ('foot', 'shank', 'thigh', 'hat')}
    unassigned = []
    total = 0.0
    for body in model.getBodySet():
        name = body.getName()
        total += body.getMass()
        base = name[:-2] if name[-2:] in ('_r', '_l') else name
        seg = SEGMENT_OF_BODY.get(base)
        if seg is None:
            unassigned.append(name)
        else:
            masses[seg] += body.getMass()
    marks = Landmarks(model, str(path)).positions(state)

    def dist(a: str, b: str) -> float:
        return float(np.mean([np.linalg.norm(marks[f'{s}_{b}'] - marks[f'{s}_{a}'])
                              for s in SIDES]))

    lengths = {'thigh': dist('hip', 'knee'), 'shank': dist('knee', 'ankle'),
               'foot': dist('ankle', 'mtp')}
    markers = {m.getName(): _vec(m.getLocationInGround(state)).tolist()
               for m in model.getMarkerSet()}
    return {'model': str(path), 'total_mass_kg': total, 'segment_masses_kg': masses,
            'unassigned_bodies': unassigned, 'segment_lengths_m': lengths,
            'markers_m': markers, 'landmarks_m': {k: v.tolist() for k, v in marks.items()}}


@dataclass(frozen=True)
class Table:
    """An OpenSim .sto/.mot table read with OpenSim's own TimeSeriesTable."""

    time: np.ndarray          # [n] s
    labels: tuple[str, ...]
    data: np.ndarray          # [n, k]
    in_degrees: bool

    def column(self, label: str) -> np.ndarray:
        """[n] values of one column; ValueError naming the file's columns if absent."""
        if label not in self.labels:
            raise ValueError(f'no column {label!r} (columns: {", ".join(self.labels)})')
        return self.data[:, self.labels.index(label)]


def read_opensim_table(path: str | Path) -> Table:
    """A .sto/.mot file through ``osim.TimeSeriesTable`` (``inDegrees`` from its header)."""
    quiet_opensim()
    table = osim.TimeSeriesTable(str(path))
    keys = list(table.getTableMetaDataKeys())
    in_deg = ('inDegrees' in keys
              and table.getTableMetaDataAsString('inDegrees').strip().lower() == 'yes')
    data = table.getMatrix().to_numpy() if table.getNumRows() else np.zeros((0, 0))
    return Table(time=np.asarray(table.getIndependentColumn(), dtype=float),
                 labels=tuple(table.getColumnLabels()), data=np.asarray(data, dtype=float),
                 in_degrees=in_deg)


def _ik_table(path: str | Path) -> tuple[np.ndarray, list[str], np.ndarray, bool]:
    table = read_opensim_table(path)
    return table.time, list(table.labels), table.data, table.in_degrees


def kinematics(model_path: str | Path, ik_path: str | Path) -> dict[str, np.ndarray]:
    """Landmarks in ground [n, 3] at every row of an IK .mot (module docstring)."""
    model, state = load(model_path)
    marks = Landmarks(model, str(model_path))
    model.realizePosition(state)
    out: dict[str, np.ndarray] = {f'default_{k}': v for k, v in marks.positions(state).items()}
    time, labels, values, in_deg = _ik_table(ik_path)
    if not np.all(np.isfinite(values)):
        rows = np.unique(np.nonzero(~np.isfinite(values))[0])
        raise ValueError(f'{ik_path}: NaN/inf coordinates at {rows.size} row(s), first at '
                         f't = {time[rows[0]]:.4f} s')
    coords = model.getCoordinateSet()
    missing = [c.getName() for c in coords if c.getName() not in labels]
    used = [lab for lab in labels if coords.contains(lab)]
    unknown = [lab for lab in labels if not coords.contains(lab)]
    if unknown:
        raise ValueError(f'{ik_path}: column(s) {", ".join(unknown)} are not coordinates of '
                         f'{model_path}')
    rot = np.array([coords.get(lab).getMotionType() == osim.Coordinate.Rotational
                    for lab in used])
    index = [labels.index(lab) for lab in used]
    q = values[:, index].copy()
    if in_deg:
        q[:, rot] = np.deg2rad(q[:, rot])
    per: dict[str, list[np.ndarray]] = {}
    for i in range(time.size):
        for j, lab in enumerate(used):
            coords.get(lab).setValue(state, float(q[i, j]), False)
        model.realizePosition(state)
        for k, v in marks.positions(state).items():
            per.setdefault(k, []).append(v)
    out.update({k: np.array(v) for k, v in per.items()})
    out['time'] = time
    out['coordinates'] = np.array(used)
    out['coordinates_at_default'] = np.array(missing)
    return out


#: Bodies of gait10dof18musc per planar segment (for OpenSim's own scaling of the jumper).
JUMPER_BODIES = {'hat': ('pelvis', 'torso'), 'thigh': ('femur_r', 'femur_l'),
                 'shank': ('tibia_r', 'tibia_l'),
                 'foot': ('talus_r', 'talus_l', 'calcn_r', 'calcn_l', 'toes_r', 'toes_l')}
JUMPER_COORDINATES = ('ankle_angle_r', 'knee_angle_r', 'hip_flexion_r')


def scaled_jumper(source: str | Path, length: dict[str, float], mass_kg: float,
                  poses: np.ndarray, muscles: list[str]) -> dict:
    """OpenSim's own scaling of the jumper's source model (gait10dof18musc): every body of a
    planar segment scaled uniformly by that segment's length factor, masses to ``mass_kg``
    with the distribution preserved; then the measures and, at ``poses`` [n, 3] (ankle, knee,
    hip, rad), the right-leg ``muscles``' lengths [n, m] and moment arms [n, m, 3]."""
    model, state = load(source)
    scales = osim.ScaleSet()
    for seg, bodies in JUMPER_BODIES.items():
        for body in bodies:
            sc = osim.Scale()
            sc.setSegmentName(body)
            k = float(length[seg])
            sc.setScaleFactors(osim.Vec3(k, k, k))
            sc.setApply(True)
            scales.cloneAndAppend(sc)
    model.scale(state, scales, True, float(mass_kg))
    path = Path(tempfile.mkdtemp()) / 'scaled.osim'
    model.printToXML(str(path))
    out = measure(path)
    model, state = load(path)
    coords = [model.getCoordinateSet().get(c) for c in JUMPER_COORDINATES]
    lmt = np.zeros((poses.shape[0], len(muscles)))
    arms = np.zeros((poses.shape[0], len(muscles), 3))
    for i, pose in enumerate(np.asarray(poses, dtype=float)):
        for c, v in zip(coords, pose):
            c.setValue(state, float(v), False)
        model.realizeVelocity(state)
        for j, name in enumerate(muscles):
            m = model.getMuscles().get(name)
            lmt[i, j] = m.getLength(state)
            for k, c in enumerate(coords):
                arms[i, j, k] = m.computeMomentArm(state, c)
    out.update({'musculotendon_lengths_m': lmt.tolist(), 'moment_arms_m': arms.tolist(),
                'optimal_fiber_length_m': [model.getMuscles().get(n).getOptimalFiberLength()
                                           for n in muscles],
                'tendon_slack_length_m': [model.getMuscles().get(n).getTendonSlackLength()
                                          for n in muscles]})
    return out


def group_moment_arms(source: str | Path, groups: dict[str, list[list[str]]],
                      coordinates: dict[str, list[str]], ranges_deg: dict[str, list[float]],
                      step_deg: float) -> dict:
    """Moment arms of the subject's own muscles lumped as the jumper lumps them: for each
    jumper muscle, the first alternative of its group (``groups``: lists of right-leg muscle
    names without ``_r``) the model has in full; on a grid over its ``coordinates`` (jumper
    coordinate names, ``ranges_deg`` in the jumper's convention, every other joint at 0), the
    F0-weighted mean moment arm [m] about each of them, with the members' maximum
    isometric forces ``f0_n`` [N] and optimal fibre lengths ``l_opt_m`` [m]. Coordinate
    signs are the jumper's (gait10dof18musc): a model whose knee_angle_r flexes positive
    (Rajagopal: range 0..140 deg) is posed at -knee and its knee moment arms negated.
    Muscles none of whose alternatives the model has in full are listed as missing.
    ``coordinate_ranges`` gives each of the three coordinates' range [rad, jumper's sign,
    ascending] and whether the model clamps it (its IK cannot leave the range)."""
    model, state = load(source)
    cs = model.getCoordinateSet()
    muscles = model.getMuscles()
    sign = {}
    for c in ('hip_flexion', 'knee_angle', 'ankle_angle'):
        if not cs.contains(c + '_r'):
            raise ValueError(f'{source}: no coordinate {c}_r')
        coord = cs.get(c + '_r')
        flexion_positive = (c == 'knee_angle'
                            and coord.getRangeMax() > abs(coord.getRangeMin()))
        sign[c] = -1.0 if flexion_positive else 1.0
    ranges = {}
    for c, k in sign.items():
        coord = cs.get(c + '_r')
        lo, hi = sorted((k * coord.getRangeMin(), k * coord.getRangeMax()))
        ranges[c] = {'range_rad': [float(lo) + 0.0, float(hi) + 0.0],
                     'clamped': bool(coord.getDefaultClamped())}
    out: dict = {'model': str(source), 'coordinate_sign': sign, 'coordinate_ranges': ranges,
                 'muscles': {}, 'missing': {}}
    for lumped, alternatives in groups.items():
        complete = [[m + '_r' for m in members] for members in alternatives
                    if all(muscles.contains(m + '_r') for m in members)]
        if not complete:
            out['missing'][lumped] = [' + '.join(m + '_r' for m in members)
                                      for members in alternatives]
            continue
        names = complete[0]
        f0 = np.array([muscles.get(n).getMaxIsometricForce() for n in names])
        l_opt = [muscles.get(n).getOptimalFiberLength() for n in names]
        coords = list(coordinates[lumped])
        axes = [np.radians(np.arange(ranges_deg[c][0], ranges_deg[c][1] + 1e-9, step_deg))
                for c in coords]
        points = np.array(np.meshgrid(*axes, indexing='ij')).reshape(len(coords), -1).T
        arms = np.zeros(points.shape)
        for i, pose in enumerate(points):
            for c in ('hip_flexion', 'knee_angle', 'ankle_angle'):
                value = pose[coords.index(c)] if c in coords else 0.0
                cs.get(c + '_r').setValue(state, sign[c] * float(value))
            model.realizePosition(state)
            for k, c in enumerate(coords):
                r = [muscles.get(n).getGeometryPath().computeMomentArm(state, cs.get(c + '_r'))
                     for n in names]
                arms[i, k] = sign[c] * float(np.dot(f0, r) / f0.sum())
        out['muscles'][lumped] = {'members': names, 'f0_n': f0.tolist(), 'l_opt_m': l_opt,
                                  'coordinates': coords,
                                  'points_rad': points.tolist(), 'moment_arms_m': arms.tolist()}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m nmt_ros.osim.subject')
    sub = parser.add_subparsers(dest='cmd', required=True)
    p = sub.add_parser('measure')
    p.add_argument('--model', required=True)
    p.add_argument('--out', required=True)
    p = sub.add_parser('kinematics')
    p.add_argument('--model', required=True)
    p.add_argument('--ik', required=True)
    p.add_argument('--out', required=True)
    p = sub.add_parser('scaled-jumper', help='OpenSim scaling of the jumper source model')
    p.add_argument('--model', required=True, help='gait10dof18musc.osim')
    p.add_argument('--spec', required=True,
                   help='JSON: {"length": {segment: factor}, "mass_kg": M, "poses": [[..]], '
                   '"muscles": [names]}')
    p.add_argument('--out', required=True)
    p = sub.add_parser('moment-arms', help="the subject's muscles lumped as the jumper's")
    p.add_argument('--model', required=True)
    p.add_argument('--spec', required=True, help='JSON: {"groups": {...}, "coordinates": '
                   '{...}, "ranges_deg": {...}, "step_deg": S} (see group_moment_arms)')
    p.add_argument('--out', required=True)
    args = parser.parse_args(argv)
    try:
        if args.cmd == 'measure':
            Path(args.out).write_text(json.dumps(measure(args.model), indent=1))
        elif args.cmd == 'scaled-jumper':
            spec = json.loads(Path(args.spec).read_text())
            res = scaled_jumper(args.model, spec['length'], spec['mass_kg'],
                                np.asarray(spec['poses'], dtype=float), spec['muscles'])
            Path(args.out).write_text(json.dumps(res))
        elif args.cmd == 'moment-arms':
            spec = json.loads(Path(args.spec).read_text())
            res = group_moment_arms(args.model, spec['groups'], spec['coordinates'],
                                    spec['ranges_deg'], float(spec['step_deg']))
            Path(args.out).write_text(json.dumps(res))
        else:
            np.savez(args.out, **kinematics(args.model, args.ik))
    except (ValueError, RuntimeError) as err:
        print(f'error: {err}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
