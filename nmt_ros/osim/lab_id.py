"""OpenSim's inverse dynamics of a lab recording, both legs' sagittal moments summed.

The reference joint torques a planar estimate of a bilateral 3-D recording is compared with::

    python -m nmt_ros.osim.lab_id --model SUBJECT.osim --ik IK.mot --grf GRF.mot \\
        --out OUT.sto [--lowpass HZ] [--grf-lowpass HZ]

Each force plate is applied to the calcaneus of the foot above it (the foot whose calcaneus is
laterally nearest to the plate's mean point of application while the plate is loaded): the
ExternalLoads file a recording ships may apply every plate to one body (the shipped drop
jump's applies all three to ``talus_r``), which would put both feet's loads on the right leg.
The file used is written beside OUT (``OUT_external_loads.xml``). Plates are found by their
``<prefix>_v/p/m`` columns (force, point, free moment, ground frame). Muscles are excluded;
coordinate filtering is off unless ``--lowpass`` is given (the shipped setup's default).
OpenSim's tool filters the coordinates only; against unfiltered plates, the filtered
kinematics cannot follow an impact and the joint moments spike at every touchdown (the
shipped drop jump: knee 964 N m, hip 870 N m in one 100 Hz sample). ``--grf-lowpass HZ``
filters the plates alike (the usual practice: the same cut-off for both, Kristianslund et al.
2012, J Biomech 45:666): each plate's force and its moment about the ground origin (point x
force + free moment, so no centre of pressure is filtered through the unloaded samples) by
a zero-lag 4th-order Butterworth, written to ``OUT_grf_lowpass.sto`` and applied at the
origin, which is the same wrench.

OUT (.sto, N m) holds, per row of the IK file, ``ankle_angle_moment``, ``knee_angle_moment``,
``hip_flexion_moment`` in **our** signs (README "Conventions": the generalized forces of the
planar model's coordinates, two legs lumped): the sum of the two legs' OpenSim moments, the
knee negated because Rajagopal's ``knee_angle`` is +flexion where ours is -flexion; then the
per-leg OpenSim columns as OpenSim reports them, and the pelvis residuals (``pelvis_tx_force``,
``pelvis_ty_force``, ``pelvis_tilt_moment``), which show how far the recording's motion and
forces disagree for that model.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import re
import sys
import tempfile
import xml.etree.ElementTree as ET

import numpy as np
import opensim as osim

from nmt_ros.osim.fit_paths import quiet_opensim
from nmt_ros.osim.subject import read_opensim_table as read_table

#: (our label, OpenSim coordinate without side suffix, sign into our convention)
SAGITTAL = (('ankle_angle_moment', 'ankle_angle', 1.0),
            ('knee_angle_moment', 'knee_angle', -1.0),
            ('hip_flexion_moment', 'hip_flexion', 1.0))
RESIDUALS = ('pelvis_tx_force', 'pelvis_ty_force', 'pelvis_tilt_moment')


def plate_feet(model_path: str | Path, ik_path: str | Path, grf_path: str | Path,
               ) -> dict[str, str]:
    """Plate prefix -> 'calcn_r' or 'calcn_l', by lateral distance while the plate is loaded."""
    grf = read_table(grf_path)
    ik = read_table(ik_path)
    prefixes = sorted({lab[:-3] for lab in grf.labels if re.search(r'_vx$', lab)})
    model = osim.Model(str(model_path))
    state = model.initSystem()
    coords = model.getCoordinateSet()
    feet = {}
    for pre in prefixes:
        fy = grf.column(f'{pre}_vy')
        loaded = fy > 50.0
        if not loaded.any():
            continue
        point_z = float(np.mean(grf.column(f'{pre}_pz')[loaded]))
        point_x = float(np.mean(grf.column(f'{pre}_px')[loaded]))
        i = int(np.argmin(np.abs(ik.time - grf.time[np.flatnonzero(loaded)[
            int(np.argmax(fy[loaded]))]])))
        for j, lab in enumerate(ik.labels):
            if coords.contains(lab):
                value = ik.data[i, j]
                if ik.in_degrees and coords.get(lab).getMotionType() == osim.Coordinate.Rotational:
                    value = np.deg2rad(value)
                coords.get(lab).setValue(state, float(value), False)
        model.realizePosition(state)
        dist = {}
        for body in ('calcn_r', 'calcn_l'):
            p = model.getBodySet().get(body).getPositionInGround(state)
            dist[body] = abs(p.get(2) - point_z) + 0.1 * abs(p.get(0) - point_x)
        feet[pre] = min(dist, key=dist.get)
    if not feet:
        raise ValueError(f'{grf_path}: no plate carries load')
    return feet


def lowpass_plates(grf_path: Path, out: Path, cutoff_hz: float) -> Path:
    """The plates of ``grf_path`` with force and moment about the origin low-passed (module
    docstring), as a GRF table at ``out`` (.sto) with the same column names (points 0)."""
    from scipy.signal import butter, filtfilt

    grf = read_table(grf_path)
    rate = (grf.time.size - 1) / (grf.time[-1] - grf.time[0])
    if not 0 < cutoff_hz < 0.5 * rate:
        raise ValueError(f'--grf-lowpass {cutoff_hz} Hz must be in (0, {0.5 * rate:g}) Hz '
                         f'(the plates are sampled at {rate:g} Hz)')
    b, a = butter(2, cutoff_hz / (0.5 * rate))
    cols = {lab: grf.column(lab) for lab in grf.labels}
    out_cols = dict(cols)
    for pre in sorted({lab[:-3] for lab in grf.labels if re.search(r'_vx$', lab)}):
        f = np.column_stack([cols[f'{pre}_v{x}'] for x in 'xyz'])
        p = np.column_stack([cols[f'{pre}_p{x}'] for x in 'xyz'])
        free = (np.column_stack([cols[f'{pre}_m{x}'] for x in 'xyz'])
                if f'{pre}_mx' in cols else np.zeros_like(f))
        moment = np.cross(p, f) + free
        f, moment = filtfilt(b, a, f, axis=0), filtfilt(b, a, moment, axis=0)
        for k, x in enumerate('xyz'):
            out_cols[f'{pre}_v{x}'] = f[:, k]
            out_cols[f'{pre}_p{x}'] = np.zeros_like(f[:, k])
            out_cols[f'{pre}_m{x}'] = moment[:, k]
    labels = list(out_cols)
    return write_sto(out, grf.time, labels, np.column_stack([out_cols[k] for k in labels]),
                     'grf_lowpass', {'lowpass_hz': cutoff_hz})


def write_loads(path: Path, grf_path: Path, feet: dict[str, str]) -> Path:
    root = ET.Element('OpenSimDocument', Version='40000')
    loads = ET.SubElement(root, 'ExternalLoads', name='plates_on_feet')
    objects = ET.SubElement(loads, 'objects')
    for pre, body in feet.items():
        ext = ET.SubElement(objects, 'ExternalForce', name=pre)
        for tag, text in (('applied_to_body', body), ('force_expressed_in_body', 'ground'),
                          ('point_expressed_in_body', 'ground'),
                          ('force_identifier', f'{pre}_v'), ('point_identifier', f'{pre}_p'),
                          ('torque_identifier', f'{pre}_m')):
            ET.SubElement(ext, tag).text = text
    ET.SubElement(loads, 'groups')
    try:
        datafile = os.path.relpath(grf_path.resolve(), path.resolve().parent)
    except ValueError:                   # other drive: keep it absolute
        datafile = str(grf_path.resolve())
    ET.SubElement(loads, 'datafile').text = datafile
    ET.indent(root, space='\t')
    path.write_bytes(b'<?xml version="1.0" encoding="UTF-8" ?>\n' + ET.tostring(root) + b'\n')
    return path


def write_sto(path: Path, time: np.ndarray, labels: list[str], data: np.ndarray, name: str,
              metadata: dict) -> Path:
    """A table as a .sto through OpenSim's own STOFileAdapter (extra header lines: metadata)."""
    table = osim.TimeSeriesTable()
    table.setColumnLabels(list(labels))
    for t, row in zip(time, np.asarray(data, dtype=float)):
        table.appendRow(float(t), osim.RowVector([float(v) for v in row]))
    table.addTableMetaDataString('name', name)
    table.addTableMetaDataString('inDegrees', 'no')
    for k, v in metadata.items():
        table.addTableMetaDataString(str(k), str(v))
    osim.STOFileAdapter.write(table, str(path))
    return path


