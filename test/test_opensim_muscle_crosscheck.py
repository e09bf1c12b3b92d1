"""OpenSim's muscles (exported model, ``crosscheck muscles`` in a subprocess) against ours.

(b) Musculotendon forces for the same states and activations: 50 states along the simulated
push-off of ``crosscheck_motion`` and 50 random states within the jump's range of motion
with nonzero speeds, random activations in [0, 1]; within 1 % of F0, with the fibre length,
pennation and force-velocity multiplier exercised over a wide range (checked here too).
(c) Moment arms ``computeMomentArm`` and OpenSim's -dl/dq (central differences of its
musculotendon lengths) against ``model.moment_arms`` within 1 mm on a grid over the jump's
range of motion: hip 0..110 deg flexion, knee 0..-120 deg, ankle -30..40 deg.
"""
from __future__ import annotations

import json
from pathlib import Path
import time

import crosscheck_motion as cm
import numpy as np
import pytest

from nmt_ros.model.jumper import default_model

pytestmark = pytest.mark.opensim
RANGES_DEG = {'ankle_angle': (-30.0, 40.0), 'knee_angle': (-120.0, 0.0),
              'hip_flexion': (0.0, 110.0)}


def _q_from_joints(th1: np.ndarray, joints: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Our q from the foot angle [n], joint angles [n, 3] (ankle, knee, hip) and r [n, 2]."""
    th2 = th1 - joints[:, 0]
    th3 = th2 - joints[:, 1]
    return np.column_stack([th1, th2, th3, th3 - joints[:, 2], r])


def _osim_muscles(tmp: Path, q: np.ndarray, qd: np.ndarray, a: np.ndarray,
                  name: str) -> tuple[dict, float]:
    np.savez(tmp / f'{name}_in.npz', q=q, qd=qd, a=a)
    start = time.perf_counter()
    cm.crosscheck('muscles', '--in', str(tmp / f'{name}_in.npz'), '--out',
                  str(tmp / f'{name}_out.npz'))
    elapsed = time.perf_counter() - start
    with np.load(tmp / f'{name}_out.npz') as out:
        return {k: out[k] for k in out.files}, elapsed


def test_muscle_forces_match_opensim(tmp_path: Path) -> None:
    model = default_model()
    names = list(model.p.muscles.names)
    motion = cm.push_off()
    rng = np.random.default_rng(2007)
    contact = np.flatnonzero(motion.t <= motion.liftoff_s)
    along = contact[np.linspace(0, contact.size - 1, 50).astype(int)]
    n = 50
    lo, hi = np.radians(np.array(list(RANGES_DEG.values()))).T
    joints = rng.uniform(lo, hi, (n, 3))
    q_rand = _q_from_joints(rng.uniform(-0.3, 0.3, n), joints,
                            np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(0, 0.3, n)]))
    qd_rand = rng.uniform(-8.0, 8.0, (n, 6))          # rad/s and m/s
    q = np.vstack([motion.q[along], q_rand])
    qd = np.vstack([motion.qd[along], qd_rand])
    a = rng.uniform(0.0, 1.0, (q.shape[0], 9))
    out, elapsed = _osim_muscles(tmp_path, q, qd, a, 'forces')
    assert list(out['muscles']) == names

    tau, f = model.batch(model.muscle_torques, q, qd, a)
    f0 = model.p.muscles.f0
    err = np.abs(out['tendon_force'] - f) / f0 * 100.0             # % of F0
    worst = err.max(axis=0)
    # The joint torques those forces make, with OpenSim's moment arms: tau = C f.
    tau_osim = np.einsum('nmj,nm->nj', out['moment_arms'], out['tendon_force'])
    tau_err = np.abs(tau_osim - tau).max(axis=0)
    # Fibre kinematics and multipliers: the same states, not just the same products.
    theta, = model.batch(model.joint_angles, q)
    theta_dot, = model.batch(model.joint_angles, qd)
    l_mt, = model.batch(model.musculotendon_lengths, theta)
    v_mt, = model.batch(model.musculotendon_velocities, theta, theta_dot)
    l_m, cos_alpha, v_m = model.batch(model.fiber_state, l_mt, v_mt)
    l_norm = l_m / model.p.muscles.l_opt
    v_norm = v_m / (model.p.muscles.v_max * model.p.muscles.l_opt)
    fiber_err_mm = np.abs(out['fiber_length'] - l_m).max() * 1e3
    pennation_err = np.abs(np.cos(out['pennation_angle']) - cos_alpha).max()
    speed_err = np.abs(out['fiber_velocity'] - v_m).max()
    fv = out['force_velocity']
    print(f'\nmuscle forces, OpenSim vs ours ({q.shape[0]} states, OpenSim subprocess '
          f'{elapsed:.1f} s), worst % of F0: '
          + ', '.join(f'{m} {e:.1e}' for m, e in zip(names, worst)))
    print(f'  fibre length {fiber_err_mm:.1e} mm, cos(pennation) {pennation_err:.1e}, fibre '
          f'speed {speed_err:.1e} m/s; joint torques C f {tau_err.max():.1e} N m; exercised: '
          f'l~ {l_norm.min():.2f}..{l_norm.max():.2f}, v~ {v_norm.min():.2f}..'
          f'{v_norm.max():.2f}, f_V {fv.min():.2f}..{fv.max():.2f}, pennation up to '
          f'{np.degrees(out["pennation_angle"]).max():.0f} deg')
    assert np.all(worst < 1.0), dict(zip(names, worst))
    assert fiber_err_mm < 1e-3 and pennation_err < 1e-6 and speed_err < 1e-6
    assert tau_err.max() < 0.01 * np.abs(tau).max()
    # The comparison covered the curves, not one corner of them.
    assert l_norm.min() < 0.6 and l_norm.max() > 1.3
    assert v_norm.min() < -0.5 and v_norm.max() > 0.5
    assert fv.min() < 0.3 and fv.max() > 1.4
    assert np.degrees(out['pennation_angle']).max() > 20.0
    assert out['passive_force_length'].max() > 0.1


def test_moment_arms_match_opensim(tmp_path: Path) -> None:
    model = default_model()
    names = list(model.p.muscles.names)
    k = 11
    axes = [np.radians(np.linspace(lo, hi, k)) for lo, hi in RANGES_DEG.values()]
    joints = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    n = joints.shape[0]
    h = 1e-5
    # Each pose, then each joint angle moved by +h and -h (the foot angle stays 0).
    shifts = np.vstack([np.zeros(3), np.eye(3) * h, -np.eye(3) * h])        # [7, 3]
    all_joints = (joints[None, :, :] + shifts[:, None, :]).reshape(-1, 3)
    q = _q_from_joints(np.zeros(all_joints.shape[0]), all_joints,
                       np.zeros((all_joints.shape[0], 2)))
    qd = np.zeros_like(q)
    a = np.full((q.shape[0], 9), 0.5)
    out, elapsed = _osim_muscles(tmp_path, q, qd, a, 'arms')
    arms_osim = out['moment_arms'][:n]                                       # [n, 9, 3]
    length = out['musculotendon_length'].reshape(7, n, 9)
    fd = -(length[1:4] - length[4:7]) / (2 * h)                            # [3, n, 9]
    arms_fd = np.transpose(fd, (1, 2, 0))
    ours, = model.batch(model.moment_arms, joints)                           # [n, 9, 3]
    l_ours, = model.batch(model.musculotendon_lengths, joints)
    err = np.abs(arms_osim - ours).max(axis=(0, 2)) * 1e3                    # mm per muscle
    err_fd = np.abs(arms_fd - ours).max(axis=(0, 2)) * 1e3
    err_len = np.abs(length[0] - l_ours).max() * 1e3
    print(f'\nmoment arms on a {k}^3 grid of the jump range (OpenSim subprocess '
          f'{elapsed:.1f} s), worst |OpenSim - ours| mm: '
          + ', '.join(f'{m} {e:.1e}' for m, e in zip(names, err)))
    print(f'  OpenSim -dl/dq (central differences) vs ours: max {err_fd.max():.1e} mm; '
          f'lengths {err_len:.1e} mm; peak |moment arm| '
          f'{np.abs(ours).max() * 1e3:.0f} mm')
    assert np.all(err < 1.0), dict(zip(names, err))
    assert np.all(err_fd < 1.0), dict(zip(names, err_fd))
    assert err_len < 1e-6
    # Moment arms about coordinates a muscle does not span are zero on both sides.
    spans = np.abs(ours).max(axis=0) > 0
    assert np.all(np.abs(arms_osim).max(axis=0)[~spans] == 0.0)
    assert json.dumps(spans.sum(axis=1).tolist()) == '[1, 1, 2, 1, 2, 1, 2, 1, 1]'
