"""Subject models: the scaled jumper, against the jumper itself and against OpenSim's scaling.

OpenSim runs in subprocesses only (``python -m nmt_ros.osim.subject``).
"""
from __future__ import annotations

from dataclasses import replace
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from nmt_ros.model.jumper import JumperModel, default_model
from nmt_ros.model.parameters import MUSCLES, SEGMENTS, load_parameters
from nmt_ros.model.subject import (
    REACH_MARGIN_RAD,
    REACH_WALL_N_M_PER_KG,
    load_rules,
    load_subject_model,
    reached_joint_ranges,
    read_subject,
    scale_factors,
    scale_parameters,
    subject_from_mass_height,
    subject_from_measures,
    write_subject,
)

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO / 'data' / 'opensim' / 'gait10dof18musc.osim'
REAL_MODEL = REPO / 'data' / 'real' / 'opencap_dropjump' / 'Models' / 'final.osim'
OPENSIM_MUSCLES = [f'{n}_r' for n in ('glut_max', 'iliopsoas', 'hamstrings', 'bifemsh',
                                      'rect_fem', 'vasti', 'gastroc', 'soleus', 'tib_ant')]
POSES = np.deg2rad([[0.0, 0.0, 0.0], [20.0, -60.0, 70.0], [-25.0, -90.0, 90.0],
                    [10.0, -20.0, 20.0], [-10.0, -110.0, 100.0]])   # ankle, knee, hip


def _flat(p: object) -> np.ndarray:
    seg = np.concatenate([np.r_[s.mass, s.izz, s.com, s.distal_joint if s.distal_joint
                                is not None else []] for s in p.segments.values()])
    m = p.muscles
    paths = np.concatenate([m.paths[n].coefficients for n in m.names])
    return np.concatenate([seg, p.contact.points.ravel(), [p.contact.k_y, p.contact.k_x,
                           p.contact.c_x], p.passive.k.ravel(), p.passive.damping, m.f0,
                           m.l_opt, m.l_slack, paths])


def test_scale_one_is_the_jumper(tmp_path: Path) -> None:
    p = load_parameters()
    subject = subject_from_mass_height(p.total_mass, load_rules()['reference']['stature_m'])
    scale = scale_factors(subject, p)
    for factors in (scale.mass, scale.length, scale.muscle_length):
        np.testing.assert_allclose(list(factors.values()), 1.0, rtol=1e-15)
    np.testing.assert_allclose(_flat(scale_parameters(p, scale)), _flat(p), rtol=1e-15)
    # through the file and the model
    (tmp_path / 'bag').mkdir()
    write_subject(tmp_path / 'bag', subject, scale)
    model = load_subject_model(tmp_path / 'bag')
    q = np.array([0.1, -0.4, 0.7, -0.5, 0.2, 0.5])
    np.testing.assert_allclose(np.asarray(model.mass_matrix(q)),
                               np.asarray(default_model().mass_matrix(q)), rtol=1e-14)
    assert load_subject_model(tmp_path) is default_model()   # a bag without a subject file


def test_scaled_model_is_consistent(tmp_path: Path) -> None:
    p = load_parameters()
    subject = subject_from_mass_height(90.0, 1.92, 'tall')
    write_subject(tmp_path / 'subject.yaml', subject)
    read, scale = read_subject(tmp_path / 'subject.yaml')
    assert read == subject
    q = scale_parameters(p, scale)
    assert q.total_mass == pytest.approx(90.0, rel=1e-12)
    k = 1.92 / 1.80
    model = JumperModel(q)
    theta = np.array([0.2, -0.9, 1.1])
    np.testing.assert_allclose(np.asarray(model.moment_arms(theta)),
                               k * np.asarray(default_model().moment_arms(theta)), rtol=1e-12)
    np.testing.assert_allclose(q.muscles.f0, p.muscles.f0 * (90.0 / p.total_mass) ** (2 / 3))
    # the standing COM height scales with stature
    assert model.standing_com_height == pytest.approx(k * default_model().standing_com_height,
                                                      rel=0.02)
    with pytest.raises(ValueError, match='stature 180.0 m'):
        subject_from_mass_height(75.0, 180.0)


