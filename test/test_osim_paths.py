"""Fitted musculotendon paths vs OpenSim's own GeometryPaths (gait10dof18musc).

OpenSim runs in a subprocess: it cannot share a process with casadi, which other tests load.
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
MUSCLES = ('gmax', 'ilpso', 'hams', 'bfsh', 'rf', 'vas', 'gas', 'sol', 'ta')
COORDINATES = {
    'gmax': ['hip_flexion'], 'ilpso': ['hip_flexion'], 'hams': ['hip_flexion', 'knee_angle'],
    'bfsh': ['knee_angle'], 'rf': ['hip_flexion', 'knee_angle'], 'vas': ['knee_angle'],
    'gas': ['knee_angle', 'ankle_angle'], 'sol': ['ankle_angle'], 'ta': ['ankle_angle'],
}

pytestmark = pytest.mark.opensim


@pytest.fixture(scope='module')
def report() -> dict:
    # OpenSim is a test requirement: a missing install fails here, it never skips.
    assert importlib.util.find_spec('opensim') is not None, 'opensim is not installed'
    proc = subprocess.run(
        [sys.executable, '-m', 'nmt_ros.osim.fit_paths', '--check', '--json', '-'],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode in (0, 1), proc.stderr
    return json.loads(proc.stdout)


def _evaluate(exponents: list, coefficients: list, q: np.ndarray) -> np.ndarray:
    """Independent evaluation of sum_k c_k prod_j q_j ** e_kj."""
    e = np.asarray(exponents, dtype=int)
    terms = np.prod(q[:, None, :] ** e[None, :, :], axis=2)
    return terms @ np.asarray(coefficients, dtype=float)


def test_data_file_structure() -> None:
    with open(DATA_FILE) as f:
        paths = yaml.safe_load(f)['paths']
    assert isinstance(paths['source'], str) and 'PolynomialPathFitter' in paths['source']
    for name in MUSCLES:
        p = paths[name]
        assert p['coordinates'] == COORDINATES[name]
        assert len(p['exponents']) == len(p['coefficients'])
        assert all(len(row) == len(p['coordinates']) for row in p['exponents'])
        assert all(isinstance(c, float) for c in p['coefficients'])


def test_lengths_meet_targets(report: dict) -> None:
    for name in MUSCLES:
        m = report['muscles'][name]
        assert m['coordinates'] == COORDINATES[name]
        assert m['length_rms_mm'] < 1.0, (name, m['length_rms_mm'])
        assert m['length_max_mm'] < 3.0, (name, m['length_max_mm'])
    assert report['pass']


def test_moment_arms_close_to_opensim(report: dict) -> None:
    # Not an acceptance target, but a regression guard: -dl/dq vs computeMomentArm.
    for name in MUSCLES:
        m = report['muscles'][name]
        assert m['moment_arm_rms_mm'] < 1.5, (name, m['moment_arm_rms_mm'])
        assert m['moment_arm_max_mm'] < 5.0, (name, m['moment_arm_max_mm'])


def test_grid_covers_the_jump(report: dict) -> None:
    ranges = {}
    for g in report['grids'].values():
        ranges.update(g['ranges_deg'])
    assert ranges == {'hip_flexion': [0.0, 110.0], 'knee_angle': [-120.0, 0.0],
                      'ankle_angle': [-30.0, 40.0]}


def test_data_file_polynomial_equals_opensim_function(report: dict) -> None:
    """OpenSim's MultivariatePolynomialFunction built from the data file == our convention."""
    with open(DATA_FILE) as f:
        paths = yaml.safe_load(f)['paths']
    for name in MUSCLES:
        m = report['muscles'][name]
        eq = m['opensim_equivalence_max_abs']
        assert max(eq.values()) <= 1e-12, (name, eq)
        q = np.asarray(m['opensim_samples']['q'])
        ours = _evaluate(paths[name]['exponents'], paths[name]['coefficients'], q)
        np.testing.assert_allclose(ours, m['opensim_samples']['length'], rtol=0, atol=1e-12)
