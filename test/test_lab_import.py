"""nmt import-lab: C3D / TRC / IK routes against synthetic ground truth and each other.

The synthetic trial is built here from known segment angles (two legs that differ), ankle
paths and plate wrenches, in a lab frame with z up and y forward (not OpenSim's), written as a
C3D (ezc3d: markers in mm, two type-2 plates, one rotated, analogs at 5x the marker rate) and
as TRC + GRF .mot. The expected angles are the mean of the known legs' angles; the expected
wrench is computed here with numpy cross products from the known forces, points and torques.
"""
from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from nmt_ros.io.c3d import Plate, plate_channels, write_c3d
from nmt_ros.io.force_plates import read_plates
from nmt_ros.io.marker_map import load_marker_map
from nmt_ros.io.opensim_files import GroundLoad, write_table
from nmt_ros.io.trc import read_trc, write_trc
from nmt_ros.io.trial_bag import read_observations
from nmt_ros.model.parameters import load_parameters
from nmt_ros.model.subject import scale_factors, scale_parameters, subject_from_mass_height
from nmt_ros.study import lab_recording as recording
from nmt_ros.study.sagittal import SagittalFrame

REPO = Path(__file__).resolve().parents[1]
REAL = REPO / 'data' / 'real' / 'opencap_dropjump'
FRAME = SagittalFrame('+y', '+z')          # lab: y forward, z up -> sagittal right = +x
RATE, RATIO = 200.0, 5
ZERO = {'r': {'foot': 2.0, 'shank': 88.0, 'thigh': 91.0},
        'l': {'foot': -3.0, 'shank': 90.5, 'thigh': 87.0}, 'hat': 97.0}
OFFSET = {'r': [0.012, -0.016], 'l': [0.007, -0.018]}
NAMES = {'r': {'hip': 'RHJC', 'knee': 'RKNE', 'ankle': 'RANK', 'heel': 'RHEE', 'toe': 'RTOE'},
         'l': {'hip': 'LHJC', 'knee': 'LKNE', 'ankle': 'LANK', 'heel': 'LHEE', 'toe': 'LTOE'}}


def _map() -> dict:
    return {'format': 'nmt_ros marker map v1', 'name': 'test',
            'frame': {'forward': '+y', 'up': '+z'}, 'legs': NAMES,
            'trunk': {'hip': ['RHJC', 'LHJC'], 'shoulder': ['RSHO', 'LSHO']},
            'zero_deg': ZERO, 'ankle_offset_m': OFFSET}


def _dir(a: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(a), np.sin(a)])


def _rot(th: np.ndarray, v: list[float]) -> np.ndarray:
    return np.column_stack([np.cos(th) * v[0] - np.sin(th) * v[1],
                            np.sin(th) * v[0] + np.cos(th) * v[1]])


def _lab(sag: np.ndarray, lateral: float) -> np.ndarray:
    """Sagittal (x fwd, y up) + lateral (toward the right) -> lab [n, 3] (x right, y fwd, z up)."""
    return np.column_stack([np.full(sag.shape[0], lateral), sag[:, 0], sag[:, 1]])


