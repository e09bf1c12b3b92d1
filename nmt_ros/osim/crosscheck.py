"""OpenSim-side evaluators for cross-checks, exchanged through files.

Run as subprocesses (OpenSim cannot share a process with casadi)::

    python -m nmt_ros.osim.crosscheck muscles --in IN.npz --out OUT.npz [--model M.osim]
    python -m nmt_ros.osim.crosscheck id --coordinates Q.sto --external-loads EL.xml \\
        [--grf GRF.mot] --out-sto OUT.sto [--out-npz OUT.npz] [--model M.osim] [--lowpass HZ]
    python -m nmt_ros.osim.crosscheck write-inputs --in IN.npz --dir DIR
    python -m nmt_ros.osim.crosscheck states-forces --states S.sto --out OUT.npz [--model M]

Without ``--model`` the model is built from the data file (``nmt_ros.osim.export``).

``muscles``: IN.npz holds ``q`` [n, 6] = our [th1, th2, th3, th4, r1, r2], ``qd`` [n, 6]
(same layout, rates) and ``a`` [n, 9] activations. They become the exported coordinates
(foot_tilt = th1, foot_tx = r1, foot_ty = r2, ankle_angle = th1 - th2, knee_angle =
th2 - th3, hip_flexion = th3 - th4; speeds alike), the activation state is set directly, and
OUT.npz gets, per sample and muscle (order of the data file), OpenSim's [n, 9] arrays
``tendon_force``, ``fiber_force`` (active + passive, along the fibre),
``active_fiber_force`` (F0 a f_L f_V), ``passive_fiber_force`` (as OpenSim 4.6 reports it for
DeGrooteFregly2016Muscle: F0 (f_PE + beta v~), damping included), its parts
``elastic_fiber_force`` (F0 f_PE) and ``damping_force`` (F0 beta v~), ``fiber_length``,
``fiber_velocity``, ``pennation_angle``, ``musculotendon_length``, ``lengthening_speed``,
the multipliers ``active_force_length``, ``force_velocity``, ``passive_force_length``, and
``moment_arms`` [n, 9, 3] about ``coordinates`` = (ankle_angle, knee_angle, hip_flexion).

``id``: OpenSim's InverseDynamicsTool on the model with the coordinates file (time + the 6
exported coordinates in rad; inDegrees=no) and the ExternalLoads file (its force applied to
body ``foot``, point and force expressed in ground). Muscles are excluded, the passive joint
ExpressionBasedCoordinateForces stay, and coordinate filtering is off
(``lowpass_cutoff_frequency_for_coordinates = -1``; ``--lowpass HZ`` sets it). The
generalized forces (``foot_tilt_moment``, ``foot_tx_force``, ``foot_ty_force``,
``ankle_angle_moment``, ``knee_angle_moment``, ``hip_flexion_moment``) go to a .sto and,
optionally, an npz with ``time``, ``labels`` and ``values``.

``states-forces``: OpenSim reads a states file (``nmt_ros.study.opensim_results``) into a
StatesTrajectory and OUT.npz gets ``time`` and the muscles' ``tendon_force`` [n, 9].

``write-inputs``: test inputs written with OpenSim's own API (TimeSeriesTable and
STOFileAdapter). IN.npz holds ``t`` [n], ``q`` [n, 6] (ours, converted as above) and
``force`` [n, 2 or 3] with ``point`` [n, 2 or 3] (ground frame, applied to the foot),
optionally ``torque`` [n, 3]. DIR receives coordinates.sto, grf.mot and
external_loads.xml.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile

import numpy as np
import opensim as osim

from nmt_ros.osim.export import build_model
from nmt_ros.osim.fit_paths import quiet_opensim
from nmt_ros.osim.modeldata import (
    EXPORT_COORDINATES,
    JOINT_COORDINATES,
    MUSCLES,
    opensim_coordinates_from_q,
)

GRF_PREFIX = 'ground_force_'
TORQUE_PREFIX = 'ground_torque_'
MUSCLE_OUTPUTS = ('tendon_force', 'fiber_force', 'active_fiber_force', 'passive_fiber_force',
                  'elastic_fiber_force', 'damping_force', 'fiber_length', 'fiber_velocity',
                  'pennation_angle', 'musculotendon_length', 'lengthening_speed',
                  'active_force_length', 'force_velocity', 'passive_force_length')


def load_model(path: str | Path | None = None) -> osim.Model:
    """The exported model from ``path``, or built afresh from the data file."""
    if path is None:
        return build_model()
    model = osim.Model(str(path))
    model.initSystem()
    return model


# ---------------------------------------------------------------------------------------------
# muscles
# ---------------------------------------------------------------------------------------------

def muscle_quantities(model: osim.Model, q: np.ndarray, qd: np.ndarray,
                      a: np.ndarray) -> dict[str, np.ndarray]:
    """OpenSim muscle outputs at our states (see module docstring)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    a = np.atleast_2d(np.asarray(a, dtype=float))
    n = q.shape[0]
    if q.shape != (n, 6) or qd.shape != (n, 6) or a.shape != (n, len(MUSCLES)):
        raise ValueError(f'expected q, qd [n, 6] and a [n, {len(MUSCLES)}]; got '
                         f'{q.shape}, {qd.shape}, {a.shape}')
    x = opensim_coordinates_from_q(q)
    xd = opensim_coordinates_from_q(qd)
    state = model.initSystem()
    cset = model.getCoordinateSet()
    coords = [cset.get(c) for c in EXPORT_COORDINATES]
    joints = [cset.get(c) for c in JOINT_COORDINATES]
    muscles = [model.getMuscles().get(m) for m in MUSCLES]
    out = {k: np.empty((n, len(MUSCLES))) for k in MUSCLE_OUTPUTS}
    out['moment_arms'] = np.empty((n, len(MUSCLES), len(JOINT_COORDINATES)))
    for i in range(n):
        for c, v, vd in zip(coords, x[i], xd[i]):
            c.setValue(state, float(v), False)
            c.setSpeedValue(state, float(vd))
        for m, ai in zip(muscles, a[i]):
            m.setActivation(state, float(ai))
        model.realizeDynamics(state)
        for k, m in enumerate(muscles):
            row = {
                'tendon_force': m.getTendonForce(state),
                'fiber_force': m.getFiberForce(state),
                'active_fiber_force': m.getActiveFiberForce(state),
                'passive_fiber_force': m.getPassiveFiberForce(state),
                'fiber_length': m.getFiberLength(state),
                'fiber_velocity': m.getFiberVelocity(state),
                'pennation_angle': m.getPennationAngle(state),
                'musculotendon_length': m.getLength(state),
                'lengthening_speed': m.getLengtheningSpeed(state),
                'active_force_length': m.getActiveForceLengthMultiplier(state),
                'force_velocity': m.getForceVelocityMultiplier(state),
                'passive_force_length': m.getPassiveForceMultiplier(state),
            }
            row['elastic_fiber_force'] = (m.getMaxIsometricForce()
                                          * row['passive_force_length'])
            row['damping_force'] = row['passive_fiber_force'] - row['elastic_fiber_force']
            for key, value in row.items():
                out[key][i, k] = value
            for j, c in enumerate(joints):
                out['moment_arms'][i, k, j] = m.computeMomentArm(state, c)
    out['muscles'] = np.array(MUSCLES)
    out['coordinates'] = np.array(JOINT_COORDINATES)
    return out


