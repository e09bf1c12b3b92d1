"""Marker maps: which markers define each planar segment (a small YAML file).

A map names, per leg (``r``, ``l``), the landmarks ``hip``, ``knee``, ``ankle``, ``heel``,
``toe`` and, for the trunk, ``hip`` and ``shoulder``; a landmark is one marker or a list of
markers (their midpoint: e.g. the two hip joint centres). The segment lines are fixed
(``nmt_ros.study.sagittal``): foot heel -> toe, shank ankle -> knee, thigh knee -> hip, HAT
hips -> shoulders. Each line's sagittal direction angle in the default pose (``zero_deg``,
degrees) makes the README zero, and ``ankle_offset_m`` (the ankle joint centre minus the ankle
landmark in the shank frame, m) places the ankle centre used for the foot's centre of mass.
Both come from a model that carries the markers (``nmt_ros.study.marker_calibration``: the
markers and joint centres in the model's default pose), so a subject's own ``.osim``
recalibrates them. This module reads and writes the format only.

The shipped default, ``data/marker_map_opencap.yaml``, is for the OpenCap / Rajagopal (2015)
marker names of ``data/real/opencap_dropjump/MarkerData/DJ1.trc``, calibrated on that
subject's ``Models/final.osim``; regenerate with ``python -m nmt_ros.study.marker_calibration``.

Format::

    format: nmt_ros marker map v1
    frame: {forward: '+x', up: '+y'}        # lab axes of the recordings it is meant for
    legs: {r: {hip: R_HJC, knee: r_knee, ankle: r_ankle, heel: r_calc, toe: r_toe}, l: ...}
    trunk: {hip: [R_HJC, L_HJC], shoulder: [R_Shoulder, L_Shoulder]}
    zero_deg: {r: {foot: .., shank: .., thigh: ..}, l: {...}, hat: ..}
    ankle_offset_m: {r: [dx, dy], l: [dx, dy]}
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

DEFAULT_MAP = Path(__file__).resolve().parent / 'data' / 'marker_map_opencap.yaml'
FORMAT = 'nmt_ros marker map v1'
SIDES = ('r', 'l')
LEG_LANDMARKS = ('hip', 'knee', 'ankle', 'heel', 'toe')
#: Segment line of each leg segment: (from landmark, to landmark).
LEG_LINES = {'foot': ('heel', 'toe'), 'shank': ('ankle', 'knee'), 'thigh': ('knee', 'hip')}


def _names(entry: object) -> list[str]:
    return [entry] if isinstance(entry, str) else [str(e) for e in entry]


def load_marker_map(path: str | Path | None = None) -> dict:
    """Read and check a marker map (the shipped OpenCap/Rajagopal one by default)."""
    path = Path(path) if path is not None else DEFAULT_MAP
    with open(path) as f:
        m = yaml.safe_load(f)
    if not isinstance(m, dict) or m.get('format') != FORMAT:
        raise ValueError(f'{path}: not a marker map (format: "{FORMAT}")')
    for side in SIDES:
        leg = (m.get('legs') or {}).get(side) or {}
        missing = [k for k in LEG_LANDMARKS if k not in leg]
        if missing:
            raise ValueError(f'{path}: legs.{side} lacks {", ".join(missing)}')
    if not all(k in (m.get('trunk') or {}) for k in ('hip', 'shoulder')):
        raise ValueError(f'{path}: trunk needs hip and shoulder')
    m['source_file'] = str(path)
    return m


def markers_used(m: dict) -> list[str]:
    """Every marker a map reads."""
    names = [n for side in SIDES for k in LEG_LANDMARKS for n in _names(m['legs'][side][k])]
    names += [n for k in ('hip', 'shoulder') for n in _names(m['trunk'][k])]
    return list(dict.fromkeys(names))


def landmark(m: dict, side: str | None, name: str, position: dict[str, np.ndarray],
             ) -> np.ndarray:
    """A landmark's position [..., 3] from marker positions (midpoint of its markers)."""
    entry = m['trunk'][name] if side is None else m['legs'][side][name]
    return np.mean([position[n] for n in _names(entry)], axis=0)


def write_marker_map(path: str | Path, m: dict) -> Path:
    path = Path(path)
    doc = {k: v for k, v in m.items() if k != 'source_file'}
    with open(path, 'w') as f:
        f.write('# nmt_ros marker map (nmt_ros/io/marker_map.py explains every key)\n')
        yaml.safe_dump(doc, f, sort_keys=False, width=99)
    return path