def _osim(*args: str) -> None:
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.osim.subject', *args], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]


@pytest.mark.opensim
def test_reference_lengths_are_the_jumper_source_model(tmp_path: Path) -> None:
    _osim('measure', '--model', str(SOURCE), '--out', str(tmp_path / 'm.json'))
    m = json.loads((tmp_path / 'm.json').read_text())
    ref = load_rules()['reference']['segment_lengths_m']
    for seg in ('thigh', 'shank', 'foot'):
        assert m['segment_lengths_m'][seg] == pytest.approx(ref[seg], abs=1e-6)
    p = load_parameters()
    for seg in SEGMENTS:
        assert m['segment_masses_kg'][seg] == pytest.approx(p.segments[seg].mass, abs=1e-4)


def _crosscheck(tmp_path: Path, length: dict, mass: float) -> tuple[dict, object, object]:
    spec = {'length': length, 'mass_kg': mass, 'poses': POSES.tolist(),
            'muscles': OPENSIM_MUSCLES}
    (tmp_path / 'spec.json').write_text(json.dumps(spec))
    _osim('scaled-jumper', '--model', str(SOURCE), '--spec', str(tmp_path / 'spec.json'),
          '--out', str(tmp_path / 'out.json'))
    res = json.loads((tmp_path / 'out.json').read_text())
    subject = subject_from_measures(res, 'opensim-scaled')
    params = scale_parameters(load_parameters(), scale_factors(subject))
    return res, subject, params


@pytest.mark.opensim
def test_uniform_scaling_matches_opensim(tmp_path: Path) -> None:
    """All bodies x1.1, 85 kg, by OpenSim's scaling and ours: the same model. Our paths differ
    from OpenSim's GeometryPath by the polynomial fit's error (up to 2.2 mm of moment arm at
    full knee extension, the fit's edge); uniform scaling must multiply that error by exactly
    1.1, so (ours - OpenSim) at scale 1.1 = 1.1 x (ours - OpenSim) at scale 1."""
    diffs = {}
    for k, mass in ((1.0, load_parameters().total_mass), (1.1, 85.0)):
        (tmp_path / str(k)).mkdir()
        res, subject, params = _crosscheck(tmp_path / str(k), {s: k for s in SEGMENTS}, mass)
        assert res['total_mass_kg'] == pytest.approx(mass, rel=1e-9)
        scale = scale_factors(subject)
        np.testing.assert_allclose(list(scale.length.values()), k, rtol=1e-9)
        np.testing.assert_allclose(list(scale.mass.values()), mass / load_parameters().total_mass,
                                   rtol=1e-6)
        np.testing.assert_allclose(params.muscles.l_opt, res['optimal_fiber_length_m'],
                                   rtol=1e-6)
        np.testing.assert_allclose(params.muscles.l_slack, res['tendon_slack_length_m'],
                                   rtol=1e-6)
        model = JumperModel(params)
        arms = np.array([np.asarray(model.moment_arms(th)) for th in POSES])    # [n, 9, 3]
        lmt = np.array([np.asarray(model.musculotendon_lengths(th)).ravel() for th in POSES])
        diffs[k] = (arms - np.asarray(res['moment_arms_m']),
                    lmt - np.asarray(res['musculotendon_lengths_m']))
    assert np.abs(diffs[1.0][0]).max() < 2.5e-3             # the fit's error (m)
    np.testing.assert_allclose(diffs[1.1][0], 1.1 * diffs[1.0][0], atol=1e-9)
    np.testing.assert_allclose(diffs[1.1][1], 1.1 * diffs[1.0][1], atol=1e-9)


