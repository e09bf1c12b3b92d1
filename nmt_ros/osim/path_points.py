"""Muscle path points of gait10dof18musc in the jumper's segment frames (for drawing).

    python -m nmt_ros.osim.path_points           # write the section into model/data/jumper.yaml
    python -m nmt_ros.osim.path_points --print   # print it

The model's musculotendon lengths are polynomials (``paths``); a picture of a muscle needs
the points its path runs through. This reads the nine right-leg muscles' ``GeometryPath``
point sets straight from ``data/opensim/gait10dof18musc.osim`` (XML; OpenSim itself is not
needed) and expresses each point in the frame of the lumped segment its body belongs to:

- ``pelvis`` -> HAT (origin at the hip centre): minus the hip joint's location in the pelvis;
- ``femur_r`` -> thigh (origin at the hip centre): as is;
- ``tibia_r`` -> shank (origin at the knee centre, pin knee): as is;
- ``talus_r`` -> foot (origin at the ankle centre): as is; ``calcn_r`` plus the subtalar
  weld's offset in the talus; ``toes_r`` plus the MTP weld's offset on top.

Joint offsets are read from the same file (every offset frame of these joints has zero
orientation; checked). A ``ConditionalPathPoint`` keeps its coordinate and range (the point is
on the path while the coordinate is inside it), a ``MovingPathPoint`` its x, y and z knots as
functions of its coordinate. Coordinates are renamed to the model's (``hip_flexion_r`` ->
``hip_flexion``, signs are the same). z (lateral, m) is kept so that the 3-D polyline length
can be checked against the model's musculotendon length polynomial (test_body_scene).
"""
from __future__ import annotations

import argparse
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np

from nmt_ros.model.parameters import DATA_FILE, MUSCLES

REPO_ROOT = Path(__file__).resolve().parents[2]
OSIM_FILE = REPO_ROOT / 'data' / 'opensim' / 'gait10dof18musc.osim'
BEGIN_MARK = '# BEGIN GENERATED PATH POINTS'
END_MARK = '# END GENERATED PATH POINTS'
#: The model's muscle name -> gait10dof18musc's right-leg muscle.
OSIM_MUSCLE = {'gmax': 'glut_max_r', 'ilpso': 'iliopsoas_r', 'hams': 'hamstrings_r',
               'bfsh': 'bifemsh_r', 'rf': 'rect_fem_r', 'vas': 'vasti_r', 'gas': 'gastroc_r',
               'sol': 'soleus_r', 'ta': 'tib_ant_r'}
BODY_SEGMENT = {'pelvis': 'hat', 'femur_r': 'thigh', 'tibia_r': 'shank', 'talus_r': 'foot',
                'calcn_r': 'foot', 'toes_r': 'foot'}
COORDINATE = {'hip_flexion_r': 'hip_flexion', 'knee_angle_r': 'knee_angle',
              'ankle_angle_r': 'ankle_angle'}


def _floats(text: str | None) -> list[float]:
    return [float(v) for v in (text or '').split()]


def _joint_offsets(root: ET.Element) -> dict[str, np.ndarray]:
    """Location [3] of each joint's parent offset frame in its parent body, by child body."""
    offsets = {}
    for joint in root.find('.//JointSet/objects'):
        frames = {f.get('name'): f for f in joint.find('frames')}
        parent = frames[joint.find('socket_parent_frame').text]
        child = frames[joint.find('socket_child_frame').text]
        for f in (parent, child):
            if any(_floats(f.find('orientation').text)):
                raise ValueError(f'{joint.get("name")}: rotated offset frames are not handled')
        if any(_floats(child.find('translation').text)):
            raise ValueError(f'{joint.get("name")}: child offset frames are not handled')
        child_body = child.find('socket_parent').text.rsplit('/', 1)[-1]
        offsets[child_body] = np.array(_floats(parent.find('translation').text))
    return offsets


def _body_to_segment(body: str, offsets: dict[str, np.ndarray]) -> np.ndarray:
    """Translation [3] that takes a point of ``body``'s frame into its segment's frame."""
    if body == 'pelvis':
        return -offsets['femur_r']                     # hip centre in the pelvis
    if body == 'calcn_r':
        return offsets['calcn_r']                      # subtalar weld in the talus
    if body == 'toes_r':
        return offsets['calcn_r'] + offsets['toes_r']  # MTP weld in the calcaneus
    return np.zeros(3)


def _spline_knots(element: ET.Element) -> tuple[list[float], list[float]]:
    spline = element.find('SimmSpline')
    if spline is None:
        raise ValueError(f'{element.tag}: only SimmSpline moving points are handled')
    return _floats(spline.find('x').text), _floats(spline.find('y').text)


