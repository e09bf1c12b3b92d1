"""C3D files (markers + analog force plates) through ezc3d, read and written.

Reading (:func:`read_c3d`): markers from POINT (``POINT:UNITS`` m or mm, converted to m;
invalid points are NaN), and every force plate of the FORCE_PLATFORM group as ezc3d computes it
from the analog channels with their calibration (``ANALOG:SCALE``, ``OFFSET``, ``GEN_SCALE``, the
plate's ``CAL_MATRIX``, ``CORNERS`` and ``ORIGIN``): force and moment in the lab frame, the moment
about the centre of the plate's surface (the mean of its corners). That pair is the plate's
whole wrench, defined in flight too; ezc3d's centre of pressure and free moment ``Tz`` give the
same wrench wherever the vertical force is non-zero (tested) and are 0/0 without load, so the
plate is returned as a :class:`~nmt_ros.io.opensim_files.GroundLoad` with its point at the
surface centre. Units (``N``; ``Nmm`` or ``Nm``; ``mm`` or ``m``) are converted to SI; others,
a plate channel that does not exist, or NaN samples are refused with the plate named.

Writing (:func:`write_c3d`, used by the tests and for handing our data to C3D tools): markers
[n, m, 3] in m (stored in mm) and type-2 plates whose six channels (Fx, Fy, Fz, Mx, My, Mz in
the plate frame, N and N mm, moments about the transducer origin) are made from a lab-frame
wrench by :func:`plate_channels`. Plate axes follow ezc3d's reading of ``CORNERS``:
x = c1 - c2, y = c1 - c4, z = x cross y; ``ORIGIN`` is the vector, in plate axes, from the
transducer origin to the surface centre (moments there = transducer moments - ORIGIN x F).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nmt_ros.io.opensim_files import GroundLoad
from nmt_ros.io.trc import UNIT_TO_M, MarkerTable

FORCE_UNITS = {'N': 1.0}
MOMENT_UNITS = {'Nmm': 1e-3, 'Nm': 1.0, 'N.mm': 1e-3, 'N.m': 1.0}


@dataclass(frozen=True)
class Plate:
    """One force plate for :func:`write_c3d`: corners [4, 3] (m, lab), origin [3] (m, plate
    axes), channels [n_analog, 6] (Fx, Fy, Fz N; Mx, My, Mz N m, about the transducer)."""

    corners: np.ndarray
    origin: np.ndarray
    channels: np.ndarray


def plate_axes(corners: np.ndarray) -> np.ndarray:
    """[3, 3] rotation whose columns are the plate's x, y, z axes in the lab frame."""
    c = np.asarray(corners, dtype=float)
    x = c[0] - c[1]
    y = c[0] - c[3]
    x = x / np.linalg.norm(x)
    z = np.cross(x, y)
    z = z / np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