@pytest.mark.opensim
def test_subject_scaling_against_opensim(tmp_path: Path) -> None:
    """The shipped subject's factors (foot 1.28, shank 1.086, thigh 1.090): OpenSim scales
    each body's path points by its own factor, we scale a muscle by its segments' mean.
    Measured worst moment-arm difference over the poses, % of the muscle's peak: GMAX 0.2,
    ILPSO 4.9, HAMS 0.4, BFSH 0.6, RF 3.4, VAS 4.3, GAS 15.5, SOL 15.3, TA 3.6 (the ankle
    plantarflexors' moment arm grows with the calcaneus, i.e. the foot's 1.28, while their
    length follows the shank's 1.086: one factor per muscle cannot do both)."""
    from nmt_ros.osim.subject_process import measure_model
    subject = subject_from_measures(measure_model(REAL_MODEL), 'DJ1')
    scale = scale_factors(subject)
    res, _, params = _crosscheck(tmp_path, scale.length, subject.mass_kg)
    assert res['total_mass_kg'] == pytest.approx(subject.mass_kg, rel=1e-9)
    for seg in ('thigh', 'shank', 'foot'):
        assert res['segment_lengths_m'][seg] == pytest.approx(
            subject.segment_lengths_m[seg], rel=1e-6)
    model = JumperModel(params)
    ours = np.array([np.asarray(model.moment_arms(th)) for th in POSES])
    theirs = np.asarray(res['moment_arms_m'])
    peak = np.abs(theirs).max(axis=(0, 2))                 # per muscle
    err = np.abs(ours - theirs).max(axis=(0, 2)) / peak
    print(dict(zip(MUSCLES, np.round(err, 3))))
    bound = np.array([0.01, 0.06, 0.01, 0.01, 0.05, 0.05, 0.17, 0.17, 0.05])
    assert np.all(err < bound), dict(zip(MUSCLES, err))


def test_path_from_moment_arms_recovers_a_known_path() -> None:
    """Moment arms sampled from a known two-coordinate path (the hamstrings' with every
    non-constant coefficient changed) give back that path's moment arms between the samples,
    and the fitted path keeps the original's length at the zero pose."""
    from dataclasses import replace

    from nmt_ros.model.subject import _gradient_rows, path_from_moment_arms

    path = load_parameters().muscles.paths['hams']
    rng = np.random.default_rng(3)
    moved = path.coefficients * (1 + 0.3 * rng.standard_normal(path.coefficients.size))
    moved[path.exponents.sum(axis=1) == 0] = 0.5          # another length at the zero pose
    target = replace(path, coefficients=moved)
    grid = np.radians(np.array(np.meshgrid(np.arange(-20, 121, 5.0), np.arange(-120, 6, 5.0),
                                           indexing='ij')).reshape(2, -1).T)
    def arms(p, q):
        return -np.einsum('nkt,t->nk', _gradient_rows(p.exponents, q), p.coefficients)
    fitted, rms = path_from_moment_arms(path, grid, arms(target, grid))
    assert rms < 1e-9
    between = grid[:-1] + np.radians([2.5, 2.5])
    np.testing.assert_allclose(arms(fitted, between), arms(target, between), atol=1e-9)
    zero = fitted.exponents.sum(axis=1) == 0
    assert fitted.coefficients[zero] == pytest.approx(
        path.coefficients[path.exponents.sum(axis=1) == 0])