def synthetic_trial(n: int = 120) -> dict:
    t = 0.5 + np.arange(n) / RATE                       # the recording's own time base
    ta = 0.5 + np.arange(n * RATIO) / (RATE * RATIO)
    ta = ta[ta <= t[-1] + 1e-12]
    w = 2 * np.pi * 1.5
    th = {}
    th['r'] = np.column_stack([0.2 * np.sin(w * t), -0.4 + 0.3 * np.sin(w * t + 0.3),
                               0.6 + 0.2 * np.cos(w * t)])
    th['l'] = th['r'] + np.array([0.05, -0.03, 0.02])
    hat = -0.5 + 0.2 * np.sin(w * t + 1.0)
    markers, ankle = {}, {}
    for s, lat in (('r', 0.1), ('l', -0.1)):
        a = np.column_stack([0.3 + 0.05 * np.sin(w * t), 0.08 + 0.02 * np.cos(w * t)])
        a = a + (0.01 if s == 'l' else 0.0)
        ankle[s] = a
        z = {k: np.deg2rad(v) for k, v in ZERO[s].items()}
        ank_m = a - _rot(th[s][:, 1], OFFSET[s])
        knee = ank_m + 0.45 * _dir(th[s][:, 1] + z['shank'])
        hip = knee + 0.42 * _dir(th[s][:, 2] + z['thigh'])
        heel = a + _rot(th[s][:, 0], [-0.06, -0.05])
        toe = heel + 0.24 * _dir(th[s][:, 0] + z['foot'])
        for k, p in (('ankle', ank_m), ('knee', knee), ('hip', hip), ('heel', heel),
                     ('toe', toe)):
            markers[NAMES[s][k]] = _lab(p, lat + (0.02 if k in ('knee', 'ankle') else 0.0))
    hip_mid = 0.5 * (markers['RHJC'] + markers['LHJC'])
    sho = hip_mid[:, 1:] + 0.5 * _dir(hat + np.deg2rad(ZERO['hat']))
    markers['RSHO'] = _lab(sho, 0.18)
    markers['LSHO'] = _lab(sho, -0.18)
    names = list(markers)
    xyz = np.stack([markers[k] for k in names], axis=1)
    # plates: lab-frame force, point, free torque at the analog rate
    rng = np.random.default_rng(3)
    na = ta.size
    loads = []
    for k in range(2):
        f = np.column_stack([rng.normal(5, 2, na), 40 * np.sin(3 * ta + k), 500 + 200 * np.sin(
            5 * ta + k)])
        p = np.column_stack([(0.15 if k == 0 else -0.15) + 0.01 * np.sin(ta),
                             0.35 + 0.05 * np.cos(2 * ta), np.zeros(na)])
        tq = np.column_stack([np.zeros(na), np.zeros(na), 3 * np.sin(7 * ta)])
        loads.append((f, p, tq))
    return {'t': t, 'ta': ta, 'names': names, 'xyz': xyz, 'theta': th, 'hat': hat,
            'ankle': ankle, 'loads': loads}


def expected(trial: dict, subject: object) -> tuple[np.ndarray, np.ndarray]:
    th = 0.5 * (trial['theta']['r'] + trial['theta']['l'])
    angles = np.column_stack([th, trial['hat']])
    params = scale_parameters(load_parameters(), scale_factors(subject))
    com_foot = params.segments['foot'].com
    # the same smooth signals at the analog times (analytic, not interpolated)
    w = 2 * np.pi * 1.5
    ta = trial['ta']
    foot = 0.5 * (0.2 * np.sin(w * ta) + 0.2 * np.sin(w * ta) + 0.05)
    ank = np.column_stack([0.3 + 0.05 * np.sin(w * ta), 0.08 + 0.02 * np.cos(w * ta)]) + 0.005
    com = ank + _rot(foot, com_foot)
    c3 = np.column_stack([np.zeros(ta.size), com[:, 0], com[:, 1]])   # lab point (x lateral)
    wrench = np.zeros((ta.size, 3))
    for f, p, tq in trial['loads']:
        wrench[:, 0] += f[:, 1]
        wrench[:, 1] += f[:, 2]
        wrench[:, 2] += (tq + np.cross(p - c3, f))[:, 0]           # about +x = right
    return angles, wrench


def corners(cx: float, cy: float, rotated: bool) -> np.ndarray:
    c = np.array([[cx + 0.2, cy + 0.3, 0], [cx - 0.2, cy + 0.3, 0], [cx - 0.2, cy - 0.3, 0],
                  [cx + 0.2, cy - 0.3, 0]])
    return c[[2, 3, 0, 1]] if rotated else c


@pytest.fixture(scope='module')
def trial() -> dict:
    return synthetic_trial()


@pytest.fixture(scope='module')
def subject() -> object:
    return subject_from_mass_height(70.0, 1.75, 'synthetic')


def _write_c3d(path: Path, trial: dict, drop_channel: bool = False) -> Path:
    plates = []
    for k, (f, p, tq) in enumerate(trial['loads']):
        c = corners(0.15 if k == 0 else -0.15, 0.35, rotated=k == 1)
        origin = np.array([0.001, -0.002, -0.04])
        plates.append(Plate(c, origin, plate_channels(c, origin, f, p, tq)))
    n = trial['t'].size
    need = n * RATIO
    plates = [Plate(pl.corners, pl.origin, np.vstack([pl.channels, np.repeat(
        pl.channels[-1:], need - pl.channels.shape[0], axis=0)])) for pl in plates]
    out = write_c3d(path, trial['names'], trial['xyz'], RATE, plates, RATE * RATIO)
    if drop_channel:
        import ezc3d
        c = ezc3d.c3d(str(out))
        c['data']['analogs'] = c['data']['analogs'][:, :9, :]
        c['parameters']['ANALOG']['LABELS']['value'] = \
            c['parameters']['ANALOG']['LABELS']['value'][:9]
        c['parameters']['ANALOG']['UNITS']['value'] = \
            c['parameters']['ANALOG']['UNITS']['value'][:9]
        c.write(str(out))
    return out


