"""OpenSim's InverseDynamicsTool on a motion simulated by our model, and ``nmt ivd``.

The push-off of ``crosscheck_motion`` (our model, its own contact forces, 1 kHz) is written
as OpenSim files with ``nmt_ros.io.opensim_files``: coordinates .sto, the exact ground wrench
(.mot, point on the ground line at the centre of pressure + free torque) and an ExternalLoads
.xml applying it to the foot. OpenSim (subprocess) runs its InverseDynamicsTool on the model
``nmt export-osim`` writes, muscles excluded, passive joint torques kept, no coordinate
filtering: its joint moments must be the simulation's muscle torques.

Comparisons are over the ground-contact phase (t <= lift-off); the files go on 10 ms into
the flight because OpenSim's quintic spline has natural end conditions (3rd and 4th
derivatives zero), wrong in the last few samples of a trial that ends in motion.
"""
from __future__ import annotations

from pathlib import Path
import time

import crosscheck_motion as cm
import numpy as np
import pytest

from nmt_ros.cli.main import main as nmt_main
from nmt_ros.io import opensim_files as of
from nmt_ros.io.ivd_opensim import (
    JOINT_LABELS,
    RESIDUAL_LABELS,
    differentiate,
    inverse_dynamics_files,
    lowpass,
)
from nmt_ros.model.jumper import default_model
from nmt_ros.osim.modeldata import EXPORT_COORDINATES, opensim_coordinates_from_q

pytestmark = pytest.mark.opensim
JOINTS = ('ankle', 'knee', 'hip')


@pytest.fixture(scope='module')
def motion() -> cm.Motion:
    return cm.push_off()


