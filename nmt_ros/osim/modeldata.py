"""Shared helpers of the OpenSim bridge that need neither OpenSim nor casadi.

The model data file is read here with PyYAML directly (``nmt_ros.model`` imports casadi,
which must not share a process with ``opensim``). Polynomial paths follow the data file's
convention::

    l_MT(q) = sum_k c_k * prod_j q_j ** e_kj      (q in rad, in the path's coordinate order)

and moment arms are ``r_j = -d l_MT / d q_j``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

REPO_ROOT = Path(__file__).resolve().parents[2]
DATA_FILE = REPO_ROOT / 'nmt_ros' / 'model' / 'data' / 'jumper.yaml'
OPENSIM_DATA_DIR = REPO_ROOT / 'data' / 'opensim'
SOURCE_MODEL = OPENSIM_DATA_DIR / 'gait10dof18musc.osim'

# Our muscle names and the right-leg OpenSim names in gait10dof18musc (order fixed).
MUSCLES = ('gmax', 'ilpso', 'hams', 'bfsh', 'rf', 'vas', 'gas', 'sol', 'ta')
OPENSIM_MUSCLES = ('glut_max', 'iliopsoas', 'hamstrings', 'bifemsh', 'rect_fem', 'vasti',
                   'gastroc', 'soleus', 'tib_ant')
# Coordinates each muscle spans, in the order used by its polynomial.
MUSCLE_COORDINATES = {
    'gmax': ('hip_flexion',),
    'ilpso': ('hip_flexion',),
    'hams': ('hip_flexion', 'knee_angle'),
    'bfsh': ('knee_angle',),
    'rf': ('hip_flexion', 'knee_angle'),
    'vas': ('knee_angle',),
    'gas': ('knee_angle', 'ankle_angle'),
    'sol': ('ankle_angle',),
    'ta': ('ankle_angle',),
}
# Joint coordinates of the exported model (OpenSim gait10dof18musc names and signs).
JOINT_COORDINATES = ('ankle_angle', 'knee_angle', 'hip_flexion')
# All coordinates of the exported model, in the order used by the cross-check files.
EXPORT_COORDINATES = ('foot_tilt', 'foot_tx', 'foot_ty', 'ankle_angle', 'knee_angle',
                      'hip_flexion')


def load_model_data(path: str | Path | None = None) -> dict:
    """The model data file (jumper.yaml) as a plain dictionary."""
    with open(Path(path) if path is not None else DATA_FILE) as f:
        return yaml.safe_load(f)


def muscle_paths(data: dict) -> dict[str, tuple[tuple[str, ...], np.ndarray, np.ndarray]]:
    """name -> (coordinates, exponents [n_terms, n_coords] int, coefficients [n_terms])."""
    paths = data.get('paths') or {}
    out = {}
    for name in MUSCLES:
        if name not in paths:
            raise ValueError(f'the model data file has no fitted path for {name!r}; run '
                             '`python -m nmt_ros.osim.fit_paths`')
        p = paths[name]
        coords = tuple(p['coordinates'])
        exps = np.asarray(p['exponents'], dtype=int).reshape(-1, len(coords))
        out[name] = (coords, exps, np.asarray(p['coefficients'], dtype=float))
    return out


def _monomials(exponents: np.ndarray, q2: np.ndarray, d: int | None = None) -> np.ndarray:
    """prod_j q_j ** e_kj for q2 [n, dim] -> [n, n_terms]; with ``d``, its derivative in q_d."""
    e = exponents
    terms = np.ones((q2.shape[0], e.shape[0]))
    for j in range(e.shape[1]):
        if j == d:
            power = np.maximum(e[:, j] - 1, 0)
            terms *= e[None, :, j] * q2[:, j:j + 1] ** power[None, :]
        else:
            terms *= q2[:, j:j + 1] ** e[None, :, j]
    return terms


def polynomial_value(exponents: np.ndarray, coefficients: np.ndarray,
                     q: np.ndarray) -> np.ndarray:
    """sum_k c_k prod_j q_j ** e_kj for q [n, dim] (or [dim]); returns [n] (or scalar)."""
    q = np.asarray(q, dtype=float)
    e = np.asarray(exponents, dtype=int)
    value = _monomials(e, np.atleast_2d(q)) @ np.asarray(coefficients, dtype=float)
    return value[0] if q.ndim == 1 else value


def polynomial_gradient(exponents: np.ndarray, coefficients: np.ndarray,
                        q: np.ndarray) -> np.ndarray:
    """d l / d q_j for q [n, dim] (or [dim]); returns [n, dim] (or [dim])."""
    q = np.asarray(q, dtype=float)
    q2 = np.atleast_2d(q)
    e = np.asarray(exponents, dtype=int)
    c = np.asarray(coefficients, dtype=float)
    grad = np.zeros((q2.shape[0], e.shape[1]))
    for i in range(e.shape[1]):
        grad[:, i] = _monomials(e, q2, i) @ c
    return grad[0] if q.ndim == 1 else grad


def opensim_exponents(dimension: int, order: int) -> list[tuple[int, ...]]:
    """Exponent tuples of OpenSim's MultivariatePolynomialFunction coefficients, in order.

    OpenSim stores the terms of total degree <= order with the exponent of the first
    coordinate varying slowest and that of the last fastest, each ascending from 0 (for 3
    coordinates, order 2: 000, 001, 002, 010, 011, 020, 100, 101, 110, 200).
    """
    def rec(dim: int, budget: int) -> list[tuple[int, ...]]:
        if dim == 0:
            return [()]
        return [(e,) + rest for e in range(budget + 1) for rest in rec(dim - 1, budget - e)]
    return rec(dimension, order)


def yaml_float(x: float) -> str:
    """Shortest round-trip repr of x that YAML 1.1 (PyYAML) still reads as a float."""
    r = repr(float(x))
    if 'e' in r:
        mantissa, exp = r.split('e')
        if '.' not in mantissa:
            mantissa += '.0'
        if exp[0] not in '+-':
            exp = '+' + exp
        r = f'{mantissa}e{exp}'
    return r


def opensim_coordinates_from_q(q: np.ndarray) -> np.ndarray:
    """Our q = [th1, th2, th3, th4, r1, r2] [n, 6] -> exported-model coordinates [n, 6].

    Output order is EXPORT_COORDINATES: foot_tilt = th1, foot_tx = r1, foot_ty = r2,
    ankle_angle = th1 - th2, knee_angle = th2 - th3, hip_flexion = th3 - th4. The map is
    linear, so the same function converts speeds.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    th1, th2, th3, th4, r1, r2 = (q[:, i] for i in range(6))
    return np.column_stack([th1, r1, r2, th1 - th2, th2 - th3, th3 - th4])