def test_c3d_round_trip(tmp_path: Path, trial: dict, subject: object) -> None:
    """A C3D written from known markers and plate signals imports to the expected arrays."""
    # the C3D starts at frame 0: shift its time base to ours
    rec = recording.import_c3d(_write_c3d(tmp_path / 't.c3d', trial), _map(), subject)
    angles, wrench = expected(trial, subject)
    np.testing.assert_allclose(rec.t_angles + trial['t'][0], trial['t'], atol=1e-12)
    np.testing.assert_allclose(rec.angles, angles, atol=2e-6)
    n = rec.t_wrench.size
    np.testing.assert_allclose(rec.wrench[:, :2], wrench[:n, :2], atol=2e-3)
    np.testing.assert_allclose(rec.wrench[:, 2], wrench[:n, 2], atol=2e-2)
    assert rec.facts['angles_rate_hz'] == pytest.approx(RATE)
    assert rec.facts['wrench_rate_hz'] == pytest.approx(RATE * RATIO)
    assert rec.facts['left_right_rms_deg']['foot'] == pytest.approx(np.rad2deg(0.05), rel=1e-6)


def test_trc_and_c3d_give_the_same_bag(tmp_path: Path, trial: dict, subject: object) -> None:
    c3d = _write_c3d(tmp_path / 't.c3d', trial)
    t0 = trial['t'][0]
    trc = write_trc(tmp_path / 't.trc', trial['t'] - t0, trial['names'], trial['xyz'] * 1e3,
                    units='mm')
    ta = trial['ta'] - t0
    cols, labels = [], []
    for k, (f, p, tq) in enumerate(trial['loads']):
        labels += [f'ground_force_{k + 1}_{q}{a}' for q in 'vpm' for a in 'xyz']
        cols += [f, p, tq]
    grf = write_table(tmp_path / 'grf.mot', ta, labels, np.hstack(cols))
    a = recording.import_c3d(c3d, _map(), subject)
    b = recording.import_trc(trc, grf, _map(), subject)
    recording.write_lab_bag(tmp_path / 'bag_c3d', a)
    recording.write_lab_bag(tmp_path / 'bag_trc', b)
    oa = read_observations(tmp_path / 'bag_c3d')
    ob = read_observations(tmp_path / 'bag_trc')
    np.testing.assert_array_equal(oa.t_angles, ob.t_angles)
    np.testing.assert_allclose(oa.angles, ob.angles, atol=2e-6)
    n = min(oa.t_wrench.size, ob.t_wrench.size)
    np.testing.assert_allclose(oa.t_wrench[:n], ob.t_wrench[:n], atol=1e-9)
    np.testing.assert_allclose(oa.wrench[:n], ob.wrench[:n], atol=2e-2)
    assert (tmp_path / 'bag_trc' / 'subject.yaml').exists()


def test_marker_gap_repaired_and_reported(tmp_path: Path, trial: dict, subject: object) -> None:
    xyz = trial['xyz'].copy()
    i = trial['names'].index('RKNE')
    xyz[50:53, i] = np.nan                              # 15 ms
    markers = read_trc(write_trc(tmp_path / 'g.trc', trial['t'], trial['names'], xyz))
    loads = [GroundLoad(f, p, tq) for f, p, tq in trial['loads']]
    rec = recording.import_markers(markers, trial['ta'], loads, _map(), subject)
    assert rec.facts['repairs'] == [{'what': 'marker RKNE', 't_start_s': trial['t'][50],
                                     't_end_s': trial['t'][52], 'samples': 3}]
    angles, _ = expected(trial, subject)
    assert np.abs(rec.angles - angles).max() < np.deg2rad(0.1)
    xyz[20:60, i] = np.nan                              # 200 ms: too long to guess
    markers = read_trc(write_trc(tmp_path / 'h.trc', trial['t'], trial['names'], xyz))
    with pytest.raises(ValueError, match='marker RKNE: gap .* longer than'):
        recording.import_markers(markers, trial['ta'], loads, _map(), subject)


