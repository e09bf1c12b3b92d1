"""The exported OpenSim model (.osim) against the data file and hand-computed kinematics.

OpenSim runs in subprocesses only (it cannot share a process with casadi).
"""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DATA_FILE = REPO / 'nmt_ros' / 'model' / 'data' / 'jumper.yaml'
COORDS = ['foot_tilt', 'foot_tx', 'foot_ty', 'ankle_angle', 'knee_angle', 'hip_flexion']

pytestmark = pytest.mark.opensim


def _run(*args: str) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


@pytest.fixture(scope='module')
def data() -> dict:
    with open(DATA_FILE) as f:
        return yaml.safe_load(f)


@pytest.fixture(scope='module')
def probe(tmp_path_factory: pytest.TempPathFactory) -> dict:
    # OpenSim is a test requirement: a missing install fails here, it never skips.
    assert importlib.util.find_spec('opensim') is not None, 'opensim is not installed'
    out = tmp_path_factory.mktemp('osim') / 'jumper.osim'
    _run('-m', 'nmt_ros.cli.main', 'export-osim', '--out', str(out))
    assert out.is_file()
    return json.loads(_run('-m', 'nmt_ros.osim.export', '--probe', str(out),
                           '--poses', '25').stdout)


def _rot(th: float) -> np.ndarray:
    return np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])


def _hand_kinematics(q: list[float], data: dict) -> dict:
    """Absolute angles and frame origins from our conventions (written out independently)."""
    tilt, tx, ty, ankle, knee, hip = q
    th = {'foot': tilt}
    th['shank'] = th['foot'] - ankle
    th['thigh'] = th['shank'] - knee
    th['hat'] = th['thigh'] - hip
    seg = data['segments']
    o = {'foot': np.array([tx, ty])}
    o['shank'] = o['foot'] - _rot(th['shank']) @ np.array(seg['shank']['distal_joint'])
    o['thigh'] = o['shank'] - _rot(th['thigh']) @ np.array(seg['thigh']['distal_joint'])
    o['hat'] = o['thigh']
    return {b: (th[b], o[b]) for b in th}


def _poly(exponents: list, coefficients: list, q: np.ndarray) -> tuple[float, np.ndarray]:
    e = np.asarray(exponents, dtype=int)
    c = np.asarray(coefficients, dtype=float)
    value = float(np.prod(q[None, :] ** e, axis=1) @ c)
    grad = np.zeros(len(q))
    for j in range(len(q)):
        d = e.copy()
        d[:, j] = np.maximum(d[:, j] - 1, 0)
        grad[j] = float((e[:, j] * np.prod(q[None, :] ** d, axis=1)) @ c)
    return value, grad


def test_structure_and_mass_properties(probe: dict, data: dict) -> None:
    assert probe['coordinates'] == COORDS
    assert probe['gravity'] == [0.0, -data['gravity']['value'], 0.0]
    assert set(probe['bodies']) == {'foot', 'shank', 'thigh', 'hat'}
    for name, b in probe['bodies'].items():
        s = data['segments'][name]
        assert b['mass'] == pytest.approx(s['mass'], abs=0)
        assert b['com'][:2] == pytest.approx(s['com'], abs=0)
        assert b['inertia'][2] == pytest.approx(s['izz'], abs=0)
    forces = probe['forces']
    for j in ('ankle_angle', 'knee_angle', 'hip_flexion'):
        assert forces[f'passive_{j}'] == 'ExpressionBasedCoordinateForce'
    assert not any('Contact' in cls or 'Sphere' in cls for cls in forces.values())


def test_kinematics_match_hand_computation(probe: dict, data: dict) -> None:
    for pose in probe['poses']:
        hand = _hand_kinematics(pose['q'], data)
        for body, (th, origin) in hand.items():
            got = pose['bodies'][body]
            assert got['angles_xyz'][:2] == pytest.approx([0.0, 0.0], abs=1e-12)
            dth = (got['angles_xyz'][2] - th + np.pi) % (2 * np.pi) - np.pi
            assert abs(dth) < 1e-12, (body, pose['q'])
            assert got['origin'][:2] == pytest.approx(origin, abs=1e-12), (body, pose['q'])


