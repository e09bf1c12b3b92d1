"""OpenSim 4 data files without OpenSim: .sto/.mot tables, ground-reaction .mot, ExternalLoads.

Pure Python + numpy (no ``opensim`` import, so usable next to casadi). Formats:

* ``.sto`` / ``.mot`` (OpenSim ``Storage``, version 1): a header of ``key=value`` lines
  (``version=1``, ``nRows``, ``nColumns`` counting the time column, ``inDegrees=yes|no``,
  anything else the caller adds) closed by ``endheader``, then one tab-separated line of
  column labels (``time`` first) and the rows. The first header line may be a bare name.
  Both OpenSim's ``Storage`` and ``TimeSeriesTable`` read what ``write_table`` writes, and
  ``read_table`` reads both their outputs (including the version-3 header of
  ``STOFileAdapter``).
* Ground reaction ``.mot``: OpenSim's usual columns ``{prefix}_v{x,y,z}`` (force),
  ``{prefix}_p{x,y,z}`` (point of application) and ``{torque_prefix}_{x,y,z}`` (free torque),
  all in the ground frame.
* ``ExternalLoads`` .xml (OpenSim 4): one ``ExternalForce`` applying that force, point and
  torque to a body, force and point expressed in ground.

Planar ground wrenches: the model's contact forces act at body points; ``ground_wrench_to_cop``
turns them into one force, a point of application on the ground line y = 0 (the centre of
pressure while the foot is loaded) and a free torque that make the wrench exact whatever the
point: ``torque_z = M_O - (P_x F_y - P_y F_x)`` with ``M_O`` the moment about the origin.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
import os
from pathlib import Path
from typing import NamedTuple
import xml.etree.ElementTree as ET

import numpy as np

GRF_PREFIX = 'ground_force'
TORQUE_PREFIX = 'ground_torque'
_TRUE = ('yes', 'true', '1')


# ---------------------------------------------------------------------------------------------
# tables
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class OpenSimTable:
    """A .sto/.mot file: time [n], column labels (time excluded), data [n, m], header."""

    time: np.ndarray
    labels: tuple[str, ...]
    data: np.ndarray
    metadata: dict[str, str] = field(default_factory=dict)
    name: str = ''
    path: Path | None = None

    @property
    def in_degrees(self) -> bool:
        """The header's ``inDegrees`` flag (False when absent, as OpenSim assumes)."""
        return self.metadata.get('inDegrees', 'no').strip().lower() in _TRUE

    def columns(self, labels: Sequence[str]) -> np.ndarray:
        """Data [n, len(labels)] of the named columns; ValueError naming any missing ones."""
        index = {label: i for i, label in enumerate(self.labels)}
        missing = [label for label in labels if label not in index]
        if missing:
            where = f' of {self.path}' if self.path is not None else ''
            raise ValueError(f'missing column(s) {", ".join(missing)} in the file{where} '
                             f'(it has: {", ".join(self.labels)})')
        return self.data[:, [index[label] for label in labels]]

    def column(self, label: str) -> np.ndarray:
        """Data [n] of one column (ValueError if missing)."""
        return self.columns([label])[:, 0]


def read_table(path: str | Path) -> OpenSimTable:
    """Read an OpenSim .sto or .mot file (time column first)."""
    path = Path(path)
    with open(path, encoding='utf-8') as f:
        lines = f.read().splitlines()
    metadata: dict[str, str] = {}
    name = ''
    end = None
    for i, raw in enumerate(lines):
        line = raw.strip()
        if line.lower() == 'endheader':
            end = i
            break
        if '=' in line:
            key, value = line.split('=', 1)
            metadata[key.strip()] = value.strip()
        elif line and not name and not metadata:
            name = line
    if end is None:
        raise ValueError(f'{path}: no "endheader" line: not an OpenSim .sto/.mot file')
    body = [ln for ln in lines[end + 1:] if ln.strip()]
    if not body:
        raise ValueError(f'{path}: no column labels after "endheader"')
    header = body[0]
    labels = [s.strip() for s in (header.split('\t') if '\t' in header else header.split())]
    labels = [s for s in labels if s]
    if not labels or labels[0].lower() != 'time':
        raise ValueError(f'{path}: the first column must be "time", not {labels[:1]}')
    rows = body[1:]
    if rows:
        try:
            values = np.loadtxt(rows, dtype=float, ndmin=2)
        except ValueError as err:
            raise ValueError(f'{path}: malformed data rows: {err}') from None
    else:
        values = np.empty((0, len(labels)))
    if values.shape[1] != len(labels):
        raise ValueError(f'{path}: {len(labels)} column labels but {values.shape[1]} columns '
                         'of data')
    return OpenSimTable(time=values[:, 0].copy(), labels=tuple(labels[1:]),
                        data=values[:, 1:].copy(), metadata=metadata, name=name, path=path)