def test_a_repeated_last_row_is_dropped_and_reported(tmp_path: Path, trial: dict,
                                                     subject: object) -> None:
    """OpenSim's tools sometimes write their last row twice (its last digit may differ, as
    in OpenSim's own CMC test kinematics): the same sample, dropped and reported; a time
    repeated with other values, or rows not uniformly spaced, are errors naming the file."""
    labels = [f'ground_force_1_{q}{a}' for q in 'vpm' for a in 'xyz']
    rows = np.hstack(trial['loads'][0])
    clean = write_table(tmp_path / 'clean.mot', trial['ta'], labels, rows)
    last = rows[-1] * (1.0 + 1e-11)
    twice = write_table(tmp_path / 'twice.mot', np.append(trial['ta'], trial['ta'][-1]),
                        labels, np.vstack([rows, last]))
    markers = read_trc(write_trc(tmp_path / 'm.trc', trial['t'], trial['names'], trial['xyz']))
    a = recording.import_trc(tmp_path / 'm.trc', clean, _map(), subject)
    b = recording.import_trc(tmp_path / 'm.trc', twice, _map(), subject)
    np.testing.assert_array_equal(a.t_wrench, b.t_wrench)
    np.testing.assert_array_equal(a.wrench, b.wrench)
    assert a.facts['repairs'] == []
    assert b.facts['repairs'] == [{'what': 'twice.mot: row repeated exactly',
                                   't_start_s': trial['ta'][-1], 't_end_s': trial['ta'][-1],
                                   'samples': 1, 'how': 'dropped'}]
    other = write_table(tmp_path / 'other.mot', np.append(trial['ta'], trial['ta'][-1]),
                        labels, np.vstack([rows, rows[-1] + 1.0]))
    with pytest.raises(ValueError, match=rf'other.mot: time does not increase at data row '
                       rf'{trial["ta"].size + 1}'):
        read_plates(other)
    uneven = trial['ta'].copy()
    uneven[10:] += 0.4 * (uneven[1] - uneven[0])
    loads = [GroundLoad(*ld) for ld in trial['loads']]
    with pytest.raises(ValueError, match='^forces: samples must be uniformly '):
        recording.import_markers(markers, uneven, loads, _map(), subject)


def test_bad_inputs_give_clear_errors(tmp_path: Path, trial: dict, subject: object) -> None:
    # a plate channel absent from the C3D
    with pytest.raises(ValueError, match='plate channel is absent'):
        recording.import_c3d(_write_c3d(tmp_path / 'd.c3d', trial, drop_channel=True), _map(),
                             subject)
    # unknown marker units
    trc = write_trc(tmp_path / 'u.trc', trial['t'], trial['names'], trial['xyz'], units='in')
    with pytest.raises(ValueError, match="units 'in' unknown"):
        read_trc(trc)
    # NaN frames in the ground reaction
    f, p, tq = trial['loads'][0]
    f = f.copy()
    f[30] = np.nan
    grf = write_table(tmp_path / 'nan.mot', trial['ta'], [
        f'ground_force_1_{q}{a}' for q in 'vpm' for a in 'xyz'], np.hstack([f, p, tq]))
    with pytest.raises(ValueError, match='plate ground_force_1: 1 NaN/inf row'):
        read_plates(grf)
    # points of application in millimetres in a GRF .mot
    grf = write_table(tmp_path / 'mm.mot', trial['ta'], [
        f'ground_force_1_{q}{a}' for q in 'vpm' for a in 'xyz'],
        np.hstack([trial['loads'][0][0], trial['loads'][0][1] * 1e3, tq]))
    with pytest.raises(ValueError, match='not metres'):
        read_plates(grf)
    # a plate without free-moment columns
    grf = write_table(tmp_path / 'nom.mot', trial['ta'], [
        f'ground_force_1_{q}{a}' for q in 'vp' for a in 'xyz'], np.hstack([f * 0, p]))
    with pytest.raises(ValueError, match='no free-moment columns'):
        read_plates(grf)
    # another lab's marker names: every marker the map needs and the file lacks, and what to do
    names = [n.lower() + '_x' for n in trial['names']]
    other = read_trc(write_trc(tmp_path / 'o.trc', trial['t'], names, trial['xyz']))
    loads = [GroundLoad(*ld) for ld in trial['loads']]
    with pytest.raises(ValueError, match=r'needs markers .* does not have: .*RKNE.*LKNE.*'
                       r'--marker-map MAP\.yaml .*or import the lab\'s OpenSim IK with --ik'):
        recording.import_markers(other, trial['ta'], loads, _map(), subject)
    # a subject facing the other way
    markers = read_trc(write_trc(tmp_path / 'f.trc', trial['t'], trial['names'],
                                 trial['xyz']))
    loads = [GroundLoad(*ld) for ld in trial['loads']]
    with pytest.raises(ValueError, match='feet point backward'):
        recording.import_markers(markers, trial['ta'], loads, _map(), subject,
                                 SagittalFrame('-y', '+z'))


