"""An NMT run's estimates as OpenSim files (``nmt_ros.study.opensim_results``), read back by
us and by OpenSim itself (a subprocess: it cannot share a process with casadi)."""
from __future__ import annotations

from pathlib import Path

import crosscheck_motion as cm
import numpy as np
import pytest

from nmt_ros.io.opensim_files import read_table
from nmt_ros.study.opensim_results import write_opensim_estimates
from nmt_ros.study.pipeline import NMTSettings, run_nmt


@pytest.fixture(scope='module')
def written(model, obs, tmp_path_factory):
    run = run_nmt(model, obs, NMTSettings(stage1='skt'))
    folder = tmp_path_factory.mktemp('opensim')
    paths = write_opensim_estimates(folder, model, run)
    return run, folder, paths


def test_files_hold_the_estimates(model, written):
    """Coordinates, torques, forces and excitations round-trip exactly."""
    run, folder, paths = written
    names = {p.name for p in paths}
    assert {'stage1.sto', 'stage1_states.sto', 'stage1_grf.mot', 'stage1_grf.xml',
            'stage1_torques.sto', 'stage2_states.sto', 'stage2_muscle_forces.sto',
            'stage2_controls.sto', 'nmt.sto', 'nmt_states.sto', 'nmt_grf.mot',
            'nmt_grf.xml'} == names
    assert all(p.is_file() for p in paths)
    theta, = model.batch(model.joint_angles, run.skt.q)
    coords = read_table(folder / 'stage1.sto')
    assert np.array_equal(coords.columns(('ankle_angle', 'knee_angle', 'hip_flexion')), theta)
    torques = read_table(folder / 'stage1_torques.sto')
    assert np.array_equal(torques.data, run.skt.tau)
    assert np.array_equal(read_table(folder / 'stage2_muscle_forces.sto').data, run.stage2.f)
    controls = read_table(folder / 'stage2_controls.sto')
    assert controls.labels[0] == '/forceset/gmax'
    assert np.array_equal(controls.data, run.stage2.u)


@pytest.mark.opensim
def test_opensim_reads_the_states_and_makes_stage2_forces(model, written, tmp_path: Path):
    """OpenSim builds a StatesTrajectory from ``stage2_states.sto`` and its muscles (the
    exported model's) produce ``stage2_muscle_forces.sto`` within 1e-9 of F0."""
    _, folder, _ = written
    out = tmp_path / 'forces.npz'
    cm.crosscheck('states-forces', '--states', str(folder / 'stage2_states.sto'),
                  '--out', str(out))
    ours = read_table(folder / 'stage2_muscle_forces.sto')
    with np.load(out) as d:
        assert list(d['muscles']) == list(model.p.muscles.names)
        assert np.allclose(d['time'], ours.time, atol=1e-12, rtol=0)
        err = np.abs(d['tendon_force'] - ours.data).max(axis=0) / model.p.muscles.f0
    assert (err < 1e-9).all(), err
