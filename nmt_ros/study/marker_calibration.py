"""Calibrating a marker map on a model: each segment line's angle in the default pose.

A marker map (``nmt_ros.io.marker_map``) names the markers of each planar segment; the
segment angle is the line's sagittal direction minus its direction in the model's default
pose (README "Lab recordings"), and the ankle joint centre sits at a fixed offset from the
ankle landmark in the shank frame. Both are read off a model that carries the markers, in its
default pose (``python -m nmt_ros.osim.subject measure``, run in an OpenSim subprocess)::

    python -m nmt_ros.study.marker_calibration --model M.osim [--map MAP] [--out OUT]
"""
from __future__ import annotations

import argparse
import copy
import sys

import numpy as np

from nmt_ros.io.marker_map import (
    DEFAULT_MAP,
    LEG_LANDMARKS,
    LEG_LINES,
    SIDES,
    landmark,
    load_marker_map,
    markers_used,
    write_marker_map,
)
from nmt_ros.study.sagittal import SagittalFrame, direction_angle

#: OpenSim's ground: x forward, y up.
OPENSIM_FRAME = SagittalFrame('+x', '+y')


def calibrate(m: dict, measures: dict) -> dict:
    """A copy of map ``m`` with ``zero_deg`` and ``ankle_offset_m`` from a model's default pose
    (``python -m nmt_ros.osim.subject measure`` output: ``markers_m``, ``landmarks_m``)."""
    markers = {k: np.asarray(v, dtype=float) for k, v in measures['markers_m'].items()}
    missing = [n for n in markers_used(m) if n not in markers]
    if missing:
        raise ValueError(f'{measures.get("model", "model")} has no marker(s) '
                         f'{", ".join(missing)} of the marker map: cannot calibrate it')
    out = copy.deepcopy(m)
    proj = OPENSIM_FRAME.project
    zero: dict = {}
    offset: dict = {}
    for side in SIDES:
        p = {k: proj(landmark(m, side, k, markers)) for k in LEG_LANDMARKS}
        zero[side] = {seg: float(np.rad2deg(direction_angle(p[a], p[b])))
                      for seg, (a, b) in LEG_LINES.items()}
        ankle_centre = proj(np.asarray(measures['landmarks_m'][f'{side}_ankle']))
        offset[side] = [float(v) for v in ankle_centre - p['ankle']]
    hip = proj(landmark(m, None, 'hip', markers))
    shoulder = proj(landmark(m, None, 'shoulder', markers))
    zero['hat'] = float(np.rad2deg(direction_angle(hip, shoulder)))
    out['zero_deg'] = zero
    out['ankle_offset_m'] = offset
    out['calibrated_on'] = str(measures.get('model', ''))
    out.pop('source_file', None)
    return out


def main(argv: list[str] | None = None) -> int:
    """Recalibrate a map on a model (module docstring)."""
    from nmt_ros.osim.subject_process import measure_model
    parser = argparse.ArgumentParser(prog='python -m nmt_ros.study.marker_calibration')
    parser.add_argument('--model', required=True, help='.osim carrying the markers')
    parser.add_argument('--map', default=None, help='map to calibrate (default: shipped)')
    parser.add_argument('--out', default=None, help='output (default: overwrite --map)')
    args = parser.parse_args(argv)
    m = load_marker_map(args.map)
    out = calibrate(m, measure_model(args.model))
    write_marker_map(args.out or args.map or DEFAULT_MAP, out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