def test_muscles_and_polynomial_paths(probe: dict, data: dict) -> None:
    m = data['muscles']
    names = m['names']
    assert list(probe['muscles']) == names
    for i, name in enumerate(names):
        got = probe['muscles'][name]
        assert got['class'] == 'DeGrooteFregly2016Muscle'
        assert got['path_class'] == 'FunctionBasedPath'
        f0 = m['max_isometric_force_one_leg'][i] * m['legs'] * m['strength_scale']
        assert got['max_isometric_force'] == pytest.approx(f0, rel=1e-15)
        assert got['optimal_fiber_length'] == m['optimal_fiber_length'][i]
        assert got['tendon_slack_length'] == m['tendon_slack_length'][i]
        assert got['pennation_angle_at_optimal'] == m['pennation_at_optimal'][i]
        assert got['max_contraction_velocity'] == m['max_contraction_velocity']
        assert got['fiber_damping'] == m['fiber_damping']
        assert (got['passive_fiber_strain_at_one_norm_force']
                == m['passive_fiber_strain_at_one_norm_force'])
        assert got['ignore_tendon_compliance'] is True
        assert got['activation_time_constant'] == m['activation_time_constant']
        assert got['deactivation_time_constant'] == m['deactivation_time_constant']

    for pose in probe['poses']:
        q = dict(zip(COORDS, pose['q']))
        qd = dict(zip(COORDS, pose['qdot']))
        for name in names:
            p = data['paths'][name]
            x = np.array([q[c] for c in p['coordinates']])
            length, grad = _poly(p['exponents'], p['coefficients'], x)
            assert pose['length'][name] == pytest.approx(length, abs=1e-12)
            expected = dict.fromkeys(COORDS, 0.0)
            expected.update(zip(p['coordinates'], -grad))
            arms = dict(zip(COORDS, pose['moment_arm'][name]))
            for c in COORDS:
                assert abs(arms[c] - expected[c]) < 1e-6, (name, c, arms[c], expected[c])
            speed = -sum(expected[c] * qd[c] for c in COORDS)
            assert pose['lengthening_speed'][name] == pytest.approx(speed, abs=1e-9)


def test_passive_joint_torques(probe: dict, data: dict) -> None:
    pj = data['passive_joints']
    for pose in probe['poses']:
        q = dict(zip(COORDS, pose['q']))
        qd = dict(zip(COORDS, pose['qdot']))
        for j in ('ankle_angle', 'knee_angle', 'hip_flexion'):
            k1, k2, k3, k4 = pj[j]['k']
            tau = pj['legs'] * (k1 * np.exp(k2 * (q[j] - pj[j]['theta_upper']))
                                + k3 * np.exp(k4 * (q[j] - pj[j]['theta_lower']))
                                - pj['damping'] * qd[j])
            assert pose['passive'][f'passive_{j}'] == pytest.approx(tau, rel=1e-12, abs=1e-12)


def test_contact_spheres_option(tmp_path: Path) -> None:
    # OpenSim is a test requirement: a missing install fails here, it never skips.
    assert importlib.util.find_spec('opensim') is not None, 'opensim is not installed'
    out = tmp_path / 'jumper_spheres.osim'
    _run('-m', 'nmt_ros.osim.export', '--out', str(out), '--with-contact-spheres')
    probe = json.loads(_run('-m', 'nmt_ros.osim.export', '--probe', str(out), '--poses',
                            '1').stdout)
    assert probe['forces']['contact_heel'] == 'SmoothSphereHalfSpaceForce'
    assert probe['forces']['contact_toe'] == 'SmoothSphereHalfSpaceForce'
