"""Routines (issue 11): minutes of ground truth on the musculoskeletal model.

A ``nmt routine --quick`` run (one countermovement jump between two stances, truth at
1080 Hz, OpenSim files) is checked against OpenSim's inverse dynamics, Newton's law for the
whole body, its targets and its own determinism; the shipped bags (a drop jump and four
countermovement jumps over 60 s, clean and with faults) against the specification of the
truth, the sway, the observations and the faults.
"""
from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from nmt_ros.io.bags import bag_info, read_arrays
from nmt_ros.io.opensim_files import read_table
from nmt_ros.io.trial_bag import read_observations
from nmt_ros.model.jumper import default_model
from nmt_ros.model.parameters import JOINTS, Q_NAMES, SEGMENTS

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / 'bags' / 'routine'
SHIPPED_FAULTS = REPO / 'bags' / 'routine_faults'
MODEL = default_model()
BW = MODEL.p.body_weight


def _custom(path: Path, key: str) -> object:
    return json.loads(bag_info(path).custom_data[f'nmt.routine.{key}'])


def _run_quick(out: Path, seed: int = 3) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'routine', '--out',
                           str(out), '--quick', '--seed', str(seed)], cwd=REPO,
                          capture_output=True, text=True, timeout=900)


@pytest.fixture(scope='module')
def quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('routine_quick')
    proc = _run_quick(out)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out / 'routine'


def _truth(path: Path) -> dict:
    """Truth arrays of a routine bag (generalized coordinates at their rate, ground wrench
    and anchors at 1080 Hz)."""
    gc = read_arrays(path, '/truth/generalized_coordinates')
    gw = read_arrays(path, '/truth/ground_wrench')
    an = read_arrays(path, '/truth/contact_anchors')
    epoch = int(bag_info(path).custom_data['nmt.trial_epoch_ns'])
    return {'t': (gc.stamp_ns - epoch) * 1e-9,
            'q': np.column_stack([gc.column(n) for n in Q_NAMES]),
            'qd': np.column_stack([gc.column(n, 'velocity') for n in Q_NAMES]),
            't_w': (gw.stamp_ns - epoch) * 1e-9,
            's': np.column_stack([gw.force[:, 0], gw.force[:, 1], gw.torque[:, 2]]),
            't_anchor': (an.stamp_ns - epoch) * 1e-9,
            'anchors': np.column_stack([an.column('heel'), an.column('toe')])}


def test_quick_routine_writes_its_folder_and_reaches_its_target(quick: Path) -> None:
    for name in ('metadata.yaml', 'routine_0.mcap', 'truth.sto', 'truth_states.sto',
                 'truth_grf.mot', 'truth_grf.xml', 'routine.png'):
        assert (quick / name).stat().st_size > 100, name
    cycles = _custom(quick, 'cycles')
    assert len(cycles) == 1 and cycles[0]['kind'] == 'cmj'
    c = cycles[0]
    assert abs(c['achieved_height_m'] - c['target_height_m']) < 0.01
    # the achieved height, independently: the COM's highest truth sample in the flight
    tr = _truth(quick)
    com, = MODEL.batch(MODEL.com, tr['q'])
    flight = (tr['t'] > c['liftoff_s']) & (tr['t'] < c['landing_s'])
    apex = com[flight, 1].max() - MODEL.standing_com_height
    assert abs(apex - c['target_height_m']) < 0.01, (apex, c['target_height_m'])
    assert abs(apex - c['achieved_height_m']) < 1e-6


def test_quick_routine_obeys_newton_for_the_whole_body(quick: Path) -> None:
    """m a_com = ground force + m g at every truth sample (qdd from the truth speeds), and
    the vertical ground force is never negative: the contact forces are the model's."""
    tr = _truth(quick)
    assert np.array_equal(tr['t'], tr['t_w'])           # 1080 Hz truth in a quick routine
    qdd = np.gradient(tr['qd'], tr['t'], axis=0)
    acc, = MODEL.batch(MODEL.com_acceleration, tr['q'], tr['qd'], qdd)
    m = MODEL.p.total_mass
    resid = m * acc - tr['s'][:, :2] - np.array([0.0, -m * MODEL.p.gravity])
    inner = slice(2, -2)
    # finite-difference qdd: compare with the peak ground force
    assert np.abs(resid[inner]).max() < 0.02 * np.abs(tr['s'][:, 1]).max(), \
        np.abs(resid[inner]).max(axis=0)
    assert tr['s'][:, 1].min() > -1e-6
    peaks = _custom(quick, 'landing_peaks')
    for p in peaks:
        assert 1.5 < p['peak_bw'] < 6.0, p