@pytest.mark.opensim
def test_ik_route_agrees_with_markers_on_the_shipped_recording() -> None:
    """IK posed on final.osim vs the TRC by the shipped marker map: same angles within the
    marker registration error (measured RMS 1.7/2.1/1.5/1.6 deg foot/shank/thigh/HAT)."""
    from nmt_ros.model.subject import subject_from_measures
    from nmt_ros.osim.subject_process import measure_model
    subject = subject_from_measures(measure_model(REAL / 'Models' / 'final.osim'), 'DJ1')
    a = recording.import_ik(REAL / 'IK' / 'DJ1_ik.mot', REAL / 'ID' / 'DJ1_grf.mot',
                            REAL / 'Models' / 'final.osim', subject,
                            REAL / 'ID' / 'DJ1_external_forces.xml')
    b = recording.import_trc(REAL / 'MarkerData' / 'DJ1.trc', REAL / 'ID' / 'DJ1_grf.mot',
                             load_marker_map(), subject)
    np.testing.assert_array_equal(a.t_angles, b.t_angles)
    rms = np.rad2deg(np.sqrt(np.mean((a.angles - b.angles) ** 2, axis=0)))
    assert np.all(rms < 2.5), rms
    np.testing.assert_array_equal(a.wrench[:, :2], b.wrench[:, :2])   # same plates, same sum
    assert a.facts['angles_rate_hz'] == pytest.approx(100.0)
    assert len(b.facts['repairs']) == 26                      # the TRC's gaps, all <= 20 ms
    assert subject.mass_kg == pytest.approx(75.3196, abs=1e-3)


@pytest.mark.opensim
def test_cli_on_the_shipped_recording_matches_the_shipped_bag(tmp_path: Path) -> None:
    out = tmp_path / 'bag'
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'import-lab',
                           '--ik', str(REAL / 'IK' / 'DJ1_ik.mot'),
                           '--grf', str(REAL / 'ID' / 'DJ1_grf.mot'),
                           '--external-loads', str(REAL / 'ID' / 'DJ1_external_forces.xml'),
                           '--model', str(REAL / 'Models' / 'final.osim'), '--name', 'DJ1',
                           '--out', str(out)], capture_output=True, text=True, timeout=300,
                          cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    new = read_observations(out)
    shipped = read_observations(REPO / 'bags' / 'real_dropjump')
    # the same numbers up to the last bits (OpenSim's IK posing differs in the 16th digit
    # between builds of its wheel)
    np.testing.assert_allclose(new.angles, shipped.angles, rtol=0, atol=1e-12)
    np.testing.assert_allclose(new.wrench, shipped.wrench, rtol=0, atol=1e-9)
    np.testing.assert_allclose(new.t_angles, np.arange(245) * 0.01, atol=1e-9)
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'import-lab',
                           '--trc', str(REAL / 'MarkerData' / 'DJ1.trc'), '--out',
                           str(tmp_path / 'x')], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2 and '--trc needs --grf' in proc.stderr


