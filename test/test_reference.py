"""The reference jump (PO), the shipped truth and the observation bag (issue 3)."""
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import yaml

from nmt_ros.io.bags import read_arrays
from nmt_ros.io.opensim_files import read_table
from nmt_ros.io.trial_bag import read_observations
from nmt_ros.model.parameters import JOINTS, SEGMENTS
from nmt_ros.model.simulation import simulate_excitations
from nmt_ros.study.observations import ObservationSettings, make_observations
from nmt_ros.study.reference import POSettings, excitation_at, make_reference

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / 'bags' / 'reference_jump'




@pytest.fixture(scope='module')
def record():
    return json.loads((BAG / 'reference.json').read_text())


def test_quick_po_converges_from_every_start_and_the_simulation_agrees(model):
    """A coarse multi-start PO reaches one optimum that a stiff forward simulation reproduces."""
    ref = make_reference(model, POSettings(n_intervals=40), starts=3, coarse_intervals=20)
    c = ref.checks
    assert c['starts_converged'] == 3
    assert c['start_apex_spread_m'] < 1e-4
    assert abs(c['mesh_refinement_apex_change_m']) < 0.005
    assert abs(c['simulation_vs_optimiser_apex_m']) < 0.003
    assert 0.15 < c['jump_height_m'] < 0.40      # a human-range squat jump
    # Proximal-to-distal recruitment: hip extensors before knee before ankle extensors.
    u = ref.po.excitation_nodes
    first = [int(np.argmax(u[i] > 0.5)) for i in range(9)]
    gmax, vas, sol = 0, 5, 7
    assert first[gmax] <= first[vas] <= first[sol]


def test_shipped_truth_is_the_forward_simulation_of_the_optimal_excitations(model, truth,
                                                                           record):
    """Re-integrating the PO's excitations with another integrator reproduces the truth."""
    nodes = np.asarray(record['po']['excitation_nodes'])
    tf = record['po']['tf_s']
    x_init = np.concatenate([truth.q[0], truth.qd[0], truth.a[0]])
    sim = simulate_excitations(model, x_init, truth.x0, lambda t: excitation_at(nodes, tf, t),
                               float(truth.t[-1]), t_eval=truth.t, rtol=1e-11, atol=1e-12)
    contact = truth.t <= truth.liftoff_s
    ang = np.degrees(np.abs(sim.x[contact, :4] - truth.q[contact, :4])).max()
    s, = model.batch(model.contact_outputs, sim.x[:, :6], sim.x[:, 6:12], truth.x0)
    force = np.abs(s[contact, :2] - truth.s[contact, :2]).max()
    assert ang < 0.1, ang
    assert force < 1.0, force
    assert abs(sim.liftoff_s - truth.liftoff_s) < 1e-4
    # The recorded jump height is the ballistic apex from lift-off.
    i = int(np.searchsorted(sim.t, sim.liftoff_s))
    h = model.jump_height(sim.x[i, :6], sim.x[i, 6:12])['height_m']
    assert abs(h - record['actual']['jump_height_m']) < 2e-3


def test_observation_noise_and_bias_follow_the_specification(model, truth):
    """Per channel: noise SD as specified (pooled over seeds), bias 0 at t = 0, force bias 0
    at lift-off, bias peaks equal the noise SD (angles, forces) and 20 % of the peak moment."""
    bw = model.p.body_weight
    noises_a, noises_w = [], []
    for seed in range(40):
        obs, comp = make_observations(truth, ObservationSettings(seed=seed), body_weight=bw)
        noises_a.append(obs.angles - truth.q[comp['angle_index'], :4] - comp['angle_bias'])
        noises_w.append(obs.wrench - truth.s[comp['wrench_index']] - comp['wrench_bias'])
        np.testing.assert_allclose(comp['angle_bias'][0], 0.0, atol=1e-12)
        np.testing.assert_allclose(comp['wrench_bias'][0], 0.0, atol=1e-12)
        after = obs.t_wrench >= truth.liftoff_s
        np.testing.assert_allclose(comp['wrench_bias'][after], 0.0, atol=1e-9)
        np.testing.assert_allclose(np.abs(comp['angle_bias']).max(axis=0),
                                   np.radians([5, 3, 2, 1]), rtol=1e-9)
        peak_m = np.abs(truth.s[truth.t <= truth.liftoff_s, 2]).max()
        np.testing.assert_allclose(np.abs(comp['wrench_bias']).max(axis=0),
                                   [0.02 * bw, 0.02 * bw, 0.2 * peak_m], rtol=1e-3)
    sd_a = np.degrees(np.concatenate(noises_a).std(axis=0))
    sd_w = np.concatenate(noises_w).std(axis=0)
    np.testing.assert_allclose(sd_a, [5, 3, 2, 1], rtol=0.05)
    np.testing.assert_allclose(sd_w, [0.02 * bw, 0.02 * bw, 0.02 * bw * 0.17], rtol=0.05)