def test_quick_routine_anchors_are_placed_at_touchdown(quick: Path) -> None:
    """Each anchor change is a touchdown: the point's ground x at that instant."""
    tr = _truth(quick)
    touchdowns = _custom(quick, 'touchdowns')
    assert len(tr['t_anchor']) == len(touchdowns) + 1
    for td, t_change, anchors in zip(touchdowns, tr['t_anchor'][1:], tr['anchors'][1:]):
        i = ['heel', 'toe'].index(td['point'])
        assert td['t_s'] <= t_change < td['t_s'] + 1 / 1080 + 1e-9
        assert anchors[i] == pytest.approx(td['anchor_m'], abs=1e-6)


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    """Two runs of one seed write the same bytes: stance with its sway, the observations'
    noise and bias, and the faulty twin's occlusions, NaN samples, drift and spikes (3 s of
    stance: the jump planner's own determinism is IPOPT's; a repeat of the quick routine with
    its jump cost 81 s of the suite)."""
    runs = []
    for name in ('a', 'b'):
        out = tmp_path / name
        proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'routine', '--out',
                               str(out), '--quick', '--jumps', '0', '--duration', '3',
                               '--both', '--seed', '5'], cwd=REPO, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs.append(out)
    files = [Path('routine/routine_0.mcap'), Path('routine/truth.sto'),
             Path('routine_faults/routine_faults_0.mcap')]
    for f in files:
        assert (runs[0] / f).read_bytes() == (runs[1] / f).read_bytes(), f
    faults = read_observations(runs[0] / 'routine_faults')
    assert not np.isfinite(faults.angles).all() or not np.isfinite(faults.wrench).all(), \
        'the faulty twin has no NaN samples: the fault generator did not run'


def test_opensim_inverse_dynamics_on_the_routine_truth_files(quick: Path,
                                                            tmp_path: Path) -> None:
    """OpenSim's InverseDynamicsTool on truth.sto + truth_grf.xml (whole routine: stance,
    push-off, flight, landing) gives the truth joint torques within 1 % of their peak."""
    osim = tmp_path / 'jumper.osim'
    subprocess.run([sys.executable, '-m', 'nmt_ros.osim.export', '--out', str(osim)],
                   check=True, cwd=REPO, capture_output=True, timeout=300)
    out = tmp_path / 'id.sto'
    subprocess.run([sys.executable, '-m', 'nmt_ros.osim.crosscheck', 'id', '--coordinates',
                    str(quick / 'truth.sto'), '--external-loads', str(quick / 'truth_grf.xml'),
                    '--out-sto', str(out), '--model', str(osim)],
                   check=True, cwd=REPO, capture_output=True, timeout=600)
    table = read_table(out)
    jt = read_arrays(quick, '/truth/joint_torques')
    epoch = int(bag_info(quick).custom_data['nmt.trial_epoch_ns'])
    t = (jt.stamp_ns - epoch) * 1e-9
    inner = (t > t[0] + 0.01) & (t < t[-1] - 0.01)     # OpenSim's spline end conditions
    for name, coord in zip(JOINTS, ('ankle_angle', 'knee_angle', 'hip_flexion')):
        tau = jt.column(name, 'effort')
        tau_os = np.interp(t, table.time, table.column(f'{coord}_moment'))
        peak = np.abs(tau).max()
        err = np.abs(tau_os[inner] - tau[inner]).max() / peak
        print(f'OpenSim ID vs truth, {name}: max error {100 * err:.3f} % of peak '
              f'{peak:.1f} N m')
        assert err < 0.01, (name, err)


# ------------------------------------------------------------------ the shipped routine
shipped = pytest.mark.skipif(not SHIPPED.exists(), reason='bags/routine not shipped')


@shipped
def test_shipped_routine_is_a_minute_of_varied_jumps_at_their_targets() -> None:
    cycles = _custom(SHIPPED, 'cycles')
    settings = _custom(SHIPPED, 'settings')
    assert settings['duration_s'] >= 60
    assert [c['kind'] for c in cycles][0] == 'drop' and len(cycles) >= 4
    fractions = [c['target_height_m'] / settings['max_jump_m'] for c in cycles]
    assert min(fractions) <= 0.4 and max(fractions) >= 0.99
    for c in cycles:
        assert abs(c['achieved_height_m'] - c['target_height_m']) < 0.01, c
    # the maximal jump is the reference jump's
    ref = json.loads((REPO / 'bags' / 'reference_jump' / 'reference.json').read_text())
    assert abs(settings['max_jump_m'] - ref['actual']['jump_height_m']) < 1e-3