def test_subject_paths_are_the_subject_models_own_moment_arms() -> None:
    """The shipped drop jump's subject (bags/real_dropjump/subject.yaml, from `nmt
    import-lab --model final.osim`) has the moment arms of its .osim's own muscles, lumped
    as the jumper lumps them (F0-weighted), checked against OpenSim between the fit's grid
    points; its hip extensor keeps its moment arm in deep flexion, where gait10dof18musc's
    glut_max (no wrapping surface) loses it."""
    from nmt_ros.model.subject import moment_arm_spec
    from nmt_ros.osim.subject_process import subject_moment_arms

    subject = load_subject_model(REPO / 'bags' / 'real_dropjump')
    assert set(read_subject(REPO / 'bags' / 'real_dropjump')[1].paths) == set(MUSCLES)
    spec = moment_arm_spec()
    spec['step_deg'] = 7.0                      # off the fit's 5 deg grid
    res = subject_moment_arms(REAL_MODEL, spec)
    assert not res['missing']
    joint = {'ankle_angle': 0, 'knee_angle': 1, 'hip_flexion': 2}
    worst = {}
    for name, a in res['muscles'].items():
        k = MUSCLES.index(name)
        th = np.zeros((len(a['points_rad']), 3))
        for j, c in enumerate(a['coordinates']):
            th[:, joint[c]] = np.asarray(a['points_rad'])[:, j]
        ours = np.array([np.asarray(subject.moment_arms(t))[k, [joint[c] for c in
                                                                  a['coordinates']]]
                         for t in th])
        worst[name] = float(np.abs(ours - np.asarray(a['moment_arms_m'])).max())
    print({n: round(1e3 * v, 2) for n, v in worst.items()})
    assert max(worst.values()) < 0.002, worst
    deep = np.radians([0.0, -90.0, 115.0])      # ankle, knee, hip: a deep landing
    gmax = MUSCLES.index('gmax')
    assert float(np.asarray(subject.moment_arms(deep))[gmax, 2]) < -0.02
    assert abs(float(np.asarray(default_model().moment_arms(deep))[gmax, 2])) < 0.005


def test_moment_arm_sampler_on_the_jumpers_source_model_gives_the_jumpers_paths() -> None:
    """``python -m nmt_ros.osim.subject moment-arms`` on gait10dof18musc.osim (knee flexing
    negative, muscles named as the jumper's: the last alternative of every group) samples
    the moment arms the jumper's fitted paths have (their fit: 0.1 mm RMS)."""
    from nmt_ros.model.subject import moment_arm_spec
    from nmt_ros.osim.subject_process import subject_moment_arms

    spec = moment_arm_spec()
    spec['step_deg'] = 10.0
    spec['ranges_deg'] = {'hip_flexion': [-20.0, 120.0], 'knee_angle': [-120.0, 0.0],
                          'ankle_angle': [-50.0, 40.0]}      # inside the paths' fit grid
    res = subject_moment_arms(SOURCE, spec)
    assert not res['missing'] and res['coordinate_sign']['knee_angle'] == 1.0
    assert res['muscles']['gmax']['members'] == ['glut_max_r']
    jumper = default_model()
    report = json.loads((REPO / 'nmt_ros' / 'model' / 'data' / 'paths_fit_report.json')
                        .read_text())['muscles']
    joint = {'ankle_angle': 0, 'knee_angle': 1, 'hip_flexion': 2}
    assert set(res['muscles']) == set(MUSCLES)
    for name, a in res['muscles'].items():
        k = MUSCLES.index(name)
        cols = [joint[c] for c in a['coordinates']]
        th = np.zeros((len(a['points_rad']), 3))
        th[:, cols] = np.asarray(a['points_rad'])
        ours = np.array([np.asarray(jumper.moment_arms(t))[k, cols] for t in th])
        worst = np.abs(ours - np.asarray(a['moment_arms_m'])).max()
        # within the fit's own worst moment-arm error (its report: 0.01-2.8 mm; the
        # iliopsoas' conditional path point makes a kink at 45 deg the polynomial smooths)
        assert worst < 1.5e-3 * report[name]['moment_arm_max_mm'] + 3e-4, (name, worst)


