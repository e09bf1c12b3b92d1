"""Results as OpenSim files, so they open in OpenSim with ``nmt export-osim``'s model.

For a motion ``<prefix>`` (the truth, Stage 1, the NMT simulation):

* ``<prefix>.sto``: the exported model's coordinates (radians, time first): foot_tilt, foot_tx,
  foot_ty, ankle_angle, knee_angle, hip_flexion.
* ``<prefix>_states.sto``: full state paths (coordinate values and speeds, and muscle
  activations when the motion has them) for OpenSim's states-based tools and the GUI.
* ``<prefix>_grf.mot`` / ``<prefix>_grf.xml``: the model's ground reaction along the motion
  (force, centre of pressure on the ground line, free torque) and the ExternalLoads applying
  it to the ``foot`` body.

The truth's files start ``pre_s`` (50 ms) before t = 0 with the static squat, which the model
holds exactly (it is an equilibrium): OpenSim differentiates coordinates with splines whose
end conditions would otherwise corrupt the accelerations at the start of the push.

``write_opensim_estimates`` adds, for an NMT run: ``stage1_torques.sto`` (the Stage-1 joint
torques, OpenSim's inverse-dynamics labels), ``stage2_states.sto`` (Stage-1 kinematics with the
Stage-2 activations: OpenSim's muscles then produce ``stage2_muscle_forces.sto``),
``stage2_controls.sto`` (the excitations, one column per muscle path as in OpenSim controls
files) and the NMT simulation as motion ``nmt``.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from nmt_ros.io.opensim_files import (
    ground_wrench_to_cop,
    write_external_loads_xml,
    write_grf_mot,
    write_table,
)
from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Truth

COORDINATES = ('foot_tilt', 'foot_tx', 'foot_ty', 'ankle_angle', 'knee_angle', 'hip_flexion')
#: OpenSim joint of each coordinate in the exported model.
JOINT_OF = {'foot_tilt': 'ground_foot', 'foot_tx': 'ground_foot', 'foot_ty': 'ground_foot',
            'ankle_angle': 'ankle', 'knee_angle': 'knee', 'hip_flexion': 'hip'}


def opensim_coordinates(model: JumperModel, q: np.ndarray) -> np.ndarray:
    """q [n, 6] -> exported coordinates [n, 6] in ``COORDINATES`` order."""
    theta, = model.batch(model.joint_angles, q)
    return np.column_stack([q[:, 0], q[:, 4], q[:, 5], theta])


def _with_quiet_start(truth: Truth, pre_s: float) -> Truth:
    """The truth extended backwards by ``pre_s`` of its (static) initial state."""
    if pre_s <= 0:
        return truth
    dt = float(truth.t[1] - truth.t[0])
    n = int(round(pre_s / dt))
    if np.abs(truth.qd[0]).max() > 1e-9:
        raise ValueError('the truth does not start at rest: no quiet period can be prepended')

    def pad(x: np.ndarray) -> np.ndarray:
        return np.concatenate([np.repeat(x[:1], n, axis=0), x])

    return replace(truth, t=np.concatenate([truth.t[0] - dt * np.arange(n, 0, -1), truth.t]),
                   q=pad(truth.q), qd=pad(truth.qd), qdd=pad(np.zeros_like(truth.qdd)),
                   a=pad(truth.a), u=pad(truth.u), f=pad(truth.f), tau=pad(truth.tau),
                   s=pad(truth.s), point_forces=pad(truth.point_forces))


def write_motion(folder: str | Path, model: JumperModel, prefix: str, t: np.ndarray,
                 q: np.ndarray, qd: np.ndarray, a: np.ndarray | None = None,
                 x0: np.ndarray | None = None) -> list[Path]:
    """``<prefix>.sto``, ``<prefix>_states.sto`` (with activations ``a`` [n, 9] if given) and,
    with the contact anchors ``x0``, ``<prefix>_grf.mot``/``.xml``; returns their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    coords = opensim_coordinates(model, q)
    speeds = opensim_coordinates(model, qd)
    speeds[:, 1:3] = qd[:, 4:6]
    out = [write_table(folder / f'{prefix}.sto', t, COORDINATES, coords, name=prefix)]
    labels = ([f'/jointset/{JOINT_OF[c]}/{c}/value' for c in COORDINATES]
              + [f'/jointset/{JOINT_OF[c]}/{c}/speed' for c in COORDINATES])
    values = [coords, speeds]
    if a is not None:
        labels += [f'/forceset/{m}/activation' for m in model.p.muscles.names]
        values.append(a)
    out.append(write_table(folder / f'{prefix}_states.sto', t, labels, np.hstack(values),
                           name=f'{prefix}_states'))
    if x0 is not None:
        points, = model.batch(model.positions, q)[4:5]
        forces, = model.batch(model.contact_forces, q, qd, x0)
        load = ground_wrench_to_cop(points, forces)
        mot = write_grf_mot(folder / f'{prefix}_grf.mot', t, load.force, load.point,
                            load.torque, name=f'{prefix}_grf')
        out += [mot, write_external_loads_xml(folder / f'{prefix}_grf.xml', mot,
                                              applied_to_body='foot')]
    return out


def write_opensim_truth(folder: str | Path, model: JumperModel, truth: Truth,
                        pre_s: float = 0.05) -> list[Path]:
    """Write the truth's four files into ``folder``; returns their paths."""
    truth = _with_quiet_start(truth, pre_s)
    return write_motion(folder, model, 'truth', truth.t, truth.q, truth.qd, truth.a, truth.x0)


def write_opensim_estimates(folder: str | Path, model: JumperModel, run: object,
                            t_offset_s: float = 0.0) -> list[Path]:
    """An NMT run's estimates as OpenSim files (module docstring); returns their paths.
    ``t_offset_s`` [s] is added to every time (the run's trial time 0 on the recording)."""
    folder = Path(folder)
    skt, s2, sim = run.skt, run.stage2, run.nmt_sim
    dt = float(t_offset_s)
    out = write_motion(folder, model, 'stage1', skt.t + dt, skt.q, skt.qd, x0=skt.x0)
    out.append(write_table(folder / 'stage1_torques.sto', skt.t + dt,
                           [f'{c}_moment' for c in COORDINATES[3:]], skt.tau,
                           name='stage1_torques'))
    if s2 is None:
        return out
    names = list(model.p.muscles.names)
    k = np.searchsorted(skt.t, s2.t - 1e-9)
    states = write_motion(folder, model, 'stage2', s2.t + dt, skt.q[k], skt.qd[k], s2.a)
    out.append(states[1])
    states[0].unlink()                  # its coordinates are Stage 1's (stage1.sto)
    out.append(write_table(folder / 'stage2_muscle_forces.sto', s2.t + dt, names, s2.f,
                           name='stage2_muscle_forces'))
    out.append(write_table(folder / 'stage2_controls.sto', s2.t + dt,
                           [f'/forceset/{m}' for m in names], s2.u, name='stage2_controls'))
    if sim is not None:
        out += write_motion(folder, model, 'nmt', sim.t + dt, sim.x[:, :6], sim.x[:, 6:12],
                            sim.x[:, 12:], sim.x0)
    return out