def knee_translation(osim_file: Path = OSIM_FILE) -> dict:
    """The knee's tibia-origin translation in the femur frame (x, y knots of knee_angle)."""
    root = ET.parse(osim_file).getroot()
    joint = next(j for j in root.iter('CustomJoint') if j.get('name') == 'knee_r')
    entry: dict = {'coordinate': 'knee_angle'}
    for name, axis, unit in (('translation1', 'x', [1.0, 0.0, 0.0]),
                             ('translation2', 'y', [0.0, 1.0, 0.0])):
        transform = joint.find(f"SpatialTransform/TransformAxis[@name='{name}']")
        if _floats(transform.find('axis').text) != unit:
            raise ValueError(f'knee_r {name}: axis is not {unit}')
        knots, values = _spline_knots(transform)
        entry[f'{axis}_knots'] = knots
        entry[axis] = values
    return entry


def path_points(osim_file: Path = OSIM_FILE) -> dict[str, list[dict]]:
    """Per model muscle, its path points as data-file entries (see the module docstring)."""
    root = ET.parse(osim_file).getroot()
    offsets = _joint_offsets(root)
    muscles = {m.get('name'): m for m in root.iter() if m.find('GeometryPath') is not None}
    result = {}
    for name in MUSCLES:
        muscle = muscles[OSIM_MUSCLE[name]]
        entries = []
        for point in muscle.find('GeometryPath/PathPointSet/objects'):
            body = point.find('socket_parent_frame').text.rsplit('/', 1)[-1]
            shift = _body_to_segment(body, offsets)
            entry: dict = {'segment': BODY_SEGMENT[body]}
            if point.tag == 'MovingPathPoint':
                coord = COORDINATE[point.find('socket_x_coordinate').text.rsplit('/', 1)[-1]]
                moving: dict = {'coordinate': coord}
                for k, axis in enumerate('xyz'):
                    knots, values = _spline_knots(point.find(f'{axis}_location'))
                    moving[f'{axis}_knots'] = knots
                    moving[axis] = [round(float(v + shift[k]), 7) for v in values]
                entry['moving'] = moving
            else:
                entry['xyz'] = [round(float(v), 7)
                                for v in np.array(_floats(point.find('location').text)) + shift]
                if point.tag == 'ConditionalPathPoint':
                    coord = point.find('socket_coordinate').text.rsplit('/', 1)[-1]
                    entry['active'] = {'coordinate': COORDINATE[coord],
                                       'range': _floats(point.find('range').text)}
                elif point.tag != 'PathPoint':
                    raise ValueError(f'{name}: path point type {point.tag} is not handled')
            entries.append(entry)
        result[name] = entries
    return result


def _flow(value: object) -> str:
    if isinstance(value, dict):
        return '{' + ', '.join(f'{k}: {_flow(v)}' for k, v in value.items()) + '}'
    if isinstance(value, list):
        return '[' + ', '.join(_flow(v) for v in value) + ']'
    return repr(value)


def section_text(points: dict[str, list[dict]]) -> str:
    """The data file's ``path_points`` section, between the markers."""
    lines = [BEGIN_MARK, 'path_points:', '  source: >-',
             '    data/opensim/gait10dof18musc.osim GeometryPath point sets of the',
             '    right-leg muscles (PathPoint, ConditionalPathPoint, MovingPathPoint) in the',
             '    segment frames (x forward, y up, z lateral, m); written by',
             '    `python -m nmt_ros.osim.path_points`.']
    lines.append('  # tibia origin in the femur frame vs knee_angle (OpenSim knee_r translation1')
    lines.append('  # and 2); shank and foot points move by R(-knee) (t(knee) - t(0)) against the')
    lines.append('  # pin knee (model/muscle_geometry.py)')
    lines.append(f'  knee_translation: {_flow(knee_translation())}')
    for name, entries in points.items():
        lines.append(f'  {name}:')
        lines += [f'    - {_flow(e)}' for e in entries]
    lines.append(END_MARK)
    return '\n'.join(lines) + '\n'


def write_section(text: str, data_file: Path = DATA_FILE) -> None:
    """Replace (or append) the generated section of the data file."""
    content = data_file.read_text(encoding='utf-8')
    if BEGIN_MARK in content:
        head, rest = content.split(BEGIN_MARK, 1)
        tail = rest.split(END_MARK, 1)[1].lstrip('\n')
        content = head + text + tail
    else:
        content = content.rstrip('\n') + '\n\n# Muscle paths for drawing (not used by the ' \
            'dynamics: lengths are the polynomials above).\n' + text
    data_file.write_text(content, encoding='utf-8')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--print', action='store_true', help='print the section only')
    args = parser.parse_args(argv)
    text = section_text(path_points())
    if args.print:
        print(text, end='')
    else:
        write_section(text)
        print(f'wrote the path points into {DATA_FILE}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