def test_subject_strengths_are_the_subject_models_own() -> None:
    """The shipped drop jump's subject takes F0 and l_opt from its .osim's own muscles
    (read here from the XML, not through OpenSim): F0 the group's sum for two legs, l_opt its
    F0-weighted mean; each such muscle's tendon slack length moves so that its normalised
    fibre length at the zero pose is the scaled jumper's (its path's operating point)."""
    from dataclasses import replace
    import re

    text = REAL_MODEL.read_text()
    osim = {}
    for m in re.finditer(r'<(\w+Muscle) name="(\w+)_r">(.*?)</\1>', text, re.S):
        f0 = float(re.search(r'<max_isometric_force>([^<]+)<', m.group(3)).group(1))
        lo = float(re.search(r'<optimal_fiber_length>([^<]+)<', m.group(3)).group(1))
        osim[m.group(2)] = (f0, lo)
    groups = {'gmax': ('glmax1', 'glmax2', 'glmax3'), 'vas': ('vasint', 'vaslat', 'vasmed'),
              'hams': ('semimem', 'semiten', 'bflh'), 'sol': ('soleus',)}
    _, scale = read_subject(REPO / 'bags' / 'real_dropjump')
    subject = load_subject_model(REPO / 'bags' / 'real_dropjump').p.muscles
    jumper_scaled = scale_parameters(load_parameters(),
                                     replace(scale, f0_n={}, l_opt_m={})).muscles
    for name, members in groups.items():
        f0 = np.array([osim[n][0] for n in members])
        lo = np.array([osim[n][1] for n in members])
        k = MUSCLES.index(name)
        assert subject.f0[k] == pytest.approx(2 * f0.sum(), rel=1e-9)
        assert subject.l_opt[k] == pytest.approx(np.dot(f0, lo) / f0.sum(), rel=1e-9)
    model = load_subject_model(REPO / 'bags' / 'real_dropjump')
    jumper = JumperModel(scale_parameters(load_parameters(), replace(scale, f0_n={},
                                                                       l_opt_m={})))
    zero = np.zeros(3)
    # the paths keep the scaled jumper's length at the zero pose
    assert np.allclose(np.asarray(model.musculotendon_lengths(zero)).ravel(),
                       np.asarray(jumper.musculotendon_lengths(zero)).ravel())
    along = lambda p, l_mt: (l_mt - p.l_slack) / p.l_opt            # noqa: E731
    l_mt = np.asarray(model.musculotendon_lengths(zero)).ravel()
    assert np.allclose(along(subject, l_mt), along(jumper_scaled, l_mt), rtol=1e-9)
    assert not np.allclose(subject.l_opt, jumper_scaled.l_opt)


def test_subject_passive_limits_start_at_its_models_clamped_ranges() -> None:
    """The shipped drop jump's subject: where its .osim clamps a coordinate to a narrower
    range than the jumper's passive limits (read here from the XML: OpenCap's knee_angle_r
    0..140 deg of flexion, positive; hip_flexion_r -30..120 deg), the passive torque starts
    at the range's end; elsewhere the jumper's limits stay."""
    import re

    text = REAL_MODEL.read_text()

    def clamped_range(name: str) -> tuple[float, float]:
        block = re.search(rf'<Coordinate name="{name}">(.*?)</Coordinate>', text, re.S).group(1)
        assert re.search(r'<clamped>\s*true\s*<', block)
        lo, hi = (float(v) for v in re.search(r'<range>([^<]+)<', block).group(1).split())
        return lo, hi

    knee_lo, knee_hi = clamped_range('knee_angle_r')     # flexion positive: negated
    hip_lo, hip_hi = clamped_range('hip_flexion_r')
    _, scale = read_subject(REPO / 'bags' / 'real_dropjump')
    assert scale.joint_range_rad['knee_angle'] == pytest.approx((-knee_hi, -knee_lo))
    assert scale.joint_range_rad['hip_flexion'] == pytest.approx((hip_lo, hip_hi))
    jumper = load_parameters().passive
    subject = load_subject_model(REPO / 'bags' / 'real_dropjump').p.passive
    assert subject.theta_upper[1] == pytest.approx(-knee_lo)              # 0: no hyperextension
    assert subject.theta_lower[2] == pytest.approx(hip_lo)               # -30 deg, not -40
    assert subject.theta_upper[1] < jumper.theta_upper[1]
    # the recording reaches 33.9 deg of dorsiflexion and 120 deg of hip flexion, past the
    # jumper's onsets (29.8, 104) but not through them: those limits would carry 0.8 and 0.2
    # N m/kg there, so they stay (test_passive_limits_a_recording_goes_through_move_out)
    assert np.degrees(scale.reached_range_rad['ankle_angle'][1]) == pytest.approx(33.9, abs=0.05)
    assert np.degrees(scale.reached_range_rad['hip_flexion'][1]) > 115
    for j, (lo, hi) in ((0, (jumper.theta_lower[0], jumper.theta_upper[0])),
                        (1, (jumper.theta_lower[1], None)), (2, (None, jumper.theta_upper[2]))):
        if lo is not None:
            assert subject.theta_lower[j] == lo
        if hi is not None:
            assert subject.theta_upper[j] == hi
    # 3 deg of knee hyperextension (knee_angle = shank - thigh angle): the subject's passive
    # knee torque flexes it back with ~90 N m, the jumper's (onset 7.4 deg) with ~1 N m
    q = np.zeros(6)
    q[1] = np.radians(3.0)
    model = load_subject_model(REPO / 'bags' / 'real_dropjump')
    assert float(np.asarray(model.joint_angles(q)).ravel()[1]) == pytest.approx(q[1])
    knee_subject = float(np.asarray(model.passive_torques(q, np.zeros(6))).ravel()[1])
    knee_jumper = float(np.asarray(default_model().passive_torques(q, np.zeros(6))).ravel()[1])
    assert knee_subject < -50.0 and -5.0 < knee_jumper < 0.0, (knee_subject, knee_jumper)


