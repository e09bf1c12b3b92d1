"""The batch NMT pipeline and the CLI entry points of the study (issues 4 and 5)."""
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from nmt_ros.io.bags import bag_info, read_arrays
from nmt_ros.io.trial_bag import read_observations, write_trial_bag
from nmt_ros.model.parameters import JOINTS, MUSCLES, SEGMENTS

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / 'bags' / 'reference_jump'


def nmt(*args, timeout=600):
    return subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope='module')
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp('reproduce')
    proc = nmt('reproduce', '--out', str(out), '--quick', '--force')
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return out, proc.stdout


def test_reproduce_writes_metrics_in_the_interface_schema(reproduced):
    out, stdout = reproduced
    m = json.loads((out / 'metrics.json').read_text())
    assert set(m['actual']) >= {'jump_height_m', 'liftoff_s'}
    assert set(m['po']) >= {'cpu_s', 'wall_s', 'iterations', 'jump_height_m'}
    skt = m['skt']
    assert set(skt['torque_rms_nm']) == set(JOINTS)
    assert set(skt['angle_rms_deg']) == set(SEGMENTS)
    assert set(skt['grf_rms_n']) == {'fore_aft', 'vertical'}
    assert np.isfinite(skt['moment_rms_nm']) and np.isfinite(skt['cpu_s'])
    ivd = m['ivd']
    assert set(ivd['torque_rms_nm']) == set(JOINTS)
    assert np.isfinite(ivd['liftoff_s']) and np.isfinite(ivd['jump_height_m'])
    n = m['nmt']
    assert set(n['torque_rms_nm']) == set(JOINTS)
    assert set(n['muscle_force_rms_n']) == set(MUSCLES)
    for key in ('cpu_s', 'jump_height_m', 'liftoff_s'):
        assert np.isfinite(n[key]), key
    # The studies around it, and the human-readable outputs.
    assert len(m['seeds']['seeds']) == 2 and m['noise_sweep'] and m['stage2_windows']
    assert m['jacobians']['max_torque_difference_rel_peak']['hip'] < 1e-4
    for name in ('report.md', 'fig3_skeletal_tracking.png', 'fig4_muscles.png',
                 'fig5_nmt.png'):
        assert (out / name).stat().st_size > 1000, name
    assert '| actual jump height |' in (out / 'report.md').read_text()
    assert 'actual jump' in stdout


def test_estimates_bag_is_stamped_with_observation_time(reproduced):
    out, _ = reproduced
    est = out / 'estimates'
    topics = {t.name: t.message_count for t in bag_info(est).topics}
    for topic in ('/nmt/skeletal/joint_torques', '/nmt/skeletal/segment_angles',
                  '/nmt/skeletal/generalized_coordinates',
                  '/nmt/skeletal/ground_wrench', '/nmt/muscle/forces',
                  '/nmt/muscle/activations', '/nmt/muscle/excitations'):
        assert topics.get(topic, 0) > 100, topic
    obs_stamps = read_arrays(BAG, '/force_plate/wrench').stamp_ns
    tq = read_arrays(est, '/nmt/skeletal/joint_torques')
    assert set(tq.stamp_ns) <= set(obs_stamps)          # every estimate at an observation time
    gc = read_arrays(est, '/nmt/skeletal/generalized_coordinates')
    seg = read_arrays(est, '/nmt/skeletal/segment_angles')
    np.testing.assert_array_equal(gc.stamp_ns, tq.stamp_ns)
    np.testing.assert_array_equal(gc.position[:, :4], seg.position)   # q = [angles, ankle]
    forces = read_arrays(est, '/nmt/muscle/forces')
    assert forces.names == MUSCLES and np.isfinite(forces.effort).all()
    # Muscles pull: the DeGroote fibre damping (and its force-velocity curve beyond the
    # maximum shortening speed) allow at most a small push, as in the truth (VAS -2.2 % F0).
    from nmt_ros.model.jumper import default_model
    f0 = default_model().p.muscles.f0
    assert (forces.effort > -0.03 * f0).all()


def test_track_works_on_a_bag_without_truth(tmp_path):
    """A lab bag (observations only): estimates, no metrics."""
    obs = read_observations(BAG)
    lab = tmp_path / 'lab'
    write_trial_bag(lab, obs)
    out = tmp_path / 'out'
    proc = nmt('track', str(lab), '--out', str(out), '--no-figures')
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / 'estimates' / 'metadata.yaml').exists()
    assert (out / 'opensim' / 'stage2_states.sto').is_file()
    assert (out / 'opensim' / 'stage1_grf.xml').is_file()
    assert not (out / 'metrics.json').exists()


def test_track_refuses_a_wrench_cutoff_that_is_not_positive(tmp_path):
    proc = nmt('track', str(BAG), '--out', str(tmp_path / 'o'), '--stage1', 'mhe',
               '--wrench-cutoff', '-5')
    assert proc.returncode == 2
    assert 'nmt track: error: the wrench cut-off -5.0 Hz must be positive' in proc.stderr
    assert 'Traceback' not in proc.stderr


def test_track_reports_a_bag_without_observations(tmp_path):
    proc = nmt('track', str(BAG / 'does_not_exist'), '--out', str(tmp_path / 'o'))
    assert proc.returncode != 0
    assert 'does_not_exist' in (proc.stderr + proc.stdout)
