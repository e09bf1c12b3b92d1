"""Marker trajectories: OpenSim's TRC files, read and written (pure Python + numpy).

TRC (``PathFileType 4 (X/Y/Z)``): a header line, a line of keys (``DataRate CameraRate
NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames``) and their values,
a line ``Frame# Time name1 <tab><tab> name2 ...``, a line ``X1 Y1 Z1 X2 ...``, then one row per
frame. Empty fields (a marker not seen) read as NaN. ``Units`` must be ``m`` or ``mm``
(converted to metres); anything else is refused.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

UNIT_TO_M = {'m': 1.0, 'mm': 1e-3, 'cm': 1e-2}


@dataclass(frozen=True)
class MarkerTable:
    """Marker positions ``xyz`` [n_frames, n_markers, 3] (m, lab frame), ``time`` [n] (s)."""

    time: np.ndarray
    names: tuple[str, ...]
    xyz: np.ndarray
    rate_hz: float
    source: str = ''
    info: dict = field(default_factory=dict)

    def marker(self, name: str) -> np.ndarray:
        """[n, 3] positions of one marker; ValueError naming it (and the known ones) if absent."""
        try:
            return self.xyz[:, self.names.index(name)]
        except ValueError:
            raise ValueError(f'marker {name!r} is not in {self.source or "the recording"} '
                             f'(it has: {", ".join(self.names)})') from None


def read_trc(path: str | Path) -> MarkerTable:
    """Read a TRC file into a :class:`MarkerTable` (metres)."""
    path = Path(path)
    lines = path.read_text(encoding='utf-8', errors='replace').splitlines()
    if len(lines) < 5 or not lines[0].startswith('PathFileType'):
        raise ValueError(f'{path}: not a TRC file (first line must start with PathFileType)')
    keys = lines[1].split('\t')
    values = lines[2].split('\t')
    header = {k.strip(): v.strip() for k, v in zip(keys, values) if k.strip()}
    units = header.get('Units', '').strip()
    if units not in UNIT_TO_M:
        raise ValueError(f'{path}: marker units {units!r} unknown (TRC "Units" must be one of '
                         f'{", ".join(UNIT_TO_M)})')
    try:
        rate = float(header['DataRate'])
    except (KeyError, ValueError):
        raise ValueError(f'{path}: no valid DataRate in the header') from None
    cols = lines[3].split('\t')
    if len(cols) < 3 or cols[0].strip() != 'Frame#' or cols[1].strip() != 'Time':
        raise ValueError(f'{path}: line 4 must start with "Frame#<tab>Time"')
    names = tuple(c.strip() for c in cols[2:] if c.strip())
    n_markers = len(names)
    if 'NumMarkers' in header and int(header['NumMarkers']) != n_markers:
        raise ValueError(f'{path}: NumMarkers = {header["NumMarkers"]} but {n_markers} names')
    rows = []
    for line in lines[5:]:
        if not line.strip():
            continue
        fields = line.split('\t')
        vals = [float(f) if f.strip() else np.nan for f in fields[:2 + 3 * n_markers]]
        vals += [np.nan] * (2 + 3 * n_markers - len(vals))
        rows.append(vals)
    if not rows:
        raise ValueError(f'{path}: no frames')
    data = np.asarray(rows, dtype=float)
    time = data[:, 1]
    if not np.all(np.isfinite(time)) or np.any(np.diff(time) <= 0):
        raise ValueError(f'{path}: the Time column must be finite and increasing')
    xyz = data[:, 2:].reshape(-1, n_markers, 3) * UNIT_TO_M[units]
    return MarkerTable(time=time, names=names, xyz=xyz, rate_hz=rate, source=str(path),
                       info={'units': units, 'header': header})


def write_trc(path: str | Path, time: np.ndarray, names: list[str] | tuple[str, ...],
              xyz: np.ndarray, units: str = 'm') -> Path:
    """Write ``xyz`` [n, m, 3] (in ``units``) as a TRC file; NaN become empty fields."""
    path = Path(path)
    time = np.asarray(time, dtype=float)
    xyz = np.asarray(xyz, dtype=float)
    n, m = xyz.shape[:2]
    rate = 1.0 / float(np.median(np.diff(time))) if n > 1 else 0.0
    out = ['\t'.join(['PathFileType', '4', '(X/Y/Z)', path.name]),
           '\t'.join(['DataRate', 'CameraRate', 'NumFrames', 'NumMarkers', 'Units',
                      'OrigDataRate', 'OrigDataStartFrame', 'OrigNumFrames']),
           '\t'.join([f'{rate:g}', f'{rate:g}', str(n), str(m), units, f'{rate:g}', '1',
                      str(n)]),
           '\t'.join(['Frame#', 'Time'] + [f'{name}\t\t' for name in names]),
           '\t'.join(['', ''] + [f'{a}{k + 1}' for k in range(m) for a in 'XYZ'])]
    for i in range(n):
        vals = ['' if not np.isfinite(v) else repr(float(v)) for v in xyz[i].reshape(-1)]
        out.append('\t'.join([str(i + 1), repr(float(time[i]))] + vals))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(out) + '\n', encoding='utf-8')
    return path