def states_file_forces(model: osim.Model, states_file: str | Path) -> dict[str, np.ndarray]:
    """Tendon forces [n, 9] (data-file order) along a states .sto, read by OpenSim itself
    (``StatesTrajectory.createFromStatesTable``: coordinate values and speeds, activations)."""
    model.initSystem()
    table = osim.TimeSeriesTable(str(states_file))
    traj = osim.StatesTrajectory.createFromStatesTable(model, table, True, False, False)
    muscles = [model.getMuscles().get(m) for m in MUSCLES]
    n = traj.getSize()
    time = np.empty(n)
    force = np.empty((n, len(MUSCLES)))
    for i in range(n):
        state = traj.get(i)
        model.realizeDynamics(state)
        time[i] = state.getTime()
        force[i] = [m.getTendonForce(state) for m in muscles]
    return {'time': time, 'tendon_force': force, 'muscles': np.array(MUSCLES)}


# ---------------------------------------------------------------------------------------------
# inverse dynamics
# ---------------------------------------------------------------------------------------------

def read_sto(path: str | Path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """(time [n], labels, values [n, m]) of a .sto/.mot file, read by OpenSim."""
    table = osim.TimeSeriesTable(str(path))
    labels = list(table.getColumnLabels())
    time = np.array(table.getIndependentColumn())
    values = table.getMatrix().to_numpy() if labels else np.empty((time.size, 0))
    return time, labels, np.asarray(values).reshape(time.size, len(labels))


def inverse_dynamics(model: osim.Model, coordinates_file: str | Path,
                     external_loads_file: str | Path | None, out_sto: str | Path,
                     grf_file: str | Path | None = None, lowpass_hz: float = -1.0,
                     ) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Run OpenSim's InverseDynamicsTool; returns (time, labels, generalized forces)."""
    out_sto = Path(out_sto).resolve()
    time, _, _ = read_sto(coordinates_file)
    with tempfile.TemporaryDirectory(prefix='nmt_id_') as tmp:
        tool = osim.InverseDynamicsTool()
        tool.setModel(model)
        tool.setCoordinatesFileName(str(Path(coordinates_file).resolve()))
        if external_loads_file is not None:
            loads_file = Path(external_loads_file).resolve()
            if grf_file is not None:   # point the loads at another data file
                loads = osim.ExternalLoads(str(loads_file), True)
                loads.setDataFileName(str(Path(grf_file).resolve()))
                loads_file = Path(tmp) / 'external_loads.xml'
                loads.printToXML(str(loads_file))
            tool.setExternalLoadsFileName(str(loads_file))
        excluded = osim.ArrayStr()
        excluded.append('Muscles')
        tool.setExcludedForces(excluded)
        tool.setLowpassCutoffFrequency(float(lowpass_hz))
        tool.setStartTime(float(time[0]))
        tool.setEndTime(float(time[-1]))
        tool.setResultsDir(str(out_sto.parent))
        tool.setOutputGenForceFileName(out_sto.name)
        if not tool.run():
            raise RuntimeError('InverseDynamicsTool failed')
    return read_sto(out_sto)


# ---------------------------------------------------------------------------------------------
# input files (OpenSim's own writers)
# ---------------------------------------------------------------------------------------------

def _table(time: np.ndarray, labels: list[str], values: np.ndarray) -> osim.TimeSeriesTable:
    table = osim.TimeSeriesTable()
    names = osim.StdVectorString()
    for label in labels:
        names.append(label)
    table.setColumnLabels(names)
    for t, row in zip(time, values):
        table.appendRow(float(t), osim.RowVector([float(v) for v in row]))
    return table


def write_coordinates_sto(path: str | Path, time: np.ndarray, coords: np.ndarray) -> None:
    """Exported-model coordinates [n, 6] (EXPORT_COORDINATES order, rad) as a .sto."""
    table = _table(np.asarray(time), list(EXPORT_COORDINATES), np.asarray(coords))
    table.addTableMetaDataString('inDegrees', 'no')
    osim.STOFileAdapter.write(table, str(path))


def write_grf_mot(path: str | Path, time: np.ndarray, force: np.ndarray, point: np.ndarray,
                  torque: np.ndarray | None = None) -> None:
    """Ground reaction force, point and torque (ground frame) as a .mot."""
    def xyz(v: np.ndarray) -> np.ndarray:
        v = np.atleast_2d(np.asarray(v, dtype=float))
        return np.column_stack([v, np.zeros((v.shape[0], 3 - v.shape[1]))])
    n = len(time)
    torque = np.zeros((n, 3)) if torque is None else xyz(torque)
    labels = ([f'{GRF_PREFIX}v{c}' for c in 'xyz'] + [f'{GRF_PREFIX}p{c}' for c in 'xyz']
              + [f'{TORQUE_PREFIX}{c}' for c in 'xyz'])
    table = _table(np.asarray(time), labels, np.hstack([xyz(force), xyz(point), torque]))
    table.addTableMetaDataString('inDegrees', 'no')
    osim.STOFileAdapter.write(table, str(path))


def write_external_loads_xml(path: str | Path, grf_file: str | Path,
                             body: str = 'foot') -> None:
    """ExternalLoads with one ExternalForce on ``body``, force and point in ground."""
    loads = osim.ExternalLoads()
    loads.setName('ground_reaction')
    loads.setDataFileName(str(grf_file))
    force = osim.ExternalForce()
    force.setName('grf')
    force.set_applied_to_body(body)
    force.set_force_expressed_in_body('ground')
    force.set_point_expressed_in_body('ground')
    force.set_force_identifier(GRF_PREFIX + 'v')
    force.set_point_identifier(GRF_PREFIX + 'p')
    force.set_torque_identifier(TORQUE_PREFIX)
    loads.cloneAndAppend(force)
    loads.printToXML(str(path))


def write_inputs(npz: str | Path, directory: str | Path) -> dict[str, Path]:
    d = np.load(npz)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    files = {'coordinates': directory / 'coordinates.sto', 'grf': directory / 'grf.mot',
             'external_loads': directory / 'external_loads.xml'}
    t = np.asarray(d['t'], dtype=float)
    write_coordinates_sto(files['coordinates'], t, opensim_coordinates_from_q(d['q']))
    write_grf_mot(files['grf'], t, d['force'], d['point'],
                  d['torque'] if 'torque' in d else None)
    write_external_loads_xml(files['external_loads'], files['grf'].resolve())
    return files


# ---------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m nmt_ros.osim.crosscheck',
                                     description='OpenSim evaluators for cross-checks.')
    sub = parser.add_subparsers(dest='verb', required=True)
    p = sub.add_parser('muscles', help='muscle forces, lengths and moment arms')
    p.add_argument('--in', dest='inp', required=True, type=Path)
    p.add_argument('--out', required=True, type=Path)
    p.add_argument('--model', type=Path, default=None)
    p = sub.add_parser('states-forces', help='muscle tendon forces along a states .sto')
    p.add_argument('--states', required=True, type=Path)
    p.add_argument('--out', required=True, type=Path)
    p.add_argument('--model', type=Path, default=None)
    p = sub.add_parser('id', help="OpenSim's InverseDynamicsTool")
    p.add_argument('--coordinates', required=True, type=Path)
    p.add_argument('--external-loads', type=Path, default=None)
    p.add_argument('--grf', type=Path, default=None,
                   help='GRF .mot (overrides the data file named in the loads file)')
    p.add_argument('--out-sto', required=True, type=Path)
    p.add_argument('--out-npz', type=Path, default=None)
    p.add_argument('--model', type=Path, default=None)
    p.add_argument('--lowpass', type=float, default=-1.0, metavar='HZ',
                   help='lowpass_cutoff_frequency_for_coordinates (default -1: no filter)')
    p = sub.add_parser('write-inputs', help='write .sto/.mot/.xml test inputs from an npz')
    p.add_argument('--in', dest='inp', required=True, type=Path)
    p.add_argument('--dir', required=True, type=Path)
    args = parser.parse_args(argv)
    quiet_opensim()

    if args.verb == 'muscles':
        d = np.load(args.inp)
        out = muscle_quantities(load_model(args.model), d['q'], d['qd'], d['a'])
        np.savez(args.out, **out)
    elif args.verb == 'states-forces':
        np.savez(args.out, **states_file_forces(load_model(args.model), args.states))
    elif args.verb == 'id':
        time, labels, values = inverse_dynamics(load_model(args.model), args.coordinates,
                                                args.external_loads, args.out_sto, args.grf,
                                                args.lowpass)
        if args.out_npz:
            np.savez(args.out_npz, time=time, labels=np.array(labels), values=values)
    else:
        for name, path in write_inputs(args.inp, args.dir).items():
            print(f'{name}: {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