def test_passive_limits_a_recording_goes_through_move_out(tmp_path: Path) -> None:
    """Joint angles a recording reaches (its 0.5th / 99.5th percentiles, so one stray frame
    does not count) move a passive limit's onset out to REACH_MARGIN_RAD past them where the
    limit would carry more than REACH_WALL_N_M_PER_KG there (the dorsiflexion wall at 45 deg:
    tens of kN m); a limit passed by a little (that wall at 33 deg: 0.6 N m/kg) or a soft one
    (hip flexion at 125 deg: 0.4 N m/kg) stays, as does every limit the recording stays inside."""
    deg = np.deg2rad
    n = 1000
    jumper = load_parameters()
    subject = subject_from_mass_height(jumper.total_mass, 1.80)

    def passive(ankle_max_deg: float, hip_max_deg: float) -> tuple[dict, object]:
        ankle = deg(np.linspace(0, ankle_max_deg, n))
        knee = deg(np.linspace(-100, -5, n))
        hip = deg(np.linspace(10, hip_max_deg, n))
        hat = np.zeros(n)
        thigh = hat + hip
        shank = thigh + knee
        theta = np.column_stack([shank + ankle, shank, thigh, hat])
        theta[500, 0] += deg(40)                    # a spike: ankle +40 deg in one frame
        theta[600, 1] = np.nan                      # an occluded frame is left out
        reached = reached_joint_ranges(theta)
        scale = replace(scale_factors(subject), reached_range_rad=reached)
        return reached, scale

    reached, scale = passive(45.0, 125.0)
    assert np.degrees(reached['ankle_angle'][1]) == pytest.approx(45, abs=1.0)   # 99.5th pct
    assert np.degrees(reached['hip_flexion'][1]) == pytest.approx(125, abs=1.0)
    p = scale_parameters(jumper, scale).passive
    assert p.theta_upper[0] == pytest.approx(reached['ankle_angle'][1] + REACH_MARGIN_RAD)
    assert p.theta_upper[2] == jumper.passive.theta_upper[2]    # soft: hip flexion stays
    np.testing.assert_array_equal(p.theta_lower, jumper.passive.theta_lower)   # inside
    assert p.theta_upper[1] == jumper.passive.theta_upper[1]
    # the walls' torques at the angles reached, two legs, against the threshold
    wall = REACH_WALL_N_M_PER_KG * jumper.total_mass
    k = jumper.passive.k
    over = reached['ankle_angle'][1] - jumper.passive.theta_upper[0]
    assert 2 * abs(k[0, 0]) * np.exp(k[0, 1] * over) > 100 * wall
    _, scale = passive(33.0, 125.0)                 # the same wall passed by 3 deg: stays
    np.testing.assert_array_equal(scale_parameters(jumper, scale).passive.theta_upper,
                                  jumper.passive.theta_upper)
    # the subject file keeps them
    _, back = read_subject(write_subject(tmp_path / 'subject.yaml', subject, scale))
    assert back.reached_range_rad == scale.reached_range_rad