#: Values of two rows at the same time that differ by at most this fraction are one sample.
REPEATED_ROW_RTOL = 1e-9


def without_repeated_rows(table: OpenSimTable) -> tuple[OpenSimTable, list[float]]:
    """(the table without the rows that repeat the row before them, the same time and the
    same values to 1e-9 of each value (the last printed digits); the times [s] of the rows
    dropped). OpenSim's tools sometimes write their last row twice, and OpenSim's own
    TimeSeriesTable then refuses the file. Any other time that does not increase is a
    ValueError naming the row: which of two different rows is right cannot be told."""
    t = table.time
    if t.size < 2:
        return table, []
    step = np.diff(t)
    a, b = table.data[1:], table.data[:-1]
    close = np.abs(a - b) <= REPEATED_ROW_RTOL * np.maximum(1.0, np.abs(b))
    same = (step == 0) & np.all(close | (np.isnan(a) & np.isnan(b)), axis=1)
    bad = np.flatnonzero((step <= 0) & ~same)
    if bad.size:
        k = int(bad[0]) + 1
        where = f'{table.path}: ' if table.path is not None else ''
        raise ValueError(f'{where}time does not increase at data row {k + 1} '
                         f'(t = {t[k]:.6f} s after {t[k - 1]:.6f} s) and the row differs from '
                         f'the one before; {bad.size} such row(s)')
    if not same.any():
        return table, []
    keep = np.concatenate([[True], ~same])
    clean = replace(table, time=t[keep], data=table.data[keep])
    return clean, t[1:][same].tolist()


def _format_rows(values: np.ndarray) -> list[str]:
    """Tab-separated rows, each number in its shortest exact (round-trip) form."""
    return ['\t'.join(map(repr, row)) for row in values.tolist()]


def write_table(path: str | Path, time: np.ndarray, labels: Sequence[str], data: np.ndarray,
                in_degrees: bool = False, name: str | None = None,
                metadata: Mapping[str, object] | None = None) -> Path:
    """Write a version-1 OpenSim .sto/.mot file; returns the path.

    ``data`` [n, len(labels)]; values are written exactly (shortest round-trip decimals).
    ``metadata`` adds ``key=value`` header lines (keys must not contain '=' or newlines).
    """
    path = Path(path)
    time = np.asarray(time, dtype=float).reshape(-1)
    data = np.asarray(data, dtype=float)
    data = data[:, None] if data.ndim == 1 else data
    labels = [str(s) for s in labels]
    if data.shape != (time.size, len(labels)):
        raise ValueError(f'data must be [{time.size}, {len(labels)}], not {data.shape}')
    for label in labels:
        if not label or any(c in label for c in '\t\n\r'):
            raise ValueError(f'bad column label {label!r}')
    header = [name or path.stem, 'version=1', f'nRows={time.size}',
              f'nColumns={len(labels) + 1}', f'inDegrees={"yes" if in_degrees else "no"}']
    for key, value in (metadata or {}).items():
        text = f'{key}={value}'
        if '\n' in text or '=' in str(key) or key in ('version', 'nRows', 'nColumns',
                                                      'inDegrees'):
            raise ValueError(f'bad metadata entry {key!r}')
        header.append(text)
    header.append('endheader')
    header.append('\t'.join(['time', *labels]))
    body = _format_rows(np.column_stack([time, data]))
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w', encoding='utf-8', newline='\n') as f:
        f.write('\n'.join(header + body) + '\n')
    return path


# ---------------------------------------------------------------------------------------------
# ground reaction files
# ---------------------------------------------------------------------------------------------

def grf_labels(prefix: str = GRF_PREFIX, torque_prefix: str = TORQUE_PREFIX) -> list[str]:
    """The 9 column labels of one force: v{x,y,z}, p{x,y,z}, torque {x,y,z}."""
    return ([f'{prefix}_v{c}' for c in 'xyz'] + [f'{prefix}_p{c}' for c in 'xyz']
            + [f'{torque_prefix}_{c}' for c in 'xyz'])


def _xyz(v: np.ndarray | None, n: int, what: str) -> np.ndarray:
    """[n, 2] or [n, 3] (or None = zeros) -> [n, 3]."""
    if v is None:
        return np.zeros((n, 3))
    v = np.asarray(v, dtype=float)
    v = v.reshape(n, -1) if v.ndim != 2 else v
    if v.shape[0] != n or v.shape[1] not in (2, 3):
        raise ValueError(f'{what} must be [{n}, 2] or [{n}, 3], not {v.shape}')
    return v if v.shape[1] == 3 else np.column_stack([v, np.zeros(n)])


