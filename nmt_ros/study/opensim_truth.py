"""The truth as OpenSim files, so the jump opens in OpenSim with ``nmt export-osim``'s model.

* ``truth.sto``: the exported model's coordinates (radians, time first): foot_tilt, foot_tx,
  foot_ty, ankle_angle, knee_angle, hip_flexion.
* ``truth_states.sto``: full state paths (coordinate values and speeds, muscle activations)
  for OpenSim's states-based tools and the GUI's motion loading.
* ``truth_grf.mot`` / ``truth_grf.xml``: the ground reaction (force, centre of pressure on the
  ground line, free torque; exact) and the ExternalLoads applying it to the ``foot`` body.

The files start ``pre_s`` (50 ms) before t = 0 with the static squat, which the model holds
exactly (it is an equilibrium): OpenSim differentiates coordinates with splines whose end
conditions would otherwise corrupt the accelerations at the start of the push.
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
from nmt_ros.study.trial import Truth

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


def write_opensim_truth(folder: str | Path, model: JumperModel, truth: Truth,
                        pre_s: float = 0.05) -> list[Path]:
    """Write the four files into ``folder``; returns their paths."""
    folder = Path(folder)
    truth = _with_quiet_start(truth, pre_s)
    coords = opensim_coordinates(model, truth.q)
    speeds = opensim_coordinates(model, truth.qd)
    speeds[:, 1:3] = truth.qd[:, 4:6]
    out = [write_table(folder / 'truth.sto', truth.t, COORDINATES, coords, name='truth')]
    labels = ([f'/jointset/{JOINT_OF[c]}/{c}/value' for c in COORDINATES]
              + [f'/jointset/{JOINT_OF[c]}/{c}/speed' for c in COORDINATES]
              + [f'/forceset/{m}/activation' for m in model.p.muscles.names])
    out.append(write_table(folder / 'truth_states.sto', truth.t, labels,
                           np.hstack([coords, speeds, truth.a]), name='truth_states'))
    points, = model.batch(model.positions, truth.q)[4:5]
    forces, = model.batch(model.contact_forces, truth.q, truth.qd, truth.x0)
    load = ground_wrench_to_cop(points, forces)
    mot = write_grf_mot(folder / 'truth_grf.mot', truth.t, load.force, load.point, load.torque,
                        name='truth_grf')
    out += [mot, write_external_loads_xml(folder / 'truth_grf.xml', mot,
                                          applied_to_body='foot')]
    return out
