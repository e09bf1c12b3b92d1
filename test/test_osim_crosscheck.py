"""Smoke test of the OpenSim cross-check evaluators (``nmt_ros.osim.crosscheck``).

OpenSim runs in subprocesses only; the expected values are computed here by hand (statics,
rigid-tendon geometry) from the data file, with numpy.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DATA_FILE = REPO / 'nmt_ros' / 'model' / 'data' / 'jumper.yaml'
JOINTS = ('ankle_angle', 'knee_angle', 'hip_flexion')

pytestmark = pytest.mark.opensim


@pytest.fixture(scope='module')
def data() -> dict:
    # OpenSim is a test requirement: a missing install fails here, it never skips.
    assert importlib.util.find_spec('opensim') is not None, 'opensim is not installed'
    with open(DATA_FILE) as f:
        return yaml.safe_load(f)


def _crosscheck(*args: str) -> None:
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.osim.crosscheck', *args], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def _rot(th: float) -> np.ndarray:
    return np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])


def _cross(r: np.ndarray, f: np.ndarray) -> float:
    return float(r[0] * f[1] - r[1] * f[0])


def _static_id(q: np.ndarray, force: np.ndarray, point: np.ndarray, data: dict) -> dict:
    """Generalized forces that hold the model still: tau = -(gravity + external + passive)."""
    th1, th2, th3, th4, r1, r2 = q
    seg = data['segments']
    g = data['gravity']['value']
    ankle = np.array([r1, r2])
    knee = ankle - _rot(th2) @ np.array(seg['shank']['distal_joint'])
    hip = knee - _rot(th3) @ np.array(seg['thigh']['distal_joint'])
    frames = {'foot': (th1, ankle), 'shank': (th2, knee), 'thigh': (th3, hip), 'hat': (th4, hip)}
    com = {b: o + _rot(th) @ np.array(seg[b]['com']) for b, (th, o) in frames.items()}
    weight = {b: np.array([0.0, -seg[b]['mass'] * g]) for b in frames}

    def moment(bodies: tuple[str, ...], pivot: np.ndarray) -> float:
        return sum(_cross(com[b] - pivot, weight[b]) for b in bodies)

    q_gen = {
        'foot_tilt': moment(tuple(frames), ankle) + _cross(point - ankle, force),
        'foot_tx': force[0],
        'foot_ty': force[1] + sum(w[1] for w in weight.values()),
        # Joint axes are -z (child turns by minus the coordinate relative to its parent).
        'ankle_angle': -moment(('shank', 'thigh', 'hat'), ankle),
        'knee_angle': -moment(('thigh', 'hat'), knee),
        'hip_flexion': -moment(('hat',), hip),
    }
    pj = data['passive_joints']
    angles = {'ankle_angle': th1 - th2, 'knee_angle': th2 - th3, 'hip_flexion': th3 - th4}
    for j in JOINTS:
        k1, k2, k3, k4 = pj[j]['k']
        q_gen[j] += pj['legs'] * (k1 * np.exp(k2 * (angles[j] - pj[j]['theta_upper']))
                                  + k3 * np.exp(k4 * (angles[j] - pj[j]['theta_lower'])))
    return {c: -v for c, v in q_gen.items()}


@pytest.mark.parametrize('case', ['upright', 'squat'])
def test_inverse_dynamics_static(case: str, data: dict, tmp_path: Path) -> None:
    seg = data['segments']
    mass = sum(seg[b]['mass'] for b in ('foot', 'shank', 'thigh', 'hat'))
    weight = mass * data['gravity']['value']
    if case == 'upright':
        # All segments upright, the body weight pushing up at the ankle centre.
        q = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.057])
        force, point = np.array([0.0, weight]), np.array([0.0, 0.057])
    else:
        # SCONE's squat angles (ankle 25, knee -70, hip 80 deg), a slanted force at the heel.
        th1 = 0.05
        th2 = th1 - np.radians(25.0)
        th3 = th2 + np.radians(70.0)
        th4 = th3 - np.radians(80.0)
        q = np.array([th1, th2, th3, th4, 0.1, 0.06])
        force, point = np.array([35.0, 0.9 * weight]), np.array([0.08, 0.0])
    n = 11
    np.savez(tmp_path / 'in.npz', t=np.linspace(0.0, 1.0, n), q=np.tile(q, (n, 1)),
             force=np.tile(force, (n, 1)), point=np.tile(point, (n, 1)))
    _crosscheck('write-inputs', '--in', str(tmp_path / 'in.npz'), '--dir', str(tmp_path))
    _crosscheck('id', '--coordinates', str(tmp_path / 'coordinates.sto'),
                '--external-loads', str(tmp_path / 'external_loads.xml'),
                '--out-sto', str(tmp_path / 'id.sto'), '--out-npz', str(tmp_path / 'id.npz'))
    assert (tmp_path / 'id.sto').is_file()
    out = np.load(tmp_path / 'id.npz')
    labels = list(out['labels'])
    expected = _static_id(q, force, point, data)
    for coord, value in expected.items():
        suffix = '_force' if coord in ('foot_tx', 'foot_ty') else '_moment'
        got = out['values'][:, labels.index(coord + suffix)]
        np.testing.assert_allclose(got, value, rtol=0, atol=1e-6, err_msg=coord)
    if case == 'upright':
        hat = seg['hat']
        # The HAT's COM lies behind the hip: holding it takes a flexion moment of
        # m g |x_com| (plus a passive torque of ~5e-4 N m).
        hip = -hat['com'][0] * hat['mass'] * data['gravity']['value']
        assert hip > 0
        assert expected['hip_flexion'] == pytest.approx(hip, abs=2e-3)


def _poly(exponents: list, coefficients: list, x: np.ndarray) -> tuple[float, np.ndarray]:
    e = np.asarray(exponents, dtype=int)
    c = np.asarray(coefficients, dtype=float)
    value = float(np.prod(x[None, :] ** e, axis=1) @ c)
    grad = np.zeros(len(x))
    for j in range(len(x)):
        d = e.copy()
        d[:, j] = np.maximum(e[:, j] - 1, 0)
        grad[j] = float((e[:, j] * np.prod(x[None, :] ** d, axis=1)) @ c)
    return value, grad


def test_muscles(data: dict, tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 6
    # Poses within the jump's range: joint angles drawn, segment angles built from them.
    ankle = rng.uniform(np.radians(-30), np.radians(40), n)
    knee = rng.uniform(np.radians(-120), 0.0, n)
    hip = rng.uniform(0.0, np.radians(110), n)
    th1 = rng.uniform(-0.2, 0.2, n)
    q = np.column_stack([th1, th1 - ankle, th1 - ankle - knee, th1 - ankle - knee - hip,
                         rng.uniform(-0.1, 0.1, n), rng.uniform(0.0, 0.2, n)])
    qd = rng.uniform(-2.0, 2.0, (n, 6))
    a = rng.uniform(0.01, 1.0, (n, 9))
    np.savez(tmp_path / 'in.npz', q=q, qd=qd, a=a)
    _crosscheck('muscles', '--in', str(tmp_path / 'in.npz'), '--out', str(tmp_path / 'out.npz'))
    out = np.load(tmp_path / 'out.npz')
    assert list(out['muscles']) == data['muscles']['names']
    assert list(out['coordinates']) == list(JOINTS)

    m = data['muscles']
    f0 = np.array(m['max_isometric_force_one_leg']) * m['legs'] * m['strength_scale']
    l_opt = np.array(m['optimal_fiber_length'])
    l_slack = np.array(m['tendon_slack_length'])
    alpha0 = np.array(m['pennation_at_optimal'])
    theta = np.column_stack([q[:, 0] - q[:, 1], q[:, 1] - q[:, 2], q[:, 2] - q[:, 3]])
    theta_dot = np.column_stack([qd[:, 0] - qd[:, 1], qd[:, 1] - qd[:, 2], qd[:, 2] - qd[:, 3]])
    for i in range(n):
        values = dict(zip(JOINTS, theta[i]))
        for k, name in enumerate(m['names']):
            p = data['paths'][name]
            x = np.array([values[c] for c in p['coordinates']])
            l_mt, grad = _poly(p['exponents'], p['coefficients'], x)
            arms = np.zeros(3)
            for c, dl in zip(p['coordinates'], grad):
                arms[JOINTS.index(c)] = -dl
            assert out['musculotendon_length'][i, k] == pytest.approx(l_mt, abs=1e-12)
            np.testing.assert_allclose(out['moment_arms'][i, k], arms, rtol=0, atol=1e-9)
            assert out['lengthening_speed'][i, k] == pytest.approx(
                -arms @ theta_dot[i], abs=1e-9)
            # Rigid tendon, constant-thickness pennation.
            h = l_opt[k] * np.sin(alpha0[k])
            l_f = np.hypot(l_mt - l_slack[k], h)
            assert out['fiber_length'][i, k] == pytest.approx(l_f, rel=1e-9)
            assert np.sin(out['pennation_angle'][i, k]) == pytest.approx(h / l_f, abs=1e-9)
    # Force bookkeeping.
    np.testing.assert_allclose(out['active_fiber_force'],
                               f0 * a * out['active_force_length'] * out['force_velocity'],
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out['elastic_fiber_force'], f0 * out['passive_force_length'],
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        out['fiber_force'], out['active_fiber_force'] + out['passive_fiber_force'],
        rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out['tendon_force'],
                               out['fiber_force'] * np.cos(out['pennation_angle']),
                               rtol=1e-9, atol=1e-9)
    v_norm = out['fiber_velocity'] / (m['max_contraction_velocity'] * l_opt)
    np.testing.assert_allclose(out['damping_force'], f0 * m['fiber_damping'] * v_norm,
                               rtol=1e-9, atol=1e-9)