def write_grf_mot(path: str | Path, t: np.ndarray, force: np.ndarray, point: np.ndarray,
                  torque: np.ndarray | None = None, prefix: str = GRF_PREFIX,
                  torque_prefix: str = TORQUE_PREFIX, name: str | None = None,
                  metadata: Mapping[str, object] | None = None) -> Path:
    """Ground reaction force [n, 3], point [n, 3] and torque [n, 3] (ground frame) as a .mot.

    2-column (x, y) arrays are accepted and padded with z = 0; ``torque`` None means zero.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    n = t.size
    values = np.hstack([_xyz(force, n, 'force'), _xyz(point, n, 'point'),
                        _xyz(torque, n, 'torque')])
    return write_table(path, t, grf_labels(prefix, torque_prefix), values, in_degrees=False,
                       name=name, metadata=metadata)


class GroundLoad(NamedTuple):
    """One force in the ground frame: force [n, 3], point [n, 3], free torque [n, 3]."""

    force: np.ndarray
    point: np.ndarray
    torque: np.ndarray

    def moment_about(self, ref: np.ndarray) -> np.ndarray:
        """Moment z [n] of the wrench about points ``ref`` [n, 2] (or [2]) of the plane."""
        ref = np.broadcast_to(np.asarray(ref, dtype=float), (self.force.shape[0], 2))
        arm = self.point[:, :2] - ref
        return self.torque[:, 2] + arm[:, 0] * self.force[:, 1] - arm[:, 1] * self.force[:, 0]


def read_grf_mot(path: str | Path, prefix: str = GRF_PREFIX,
                 torque_prefix: str = TORQUE_PREFIX) -> tuple[np.ndarray, GroundLoad]:
    """(time [n], GroundLoad) from a ground reaction .mot; missing torque columns mean zero."""
    table = read_table(path)
    labels = grf_labels(prefix, torque_prefix)
    force = table.columns(labels[0:3])
    point = table.columns(labels[3:6])
    if any(label in table.labels for label in labels[6:9]):
        torque = table.columns(labels[6:9])
    else:
        torque = np.zeros_like(force)
    return table.time, GroundLoad(force, point, torque)


def load_on_ground_line(force: np.ndarray, moment_origin: np.ndarray, fy_min: float = 10.0,
                        fallback_x: np.ndarray | float = 0.0) -> GroundLoad:
    """A planar wrench (force [n, 2], moment about the origin [n]) as force/point/torque.

    The point lies on the ground line y = 0: the centre of pressure ``x = M_O / F_y`` where
    ``F_y >= 2 fy_min``; where ``F_y <= fy_min`` the point holds the last such centre of
    pressure (the first one before any; ``fallback_x`` if the wrench is never loaded), with a
    smooth blend in between. The free torque ``M_O - P_x F_y`` makes the wrench exact at every
    sample whatever the point (it is 0 at the centre of pressure).
    """
    force = np.atleast_2d(np.asarray(force, dtype=float))
    m_o = np.asarray(moment_origin, dtype=float).reshape(-1)
    n = force.shape[0]
    if force.shape[1] != 2 or m_o.size != n:
        raise ValueError(f'force must be [n, 2] and moment [n]; got {force.shape}, {m_o.shape}')
    if fy_min <= 0:
        raise ValueError('fy_min must be positive')
    fy = force[:, 1]
    loaded = fy >= 2.0 * fy_min
    cop = np.divide(m_o, fy, out=np.zeros(n), where=fy > 0)
    fallback = np.broadcast_to(np.asarray(fallback_x, dtype=float), (n,))
    if loaded.any():
        idx = np.where(loaded, np.arange(n), -1)
        last = np.maximum.accumulate(idx)              # last loaded sample so far
        last[last < 0] = int(np.argmax(loaded))        # before the first: the first one
        held = cop[last]
    else:
        held = fallback.copy()
    s = np.clip((fy - fy_min) / fy_min, 0.0, 1.0)
    w = s * s * (3.0 - 2.0 * s)                        # smoothstep: 0 below fy_min, 1 above 2x
    px = w * cop + (1.0 - w) * held
    point = np.column_stack([px, np.zeros(n), np.zeros(n)])
    torque = np.column_stack([np.zeros(n), np.zeros(n), m_o - px * fy])
    return GroundLoad(np.column_stack([force, np.zeros(n)]), point, torque)


def ground_wrench_to_cop(points: np.ndarray, forces: np.ndarray, fy_min: float = 10.0,
                         ) -> GroundLoad:
    """Contact point forces -> one exact GroundLoad with its point at the centre of pressure.

    ``points`` and ``forces`` are [n, 2, k] as the model's ``positions(q)[4]`` and
    ``contact_forces`` give them (rows x, y in ground; one column per contact point).
    See ``load_on_ground_line`` for the point's choice (``fy_min`` [N]); without load the
    point falls back to the mean x of the contact points.
    """
    points = np.asarray(points, dtype=float)
    forces = np.asarray(forces, dtype=float)
    if points.ndim == 2:
        points, forces = points[None], forces[None]
    if points.shape != forces.shape or points.shape[1] != 2:
        raise ValueError(f'points and forces must both be [n, 2, k]; got {points.shape}, '
                         f'{forces.shape}')
    total = forces.sum(axis=2)                                         # [n, 2]
    m_o = (points[:, 0] * forces[:, 1] - points[:, 1] * forces[:, 0]).sum(axis=1)
    return load_on_ground_line(total, m_o, fy_min, fallback_x=points[:, 0].mean(axis=1))


# ---------------------------------------------------------------------------------------------
# ExternalLoads
# ---------------------------------------------------------------------------------------------

def write_external_loads_xml(path: str | Path, mot_file: str | Path,
                             applied_to_body: str = 'foot', force_name: str = 'grf',
                             prefix: str = GRF_PREFIX, torque_prefix: str = TORQUE_PREFIX,
                             expressed_in_body: str = 'ground', name: str = 'external_loads',
                             relative: bool = True) -> Path:
    """OpenSim 4 ExternalLoads with one ExternalForce (force/point/torque of ``mot_file``).

    Force and point are expressed in ``expressed_in_body`` (ground). With ``relative`` the
    data file is named relative to the .xml's folder (OpenSim resolves it from there), so the
    pair can be moved together.
    """
    path = Path(path)
    mot = Path(mot_file)
    if relative:
        try:
            datafile = os.path.relpath(mot.resolve(), path.resolve().parent)
        except ValueError:                   # other drive (Windows): keep it absolute
            datafile = str(mot.resolve())
    else:
        datafile = str(mot)
    root = ET.Element('OpenSimDocument', Version='40000')
    loads = ET.SubElement(root, 'ExternalLoads', name=name)
    objects = ET.SubElement(loads, 'objects')
    ext = ET.SubElement(objects, 'ExternalForce', name=force_name)
    for tag, text in (('appliesForce', 'true'), ('applied_to_body', applied_to_body),
                      ('force_expressed_in_body', expressed_in_body),
                      ('point_expressed_in_body', expressed_in_body),
                      ('force_identifier', f'{prefix}_v'),
                      ('point_identifier', f'{prefix}_p'),
                      ('torque_identifier', f'{torque_prefix}_')):
        ET.SubElement(ext, tag).text = text
    ET.SubElement(loads, 'groups')
    ET.SubElement(loads, 'datafile').text = datafile
    ET.indent(root, space='\t')
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'wb') as f:
        f.write(b'<?xml version="1.0" encoding="UTF-8" ?>\n')
        f.write(ET.tostring(root, encoding='utf-8'))
        f.write(b'\n')
    return path


@dataclass(frozen=True)
class ExternalForceSpec:
    """One ExternalForce of an ExternalLoads file."""

    name: str
    applied_to_body: str
    force_expressed_in_body: str
    point_expressed_in_body: str
    force_identifier: str
    point_identifier: str
    torque_identifier: str


def read_external_loads_xml(path: str | Path) -> tuple[Path | None, list[ExternalForceSpec]]:
    """(data file resolved against the .xml's folder, the ExternalForces) of a loads file."""
    path = Path(path)
    root = ET.parse(path).getroot()
    loads = root.find('ExternalLoads') if root.tag != 'ExternalLoads' else root
    if loads is None:
        raise ValueError(f'{path}: no ExternalLoads element')

    def text(el: ET.Element, tag: str, default: str = '') -> str:
        child = el.find(tag)
        return (child.text or '').strip() if child is not None else default

    forces = [ExternalForceSpec(
        name=el.get('name', ''), applied_to_body=text(el, 'applied_to_body'),
        force_expressed_in_body=text(el, 'force_expressed_in_body', 'ground'),
        point_expressed_in_body=text(el, 'point_expressed_in_body', 'ground'),
        force_identifier=text(el, 'force_identifier'),
        point_identifier=text(el, 'point_identifier'),
        torque_identifier=text(el, 'torque_identifier'))
        for el in loads.iter('ExternalForce')]
    datafile = text(loads, 'datafile')
    data_path = (path.parent / datafile) if datafile else None
    return data_path, forces