def test_mass_implied_weighs_the_subject_with_its_own_force_plates(tmp_path: Path) -> None:
    """`--mass implied`: the subject takes the body mass the recording's momentum balance
    implies (the shipped drop jump: the impulse between its two flights, 94.5 kg by the IK
    route; the markers' COM with the jumper's proportions here), and says so; a --mass that
    is neither a number, 'implied' nor 'model' (or 'model' without --model) is a clear
    error."""
    import json

    import yaml

    def run(*extra: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'import-lab',
                               '--trc', str(REAL / 'MarkerData' / 'DJ1.trc'),
                               '--grf', str(REAL / 'ID' / 'DJ1_grf.mot'),
                               '--external-loads', str(REAL / 'ID' / 'DJ1_external_forces.xml'),
                               '--height', '1.8', *extra], capture_output=True, text=True,
                              timeout=300, cwd=REPO)
    out = tmp_path / 'bag'
    proc = run('--mass', 'implied', '--out', str(out))
    assert proc.returncode == 0, proc.stderr
    subject = yaml.safe_load((out / 'subject.yaml').read_text())['subject']
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())
    facts = json.loads(meta['rosbag2_bagfile_information']['custom_data']['nmt.import'])
    implied = facts['momentum_balance']['implied_mass_kg']
    assert subject['mass_kg'] == pytest.approx(implied, abs=0.01)
    assert implied == pytest.approx(94.5, rel=0.02)
    assert 'force plates imply' in subject['source']
    assert not any('imply a body mass' in w for w in facts['warnings'])
    # with the jumper's 75.16 kg the same recording is flagged
    proc = run('--mass', '75.16', '--out', str(tmp_path / 'b2'))
    assert proc.returncode == 0 and 'imply a body mass of' in proc.stderr
    proc = run('--mass', 'heavy', '--out', str(tmp_path / 'b3'))
    assert proc.returncode == 2 and "'heavy': a mass in kg, 'implied' or 'model'" in proc.stderr
    proc = run('--mass', 'model', '--out', str(tmp_path / 'b4'))      # no --model to keep
    assert proc.returncode == 2 and '--mass model needs --model' in proc.stderr


def test_a_model_the_jumpers_joints_cannot_pose_keeps_the_jumpers_paths(tmp_path: Path) -> None:
    """A subject .osim without the jumper's joint coordinates (here the shipped model with
    hip_flexion_r renamed) still imports: its muscle geometry cannot be sampled, so the
    subject keeps the scaled jumper's paths, and the import says why."""
    import yaml

    model = tmp_path / 'renamed.osim'
    model.write_text((REAL / 'Models' / 'final.osim').read_text().replace('hip_flexion_r',
                                                                          'hip_flex_r'))
    out = tmp_path / 'bag'
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'import-lab',
                           '--trc', str(REAL / 'MarkerData' / 'DJ1.trc'),
                           '--grf', str(REAL / 'ID' / 'DJ1_grf.mot'),
                           '--external-loads', str(REAL / 'ID' / 'DJ1_external_forces.xml'),
                           '--model', str(model), '--out', str(out)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert "muscle paths: the scaled jumper's" in proc.stderr
    assert 'no coordinate hip_flexion_r' in proc.stderr
    assert 'paths' not in yaml.safe_load((out / 'subject.yaml').read_text())['scale']


def test_a_models_moment_arms_are_measured_once_then_read_from_the_cache(tmp_path,
                                                                          monkeypatch):
    """The moment arms of a model (its file, the spec, the measuring code, OpenSim's
    version) are kept in the cache: with them there, no OpenSim process runs; a model that
    differs by one byte has a cache file of its own, and an unreadable cache file is
    measured again, not trusted."""
    import json

    from nmt_ros.model.subject import moment_arm_spec
    from nmt_ros.osim import subject_process

    monkeypatch.setenv('NMT_CACHE_DIR', str(tmp_path / 'cache'))
    model = tmp_path / 'final.osim'
    model.write_bytes((REAL / 'Models' / 'final.osim').read_bytes())
    spec = moment_arm_spec()
    cached = subject_process.moment_arms_cache_file(model, spec)
    assert cached.parent.name == 'osim' and cached.parent.parent == tmp_path / 'cache'
    arms = {'planted': [1.0, 2.0]}
    cached.write_text(json.dumps(arms))

    def no_opensim(args: list[str]) -> None:
        raise AssertionError(f'OpenSim ran: {args}')

    monkeypatch.setattr(subject_process, '_run', no_opensim)
    assert subject_process.subject_moment_arms(model, spec) == arms
    # another model (one byte more) or another spec: another file
    other = tmp_path / 'other.osim'
    other.write_bytes(model.read_bytes() + b' ')
    assert subject_process.moment_arms_cache_file(other, spec) != cached
    assert subject_process.moment_arms_cache_file(model, {**spec, 'x': 1}) != cached
    # a half-written cache file is not trusted: OpenSim runs again
    cached.write_text('{"planted": [1.0,')
    with pytest.raises(AssertionError, match='OpenSim ran'):
        subject_process.subject_moment_arms(model, spec)
