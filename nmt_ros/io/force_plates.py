"""Force plates from an OpenSim ground-reaction file (.mot), with or without ExternalLoads.

Each plate is a :class:`~nmt_ros.io.opensim_files.GroundLoad` in the lab (ground) frame: force
[N], point of application [m], free torque [N m], one row per sample of the file.
"""
from __future__ import annotations

import os
import re

import numpy as np

from nmt_ros.io.opensim_files import (
    GroundLoad,
    read_external_loads_xml,
    read_table,
    without_repeated_rows,
)

#: A plate's point of application farther than this from the lab origin means wrong units [m].
MAX_POINT_M = 20.0


def read_plates(grf: str | os.PathLike, external_loads: str | os.PathLike | None = None,
                ) -> tuple[np.ndarray, list[GroundLoad], list[str], list[float]]:
    """(time [n], one GroundLoad per plate (ground frame, N / m / N m), plate names, the
    times [s] of rows dropped because they repeated the row before exactly).

    With ``external_loads`` its ExternalForces name the columns (force and point expressed in
    ground); without, every ``<prefix>_vx/vy/vz`` triple is a plate, with its point
    ``<prefix>_px..`` and free torque ``<prefix>_mx..`` or ``<torque prefix>_x..`` (``force`` ->
    ``torque`` in the prefix). Missing columns, NaN samples and points of application too far
    for metres are refused.
    """
    table, repeated = without_repeated_rows(read_table(grf))
    labels = set(table.labels)
    specs: list[tuple[str, str, str, str]] = []      # name, force, point, torque identifiers
    if external_loads is not None:
        _, forces = read_external_loads_xml(external_loads)
        if not forces:
            raise ValueError(f'{external_loads}: no ExternalForce')
        for f in forces:
            for what, frame in (('force', f.force_expressed_in_body),
                                ('point', f.point_expressed_in_body)):
                if frame != 'ground':
                    raise ValueError(f'{external_loads}: {f.name}: {what} expressed in '
                                     f'{frame!r}; only ground is supported')
            specs.append((f.name, f.force_identifier, f.point_identifier, f.torque_identifier))
    else:
        prefixes = sorted({lab[:-3] for lab in labels if re.search(r'_v[xyz]$', lab)
                           and all(f'{lab[:-3]}_v{c}' in labels for c in 'xyz')})
        if not prefixes:
            raise ValueError(f'{grf}: no force columns (<prefix>_vx, _vy, _vz)')
        for pre in prefixes:
            cands = [f'{pre}_m', pre.replace('force', 'torque') + '_']
            torque = next((c for c in cands if all(f'{c}{a}' in labels for a in 'xyz')), None)
            if torque is None:
                raise ValueError(f'{grf}: plate {pre}: no free-moment columns ({cands[0]}x.. or '
                                 f'{cands[1]}x..); name them with --external-loads')
            specs.append((pre, f'{pre}_v', f'{pre}_p', torque))
    loads, names = [], []
    for name, fid, pid, tid in specs:
        cols = [f'{fid}{a}' for a in 'xyz'] + [f'{pid}{a}' for a in 'xyz']
        cols += [f'{tid}{a}' for a in 'xyz']
        values = table.columns(cols)
        bad = ~np.all(np.isfinite(values), axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f'{grf}: plate {name}: {int(bad.sum())} NaN/inf row(s), first at '
                             f't = {table.time[i]:.4f} s')
        force, point, torque = values[:, :3], values[:, 3:6], values[:, 6:]
        loaded = np.linalg.norm(force, axis=1) > 1.0
        if loaded.any() and np.abs(point[loaded]).max() > MAX_POINT_M:
            raise ValueError(f'{grf}: plate {name}: points of application up to '
                             f'{np.abs(point[loaded]).max():.0f} from the origin: not metres '
                             '(OpenSim GRF files are N, m, N m)')
        loads.append(GroundLoad(force, point, torque))
        names.append(name)
    return table.time, loads, names, repeated