def run_id(model_path: Path, ik_path: Path, grf_path: Path, out: Path,
           lowpass_hz: float = -1.0, grf_lowpass_hz: float = -1.0) -> dict:
    quiet_opensim()
    feet = plate_feet(model_path, ik_path, grf_path)
    if grf_lowpass_hz > 0:
        grf_path = lowpass_plates(grf_path, out.with_name(out.stem + '_grf_lowpass.sto'),
                                  grf_lowpass_hz)
    loads_xml = out.with_name(out.stem + '_external_loads.xml')
    write_loads(loads_xml, grf_path, feet)
    with tempfile.TemporaryDirectory() as tmp:
        tool = osim.InverseDynamicsTool()
        model = osim.Model(str(model_path))
        model.initSystem()
        tool.setModel(model)
        tool.setCoordinatesFileName(str(ik_path))
        tool.setExternalLoadsFileName(str(loads_xml))
        tool.setLowpassCutoffFrequency(float(lowpass_hz))
        excluded = osim.ArrayStr()
        excluded.append('Muscles')
        tool.setExcludedForces(excluded)
        ik = read_table(ik_path)
        tool.setStartTime(float(ik.time[0]))
        tool.setEndTime(float(ik.time[-1]))
        tool.setResultsDir(tmp)
        tool.setOutputGenForceFileName('id.sto')
        if not tool.run():
            raise RuntimeError('OpenSim InverseDynamicsTool failed')
        res = read_table(Path(tmp) / 'id.sto')
    labels, cols = [], []
    for ours, coord, sign in SAGITTAL:
        r = res.column(f'{coord}_r_moment')
        left = res.column(f'{coord}_l_moment')
        labels.append(ours)
        cols.append(sign * (r + left))
    for _, coord, _ in SAGITTAL:
        for s in ('r', 'l'):
            labels.append(f'{coord}_{s}_moment')
            cols.append(res.column(f'{coord}_{s}_moment'))
    for lab in RESIDUALS:
        labels.append(lab)
        cols.append(res.column(lab))
    data = np.column_stack(cols)
    meta = {'plates_on': ' '.join(f'{k}:{v}' for k, v in feet.items()),
            'lowpass_hz': lowpass_hz, 'grf_lowpass_hz': grf_lowpass_hz,
            'note': 'first 3 columns: both legs summed in nmt_ros signs (knee negated)'}
    write_sto(out, res.time, labels, data, 'opensim_id', meta)
    peaks = {lab: float(np.abs(data[:, i]).max()) for i, lab in enumerate(labels)}
    return {'feet': feet, 'peaks_abs_nm': peaks, 'external_loads': str(loads_xml)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m nmt_ros.osim.lab_id')
    parser.add_argument('--model', required=True, type=Path)
    parser.add_argument('--ik', required=True, type=Path)
    parser.add_argument('--grf', required=True, type=Path)
    parser.add_argument('--out', required=True, type=Path)
    parser.add_argument('--lowpass', type=float, default=-1.0,
                        help='coordinate low-pass cut-off [Hz] (default: none)')
    parser.add_argument('--grf-lowpass', type=float, default=-1.0,
                        help='force-plate low-pass cut-off [Hz] (default: none; module doc)')
    args = parser.parse_args(argv)
    info = run_id(args.model, args.ik, args.grf, args.out, args.lowpass, args.grf_lowpass)
    for k, v in info['peaks_abs_nm'].items():
        print(f'{k:24s} peak |.| {v:9.1f}')
    print('plates on', info['feet'])
    return 0


if __name__ == '__main__':
    sys.exit(main())