@shipped
def test_shipped_drop_jump_falls_lands_takes_off_and_lands() -> None:
    intervals = _custom(SHIPPED, 'contact_intervals_s')
    drop = _custom(SHIPPED, 'cycles')[0]
    t_fall = np.sqrt(2 * 0.30 / MODEL.p.gravity)
    first, second = intervals[0], intervals[1]
    assert 0.15 < first[0] < t_fall + 0.05          # the fall from the box
    assert 0.15 < first[1] - first[0] < 0.6         # landing and push-off
    assert abs(first[1] - drop['liftoff_s']) < 2e-3
    assert second[0] - first[1] > 0.2               # a real flight
    tr = _truth(SHIPPED)
    fy = tr['s'][:, 1]
    land = (tr['t_w'] > first[0]) & (tr['t_w'] < first[0] + 0.2)
    assert 1.5 < fy[land].max() / BW < 6.0


def _cop(tr: dict) -> tuple[np.ndarray, np.ndarray]:
    """Centre of pressure x [m] at the generalized-coordinate instants (ground line)."""
    idx = np.rint(tr['t'] * 1080).astype(int)
    s = tr['s'][idx]
    pos = MODEL.batch(MODEL.positions, tr['q'])
    foot = pos[3][:, :, 0]                          # COM of the foot segment
    return tr['t'], foot[:, 0] + (s[:, 2] - foot[:, 1] * s[:, 0]) / s[:, 1]


@shipped
def test_shipped_stance_sways_and_stays_upright() -> None:
    tr = _truth(SHIPPED)
    t, cop = _cop(tr)
    com, = MODEL.batch(MODEL.com, tr['q'])
    for a, b in _custom(SHIPPED, 'stance_windows_s'):
        sel = (t > a + 1.5) & (t < b - 1.0)
        rng = np.ptp(cop[sel])
        assert 0.001 < rng < 0.06, (a, b, rng)
        assert np.abs(np.degrees(tr['q'][sel, 3])).max() < 20      # trunk upright
        idx = np.rint(t[sel] * 1080).astype(int)
        assert tr['s'][idx, 1].min() > 0.5 * BW                   # both feet loaded
        # the sway is slow: 90 % of the COP's power below 1 Hz
        x = cop[sel] - cop[sel].mean()
        p = np.abs(np.fft.rfft(x)) ** 2
        f = np.fft.rfftfreq(x.size, t[1] - t[0])
        assert p[f <= 1.0].sum() > 0.9 * p.sum()
        # ankle strategy: the COM moves with the COP, within the feet
        last = np.searchsorted(tr['t_anchor'], t[sel] + 1e-9, side='right') - 1
        x0 = tr['anchors'][last, 0]                 # the heel's anchor in force
        assert ((com[sel, 0] > x0) & (com[sel, 0] < x0 + 0.17)).all()


@shipped
def test_shipped_observations_are_truth_plus_bias_plus_noise() -> None:
    obs = read_observations(SHIPPED)
    gw = read_arrays(SHIPPED, '/truth/ground_wrench')
    ga = read_arrays(SHIPPED, '/truth/segment_angles')
    ba = read_arrays(SHIPPED, '/truth/mocap_bias')
    bw_ = read_arrays(SHIPPED, '/truth/force_plate_bias')
    s = np.column_stack([gw.force[:, 0], gw.force[:, 1], gw.torque[:, 2]])
    bias_w = np.column_stack([bw_.force[:, 0], bw_.force[:, 1], bw_.torque[:, 2]])
    bias_a = np.column_stack([ba.column(n) for n in SEGMENTS])
    theta = np.column_stack([ga.column(n) for n in SEGMENTS])
    noise_w = obs.wrench - s - bias_w
    noise_a = obs.angles - theta - bias_a
    np.testing.assert_allclose(np.degrees(noise_a.std(axis=0)), [5, 3, 2, 1], rtol=0.05)
    np.testing.assert_allclose(noise_w.std(axis=0), [0.02 * BW, 0.02 * BW, 0.02 * BW * 0.17],
                               rtol=0.05)
    # bias: angle peaks = noise SD, zero at t = 0; force peaks 2 % BW, zero in flight;
    # moment peak 20 % of the routine's peak moment
    np.testing.assert_allclose(np.abs(bias_a).max(axis=0), np.radians([5, 3, 2, 1]),
                               rtol=1e-4)
    assert np.abs(bias_a[0]).max() == 0.0
    np.testing.assert_allclose(np.abs(bias_w[:, :2]).max(axis=0), 0.02 * BW, rtol=1e-4)
    np.testing.assert_allclose(np.abs(bias_w[:, 2]).max(), 0.2 * np.abs(s[:, 2]).max(),
                               rtol=1e-4)
    # a gain error eps(t) F(t): proportional to the force, so (almost) zero in flight
    flight = s[:, 1] < 1.0
    assert flight.sum() > 500
    eps = np.abs(bias_w[:, :2]) / np.maximum(np.abs(s[:, :2]), 1e-9)
    assert eps[s[:, 1] > 100].max() < 0.2             # a gain (fore-aft: small force)
    assert (np.abs(bias_w[flight, :2]) <= 0.2 * np.abs(s[flight, :2]) + 2.0 ** -12).all()