def plate_channels(corners: np.ndarray, origin: np.ndarray, force: np.ndarray,
                   point: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """Channels [n, 6] (plate frame, moments about the transducer, N and N m) of a lab-frame
    wrench: force [n, 3] (N) at point [n, 3] (m) plus free torque [n, 3] (N m)."""
    rot = plate_axes(corners)
    centre = np.asarray(corners, dtype=float).mean(axis=0)
    force = np.asarray(force, dtype=float)
    m_centre = np.asarray(torque, dtype=float) + np.cross(np.asarray(point) - centre, force)
    f_p = force @ rot
    m_p = m_centre @ rot + np.cross(np.asarray(origin, dtype=float), f_p)
    return np.hstack([f_p, m_p])


def _int_parameter(c3d: object, group: str, name: str, values: np.ndarray) -> None:
    import ezc3d
    arr = np.asarray(values)
    p = ezc3d.ezc3d.Parameter(name, '')
    p.set(ezc3d.ezc3d.VecInt([int(v) for v in arr.reshape(-1, order='F')]),
          ezc3d.ezc3d.VecUInt([int(s) for s in arr.shape]))
    c3d._storage['parameters'].add_parameter(group, p)


def write_c3d(path: str | Path, marker_names: list[str] | tuple[str, ...], xyz: np.ndarray,
              rate_hz: float, plates: list[Plate] = (), analog_rate_hz: float | None = None,
              ) -> Path:
    """Markers ``xyz`` [n, m, 3] (m) and type-2 ``plates`` as a C3D file (ezc3d)."""
    import ezc3d
    xyz = np.asarray(xyz, dtype=float)
    n = xyz.shape[0]
    c = ezc3d.c3d()
    c['parameters']['POINT']['RATE']['value'] = [float(rate_hz)]
    c['parameters']['POINT']['LABELS']['value'] = list(marker_names)
    c['parameters']['POINT']['UNITS']['value'] = ['mm']
    pts = np.ones((4, xyz.shape[1], n))
    pts[:3] = np.transpose(xyz * 1e3, (2, 1, 0))
    c['data']['points'] = pts
    if plates:
        ratio = int(round((analog_rate_hz or rate_hz) / rate_hz))
        c['parameters']['ANALOG']['RATE']['value'] = [float(rate_hz * ratio)]
        labels, units, data = [], [], []
        for k, plate in enumerate(plates):
            ch = np.asarray(plate.channels, dtype=float)
            if ch.shape != (n * ratio, 6):
                raise ValueError(f'plate {k + 1}: channels must be [{n * ratio}, 6]')
            labels += [f'{q}{k + 1}' for q in ('Fx', 'Fy', 'Fz', 'Mx', 'My', 'Mz')]
            units += ['N'] * 3 + ['Nmm'] * 3
            data.append(ch * np.array([1, 1, 1, 1e3, 1e3, 1e3]))
        c['parameters']['ANALOG']['LABELS']['value'] = labels
        c['parameters']['ANALOG']['UNITS']['value'] = units
        c['data']['analogs'] = np.hstack(data).T.reshape(1, len(labels), n * ratio)
        c.add_parameter('FORCE_PLATFORM', 'USED', len(plates))
        _int_parameter(c, 'FORCE_PLATFORM', 'TYPE', np.full(len(plates), 2))
        _int_parameter(c, 'FORCE_PLATFORM', 'ZERO', np.array([1, 0]))
        corners = np.stack([np.asarray(p.corners, float).T * 1e3 for p in plates], axis=2)
        c.add_parameter('FORCE_PLATFORM', 'CORNERS', corners)
        origin = np.stack([np.asarray(p.origin, float) * 1e3 for p in plates], axis=1)
        c.add_parameter('FORCE_PLATFORM', 'ORIGIN', origin)
        _int_parameter(c, 'FORCE_PLATFORM', 'CHANNEL',
                       np.arange(1, 6 * len(plates) + 1).reshape(len(plates), 6).T)
        c.add_parameter('FORCE_PLATFORM', 'CAL_MATRIX', np.zeros((6, 6, len(plates))))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    c.write(str(path))
    return path


def _param(c3d: object, group: str, name: str) -> object | None:
    g = c3d['parameters'].get(group)
    if g is None or name not in g:
        return None
    return g[name]['value']


def read_c3d(path: str | Path, ) -> tuple[MarkerTable, np.ndarray, list[GroundLoad], dict]:
    """(markers, analog times [n_a] (s), one GroundLoad per plate (lab frame, SI), facts)."""
    import ezc3d
    path = Path(path)
    if not path.exists():
        raise ValueError(f'{path}: no such file')
    try:
        c = ezc3d.c3d(str(path))
    except Exception as err:                                    # ezc3d raises many types
        raise ValueError(f'{path}: not a readable C3D file ({err})') from None
    units = str((_param(c, 'POINT', 'UNITS') or [''])[0]).strip()
    if units not in UNIT_TO_M:
        raise ValueError(f'{path}: marker units POINT:UNITS = {units!r} unknown '
                         f'(expected one of {", ".join(UNIT_TO_M)})')
    rate = float(c['header']['points']['frame_rate'])
    first = int(c['header']['points']['first_frame'])
    names = tuple(str(s).strip() for s in _param(c, 'POINT', 'LABELS'))
    pts = np.asarray(c['data']['points'], dtype=float)          # [4, m, n]
    xyz = np.transpose(pts[:3], (2, 1, 0)) * UNIT_TO_M[units]
    time = (first + np.arange(xyz.shape[0])) / rate
    markers = MarkerTable(time=time, names=names[:xyz.shape[1]], xyz=xyz, rate_hz=rate,
                          source=str(path), info={'units': units})
    facts: dict = {'point_rate_hz': rate, 'marker_units': units}
    if 'FORCE_PLATFORM' not in c['parameters']:
        return markers, np.empty(0), [], facts
    analog_rate = float(c['header']['analogs']['frame_rate'])
    n_analog = int(np.asarray(c['data']['analogs']).shape[2])
    channels = np.asarray(_param(c, 'FORCE_PLATFORM', 'CHANNEL'), dtype=int)
    n_channels = int(np.asarray(c['data']['analogs']).shape[1])
    if channels.size and (channels.max() > n_channels or channels.min() < 1):
        bad = sorted({int(v) for v in channels.reshape(-1) if v > n_channels or v < 1})
        raise ValueError(f'{path}: FORCE_PLATFORM:CHANNEL names analog channel(s) {bad} but '
                         f'the file has {n_channels} analog channels: a plate channel is absent')
    try:
        c = ezc3d.c3d(str(path), extract_forceplat_data=True)
    except Exception as err:
        raise ValueError(f'{path}: ezc3d cannot compute the force plates: {err}') from None
    t_analog = first / rate + np.arange(n_analog) / analog_rate
    loads = []
    for k, pf in enumerate(c['data']['platform']):
        fu, mu, pu = (str(pf['unit_force']).strip(), str(pf['unit_moment']).strip(),
                      str(pf['unit_position']).strip())
        if fu not in FORCE_UNITS or mu not in MOMENT_UNITS or pu not in UNIT_TO_M:
            raise ValueError(f'{path}: plate {k + 1}: units force {fu!r}, moment {mu!r}, '
                             f'position {pu!r}: unknown (N; Nmm or Nm; mm or m expected; see '
                             'ANALOG:UNITS and POINT:UNITS)')
        force = np.asarray(pf['force'], dtype=float).T * FORCE_UNITS[fu]
        moment = np.asarray(pf['moment'], dtype=float).T * MOMENT_UNITS[mu]
        bad = ~np.all(np.isfinite(np.hstack([force, moment])), axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f'{path}: plate {k + 1}: {int(bad.sum())} NaN/inf analog '
                             f'sample(s), first at t = {t_analog[i]:.4f} s')
        centre = np.asarray(pf['corners'], dtype=float).mean(axis=1) * UNIT_TO_M[pu]
        loads.append(GroundLoad(force, np.tile(centre, (force.shape[0], 1)), moment))
        facts.setdefault('plates', []).append({
            'plate': k + 1, 'units': [fu, mu, pu], 'centre_m': centre.tolist(),
            'cop_m': np.asarray(pf['center_of_pressure'], dtype=float).T * UNIT_TO_M[pu],
            'tz_nm': np.asarray(pf['Tz'], dtype=float).T * MOMENT_UNITS[mu]})
    facts['analog_rate_hz'] = analog_rate
    return markers, t_analog, loads, facts