def test_shipped_bag_noise_matches_its_bias_topics_and_the_specification(model, truth):
    """The shipped observations = truth + published bias + noise of the specified SD."""
    obs = read_observations(BAG)
    bias_a = read_arrays(BAG, '/truth/mocap_bias')
    bias_w = read_arrays(BAG, '/truth/force_plate_bias')
    ia = np.rint(obs.t_angles * 1080).astype(int)
    iw = np.rint(obs.t_wrench * 1080).astype(int)
    na = obs.angles - truth.q[ia, :4] - np.column_stack([bias_a.column(n) for n in SEGMENTS])
    nw = obs.wrench - truth.s[iw] - np.column_stack([bias_w.force[:, 0], bias_w.force[:, 1],
                                                     bias_w.torque[:, 2]])
    bw = model.p.body_weight
    # 30 angle samples per channel: the sample SD's relative standard error is ~13 %; pool
    # the channels (normalised by their SD) for a 10 % check, and each wrench channel has 269.
    z = np.degrees(na) / np.array([5, 3, 2, 1])
    assert abs(z.std() - 1) < 0.10
    np.testing.assert_allclose(nw.std(axis=0), [0.02 * bw, 0.02 * bw, 0.02 * bw * 0.17],
                               rtol=0.10)


def test_bag_layout_counts_and_readers(truth):
    """120 Hz and 1080 Hz counts over the duration; metadata v9 fields; three readers."""
    meta = yaml.safe_load((BAG / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    for key in ('version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
                'topics_with_message_count', 'compression_format', 'compression_mode',
                'relative_file_paths', 'files', 'custom_data', 'ros_distro'):
        assert key in meta, key
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    duration = truth.t[-1]
    assert counts['/mocap/segment_angles'] == int(np.floor(duration * 120 + 1e-6)) + 1
    assert counts['/force_plate/wrench'] == int(np.floor(duration * 1080 + 1e-6)) + 1
    for t in meta['topics_with_message_count']:
        assert t['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    # rosbags (independent reader) decodes every message.
    from rosbags.highlevel import AnyReader
    n = 0
    with AnyReader([BAG]) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    assert n == meta['message_count']
    # mcap_ros2 decodes every message too.
    from mcap_ros2.reader import read_ros2_messages
    mcap = BAG / meta['relative_file_paths'][0]
    assert sum(1 for _ in read_ros2_messages(str(mcap))) == meta['message_count']
    # ...and rclpy's own deserialisation (what ros2 bag play and the nodes use).
    from nmt_ros.io.bags import read_bag
    assert sum(1 for _ in read_bag(BAG)) == meta['message_count']


def test_opensim_inverse_dynamics_on_the_truth_files_gives_the_truth_torques(tmp_path, truth):
    """OpenSim's InverseDynamicsTool on truth.sto + truth_grf.xml with the exported model."""
    osim = tmp_path / 'jumper.osim'
    subprocess.run([sys.executable, '-m', 'nmt_ros.osim.export', '--out', str(osim)],
                   check=True, cwd=REPO, capture_output=True, timeout=300)
    out = tmp_path / 'id.sto'
    subprocess.run([sys.executable, '-m', 'nmt_ros.osim.crosscheck', 'id', '--coordinates',
                    str(BAG / 'truth.sto'), '--external-loads', str(BAG / 'truth_grf.xml'),
                    '--out-sto', str(out), '--model', str(osim)],
                   check=True, cwd=REPO, capture_output=True, timeout=300)
    table = read_table(out)
    cols = {name: table.column(f'{coord}_moment') for name, coord in
            zip(JOINTS, ('ankle_angle', 'knee_angle', 'hip_flexion'))}
    contact = (truth.t <= truth.liftoff_s) & (truth.t <= truth.t[-6])  # spline end effects
    for j, name in enumerate(JOINTS):
        tau_os = np.interp(truth.t, table.time, cols[name])
        peak = np.abs(truth.tau[contact, j]).max()
        err = np.abs(tau_os[contact] - truth.tau[contact, j]).max() / peak
        worst = truth.t[contact][np.argmax(np.abs(tau_os[contact] - truth.tau[contact, j]))]
        print(f'OpenSim ID vs truth, {name}: max error {100 * err:.3f} % of peak at {worst:.4f} s')
        assert err < 0.02, (name, err)


def test_nmt_reference_quick_writes_the_bag_and_its_companions(tmp_path):
    """`nmt reference --quick`: a complete, readable reference folder (bag + files + figure)."""
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'reference', '--out',
                           str(tmp_path), '--quick', '--seed', '7'], cwd=REPO,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    folder = tmp_path / 'reference_jump'
    for name in ('metadata.yaml', 'reference_jump_0.mcap', 'reference.json', 'truth.sto',
                 'truth_states.sto', 'truth_grf.mot', 'truth_grf.xml', 'reference_jump.png'):
        assert (folder / name).stat().st_size > 100, name
    record = json.loads((folder / 'reference.json').read_text())
    assert record['po']['converged'] and record['po']['iterations'] > 0
    assert record['quick'] is True
    assert 'jump height' in proc.stdout and 'CPU' in proc.stdout
    obs = read_observations(folder)
    assert obs.t_angles.size > 20 and np.isfinite(obs.wrench).all()
    # A second run into the same place refuses to overwrite without --force.
    again = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'reference', '--out',
                            str(tmp_path), '--quick'], cwd=REPO, capture_output=True,
                           text=True, timeout=600)
    assert again.returncode == 2 and 'exists' in again.stderr