@pytest.fixture(scope='module')
def files(motion: cm.Motion, tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp('id_crosscheck')
    load = of.ground_wrench_to_cop(motion.points, motion.forces)
    out = {
        'coordinates': of.write_table(d / 'coordinates.sto', motion.t, EXPORT_COORDINATES,
                                      opensim_coordinates_from_q(motion.q)),
        'grf': of.write_grf_mot(d / 'grf.mot', motion.t, *load),
        'model': cm.export_model(d / 'jumper.osim'),
        'load': load,
        'dir': d,
    }
    out['loads'] = of.write_external_loads_xml(d / 'external_loads.xml', out['grf'])
    start = time.perf_counter()
    cm.crosscheck('id', '--model', str(out['model']), '--coordinates', str(out['coordinates']),
                  '--external-loads', str(out['loads']), '--out-sto', str(d / 'opensim_id.sto'))
    out['opensim_s'] = time.perf_counter() - start
    out['opensim'] = of.read_table(d / 'opensim_id.sto')
    return out


def _contact(motion: cm.Motion) -> np.ndarray:
    return motion.t <= motion.liftoff_s


def test_motion_is_a_real_push_off(motion: cm.Motion) -> None:
    model = default_model()
    theta, = model.batch(model.joint_angles, motion.q)
    contact = _contact(motion)
    excursion = np.degrees(np.ptp(theta[contact], axis=0))
    fy = motion.forces[:, 1].sum(axis=1)
    ratio = fy.max() / model.p.body_weight
    print(f'\npush-off: {motion.t.size} samples at 1 kHz, lift-off {motion.liftoff_s:.4f} s, '
          f'built in {motion.build_s:.1f} s; joint excursions (contact) ankle/knee/hip '
          f'{excursion.round(1)} deg; peak vertical force {ratio:.2f} BW; peak |muscle '
          f'torque| {np.abs(motion.tau[contact]).max(axis=0).round(1)} N m')
    assert np.all(excursion > 20.0)
    assert ratio > 1.5
    assert fy[-1] < 1.0                      # the files end in the flight phase


def test_ground_load_is_the_contact_outputs(motion: cm.Motion, files: dict) -> None:
    """The .mot wrench (point on y = 0 + free torque) is exactly the model's outputs s."""
    model = default_model()
    s, = model.batch(model.contact_outputs, motion.q, motion.qd, motion.x0)
    foot_com = model.batch(model.positions, motion.q)[3][:, :, 0]
    _, load = of.read_grf_mot(files['grf'])
    wrench = np.column_stack([load.force[:, :2], load.moment_about(foot_com)])
    scale = np.abs(s).max(axis=0)
    err = (np.abs(wrench - s) / scale).max()
    cop = load.point[motion.t <= motion.liftoff_s - 0.02, 0]
    print(f'\nground wrench in the .mot vs the model outputs s: {err:.1e} relative; point of '
          f'application {cop.min():.3f}..{cop.max():.3f} m (centre of pressure)')
    assert err < 1e-12


def test_opensim_inverse_dynamics_gives_the_muscle_torques(motion: cm.Motion,
                                                           files: dict) -> None:
    table = files['opensim']
    np.testing.assert_allclose(table.time, motion.t, rtol=0, atol=1e-12)
    contact = _contact(motion)
    tau = table.columns(JOINT_LABELS)
    peak = np.abs(motion.tau[contact]).max(axis=0)
    err = np.abs(tau - motion.tau) / peak * 100.0
    worst = err[contact].max(axis=0)
    whole = err.max(axis=0)
    resid = np.abs(table.columns(RESIDUAL_LABELS['foot'])[contact]).max(axis=0)
    print(f'\nOpenSim ID vs muscle torques (contact phase), worst % of peak |tau| '
          f'ankle/knee/hip: {worst[0]:.2e} {worst[1]:.2e} {worst[2]:.2e} '
          f'(whole file incl. the natural-spline end: {whole.round(2)}); foot residuals '
          f'(moment, fx, fy) max {resid.round(4)}; OpenSim subprocess {files["opensim_s"]:.1f} s')
    assert np.all(worst < 1.0), worst
    # The motion is dynamically consistent with the applied wrench: no residual.
    assert resid[0] < 0.5 and resid[1] < 1.0 and resid[2] < 1.0, resid


def test_nmt_ivd_matches_opensim(motion: cm.Motion, files: dict, capsys) -> None:
    d = files['dir']
    start = time.perf_counter()
    rc = nmt_main(['ivd', '--coordinates', str(files['coordinates']), '--grf',
                   str(files['grf']), '--out', str(d / 'nmt_ivd.sto')])
    elapsed = time.perf_counter() - start
    assert rc == 0
    assert 'wrote' in capsys.readouterr().out
    ours = of.read_table(d / 'nmt_ivd.sto')
    opensim = files['opensim']
    assert ours.labels == opensim.labels     # same names and order as OpenSim's
    contact = _contact(motion)
    peak = np.abs(motion.tau[contact]).max(axis=0)
    tau = ours.columns(JOINT_LABELS)
    vs_opensim = (np.abs(tau - opensim.columns(JOINT_LABELS)) / peak).max(axis=0)
    vs_truth = (np.abs(tau - motion.tau)[contact] / peak).max(axis=0)
    resid_diff = np.abs(ours.columns(RESIDUAL_LABELS['foot'])
                        - opensim.columns(RESIDUAL_LABELS['foot'])).max()
    with capsys.disabled():
        print(f'\nnmt ivd ({elapsed:.2f} s) vs OpenSim ID, whole file, max |diff| / peak: '
              f'{vs_opensim.max():.1e}; residuals max |diff| {resid_diff:.1e}; '
              f'vs the muscle torques (contact): {vs_truth.max():.1e} relative')
    # Same spline (natural quintic), same dynamics: agreement to rounding.
    assert vs_opensim.max() < 1e-6
    assert resid_diff < 1e-4
    assert vs_truth.max() < 1e-4


def test_nmt_ivd_options(motion: cm.Motion, files: dict) -> None:
    contact = _contact(motion)
    peak = np.abs(motion.tau[contact]).max(axis=0)
    foot = inverse_dynamics_files(files['coordinates'], files['grf'])
    # Bottom-up (residual on the HAT): same torques on a consistent motion, tiny residuals
    # (the derivative errors, largest at lift-off, now pass through the whole chain).
    hat = inverse_dynamics_files(files['coordinates'], files['grf'], files['dir'] / 'hat.sto',
                                 residuals='hat')
    assert of.read_table(files['dir'] / 'hat.sto').labels == (JOINT_LABELS
                                                               + RESIDUAL_LABELS['hat'])
    diff = (np.abs(hat.tau - foot.tau)[contact] / peak).max()
    hat_resid = np.abs(hat.residual[contact]).max(axis=0)
    # Not-a-knot ends: no natural-spline error at the end of the file.
    nak = inverse_dynamics_files(files['coordinates'], files['grf'], spline_ends='not-a-knot')
    end_natural = (np.abs(foot.tau - motion.tau) / peak).max()
    end_nak = (np.abs(nak.tau - motion.tau) / peak).max()
    print(f'\nnmt ivd --residuals hat vs foot: {diff:.1e} relative, HAT residuals max '
          f'{hat_resid.round(4)}; whole-file error natural ends {end_natural:.1e}, '
          f'not-a-knot {end_nak:.1e}')
    assert diff < 1e-3
    assert np.all(hat_resid < 1.0)
    assert end_nak < 0.2 * end_natural
    # Coordinates in degrees give the same result.
    coords = opensim_coordinates_from_q(motion.q)
    rot = [EXPORT_COORDINATES.index(c) for c in ('foot_tilt', 'ankle_angle', 'knee_angle',
                                                  'hip_flexion')]
    coords[:, rot] = np.degrees(coords[:, rot])
    deg = of.write_table(files['dir'] / 'deg.sto', motion.t, EXPORT_COORDINATES, coords,
                         in_degrees=True)
    np.testing.assert_allclose(inverse_dynamics_files(deg, files['grf']).tau, foot.tau,
                               rtol=0, atol=1e-6 * peak.max())
    # The GRF at another rate (every 2nd coordinate sample kept, 500 Hz vs 1 kHz): the
    # wrench is interpolated (force and moment about the origin).
    half = files['load']
    sub = of.write_grf_mot(files['dir'] / 'grf_half.mot', motion.t[::2], half.force[::2],
                           half.point[::2], half.torque[::2])
    t_end = motion.t[::2][-1]
    keep = motion.t <= t_end
    short = of.write_table(files['dir'] / 'short.sto', motion.t[keep], EXPORT_COORDINATES,
                           opensim_coordinates_from_q(motion.q[keep]))
    inter = inverse_dynamics_files(short, sub)
    err = (np.abs(inter.tau - motion.tau[keep])[contact[keep]] / peak).max()
    print(f'GRF at 500 Hz, coordinates at 1 kHz: {err:.1e} relative')
    assert err < 0.01


def test_nmt_ivd_errors(files: dict, tmp_path: Path, capsys) -> None:
    table = of.read_table(files['coordinates'])
    of.write_table(tmp_path / 'bad.sto', table.time, table.labels[:4], table.data[:, :4])
    rc = nmt_main(['ivd', '--coordinates', str(tmp_path / 'bad.sto'), '--grf',
                   str(files['grf']), '--out', str(tmp_path / 'x.sto')])
    err = capsys.readouterr().err
    assert rc == 2
    assert 'knee_angle' in err and 'hip_flexion' in err and 'bad.sto' in err
    assert not (tmp_path / 'x.sto').exists()
    rc = nmt_main(['ivd', '--coordinates', str(files['coordinates']), '--grf',
                   str(files['coordinates']), '--out', str(tmp_path / 'x.sto')])
    assert rc == 2 and 'ground_force_vx' in capsys.readouterr().err


def test_nmt_ivd_lowpass_matches_opensim(motion: cm.Motion, files: dict) -> None:
    """``--lowpass`` is OpenSim's coordinate filter: same torques as its ID with the option."""
    d = files['dir']
    cm.crosscheck('id', '--model', str(files['model']), '--coordinates',
                  str(files['coordinates']), '--external-loads', str(files['loads']),
                  '--out-sto', str(d / 'opensim_id_lp.sto'), '--lowpass', '15')
    opensim = of.read_table(d / 'opensim_id_lp.sto')
    assert nmt_main(['ivd', '--coordinates', str(files['coordinates']), '--grf',
                     str(files['grf']), '--out', str(d / 'nmt_ivd_lp.sto'),
                     '--lowpass', '15']) == 0
    ours = of.read_table(d / 'nmt_ivd_lp.sto')
    peak = np.abs(opensim.columns(JOINT_LABELS)).max(axis=0)
    diff = (np.abs(ours.columns(JOINT_LABELS) - opensim.columns(JOINT_LABELS)) / peak).max()
    changed = (np.abs(ours.columns(JOINT_LABELS) - motion.tau) / peak).max()
    print(f'\nnmt ivd --lowpass 15 vs OpenSim ID with a 15 Hz cut-off: {diff:.1e} relative '
          f'(the filter itself changes the torques by up to {changed:.0%} of peak)')
    assert diff < 1e-6
    assert changed > 0.05                     # the filter did act


def test_lowpass_is_zero_lag() -> None:
    t = np.arange(0.0, 1.0, 1e-3)
    slow = np.sin(2 * np.pi * 2.0 * t + 0.3)
    fast = 0.1 * np.sin(2 * np.pi * 150.0 * t)
    y = lowpass(t, np.column_stack([slow + fast, slow]), 20.0)
    inner = slice(40, -40)
    assert np.abs(y[inner, 0] - slow[inner]).max() < 2e-3    # noise gone, no lag
    assert np.abs(y[:, 1] - slow).max() < 2e-3
    # OpenSim's padding reflects about the end points: the end samples are kept as they are.
    np.testing.assert_allclose(y[[0, -1], 0], (slow + fast)[[0, -1]], atol=1e-12)
    # Uneven sampling is resampled, filtered and brought back.
    tu = np.sort(np.random.default_rng(0).uniform(0.0, 1.0, 700))
    yu = lowpass(tu, np.sin(2 * np.pi * 2.0 * tu + 0.3), 20.0)
    assert np.abs(yu - np.sin(2 * np.pi * 2.0 * tu + 0.3)).max() < 5e-3
    x, xd, xdd = differentiate(t, slow[:, None], ends='not-a-knot')
    w = 2 * np.pi * 2.0
    assert np.abs(xdd[:, 0] + w * w * slow).max() < 1e-6 * w * w
    with pytest.raises(ValueError, match='Nyquist'):
        lowpass(t, slow[:, None], 600.0)