@pytest.mark.skipif(not SHIPPED_FAULTS.exists(), reason='bags/routine_faults not shipped')
def test_shipped_faults_are_where_their_topics_say() -> None:
    clean = read_observations(SHIPPED)
    obs = read_observations(SHIPPED_FAULTS)
    assert obs.t_angles.size == clean.t_angles.size        # frames keep coming
    assert obs.t_wrench.size == clean.t_wrench.size
    drops = read_arrays(SHIPPED_FAULTS, '/truth/mocap_dropouts')
    epoch = int(bag_info(SHIPPED).custom_data['nmt.trial_epoch_ns'])
    k = np.rint(((drops.stamp_ns - epoch) * 1e-9) * 120).astype(int)
    codes = np.zeros(clean.angles.shape)
    codes[k] = np.column_stack([drops.column(n) for n in SEGMENTS])
    assert np.array_equal(np.isnan(obs.angles), codes != 0)
    occluded = codes == 1
    runs = []     # occlusion lengths per segment, s
    for j in range(4):
        edges = np.diff(np.r_[0, occluded[:, j].astype(int), 0])
        runs += list((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)) / 120)
    assert runs and min(runs) >= 0.04 and max(runs) <= 0.31
    wdrop = read_arrays(SHIPPED_FAULTS, '/truth/force_plate_dropouts')
    kw = np.rint(((wdrop.stamp_ns - epoch) * 1e-9) * 1080).astype(int)
    assert np.array_equal(np.flatnonzero(np.isnan(obs.wrench[:, 1])), np.sort(kw))
    # drift = faulty bias - clean bias - spikes, exactly; present in flight; a few % BW
    bf = read_arrays(SHIPPED_FAULTS, '/truth/force_plate_bias')
    bc = read_arrays(SHIPPED, '/truth/force_plate_bias')
    spikes = np.zeros((obs.t_wrench.size, 3))
    sp = read_arrays(SHIPPED_FAULTS, '/truth/force_plate_spikes')
    ks = np.rint(((sp.stamp_ns - epoch) * 1e-9) * 1080).astype(int)
    spikes[ks] = np.column_stack([sp.force[:, 0], sp.force[:, 1], sp.torque[:, 2]])
    drift = (np.column_stack([bf.force[:, 0], bf.force[:, 1], bf.torque[:, 2]])
             - np.column_stack([bc.force[:, 0], bc.force[:, 1], bc.torque[:, 2]]) - spikes)
    assert 0.01 * BW < np.abs(drift[:, 1]).max() <= 0.05 * BW
    gw = read_arrays(SHIPPED, '/truth/ground_wrench')
    flight = gw.force[:, 1] < 1.0
    assert np.abs(drift[flight, 1]).max() > 0.002 * BW
    assert np.abs(np.diff(drift[:, 1])).max() < 0.001 * BW         # slow
    assert 0.15 * BW < np.abs(spikes).max() < 0.55 * BW


def test_a_plan_that_fails_from_the_last_plan_is_solved_again_from_the_default_guess() -> None:
    """Seed 8's fourth landing (a 9 cm jump after a 20 cm one) was infeasible from the last
    landing's plan and the routine died; a failed warm start now starts again from the
    planner's own guess, both solves counted in the cycle's CPU and iterations."""
    from nmt_ros.study.jump_planning import Plan
    from nmt_ros.study.routine import Cycle, RoutineBuilder

    def plan(success: bool, iterations: int) -> Plan:
        z = np.zeros(2)
        return Plan('landing', z, z, z, z, z, success, 'Solve_Succeeded' if success else
                    'Infeasible_Problem_Detected', iterations, 1.0)

    last = plan(True, 10)
    calls = []

    def solve(guess: Plan | None = None) -> Plan:
        calls.append(guess)
        return plan(guess is None, 30 if guess is None else 900)

    builder = RoutineBuilder.__new__(RoutineBuilder)
    builder.templates, builder.cpu, builder.say = {'landing': last}, {'plan': 0.0}, print
    cycle = Cycle(kind='cmj', target_height_m=0.09, start_s=0.0)
    got = builder._plan(solve, 'landing', 'landing', cycle)
    assert calls == [last, None] and got.success
    assert builder.templates['landing'] is got
    assert (cycle.plan_iterations, cycle.plan_cpu_s, builder.cpu['plan']) == (930, 2.0, 2.0)
    # nothing to fall back to: the failure is an error
    builder.templates = {}
    with pytest.raises(RuntimeError, match='landing plan did not converge'):
        builder._plan(lambda guess=None: plan(False, 5), 'landing', 'landing', cycle)
