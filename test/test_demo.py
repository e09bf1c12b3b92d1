"""``nmt demo`` (what ``make demo`` runs) end to end: exit code, report, summary.json."""
from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'


def test_demo_runs_the_graph_and_reports(tmp_path):
    out = tmp_path / 'demo'
    (out / 'recording').mkdir(parents=True)
    (out / 'recording' / 'stale.txt').write_text('a previous demo')   # replaced, not refused
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.cli.main', 'demo', '--out', str(out),
                           '--bag', str(BAG)],
                          capture_output=True, text=True, timeout=180, env=dict(os.environ))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = proc.stdout
    for words in ('jump height: tracked motion', 'joint torques vs truth',
                  'muscle forces vs truth', 'live graph vs batch trackers',
                  'latency observation -> joint_torques', 'latency observation -> muscle_forces',
                  'CPU share', 'messages (published / recorded)', str(out / 'recording')):
        assert words in text, words
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['lossless'] and summary['graph']['returncode'] == 0
    # the live graph computes what the same estimators compute offline on the bag (Stage 1
    # updates on data time; Stage 2 windows on fixed instants): equal up to rounding
    assert max(summary['vs_batch']['torque_rms_pct_peak'].values()) < 0.01
    assert max(summary['vs_batch']['muscle_force_rms_pct_f0'].values()) < 2.0
    assert summary['vs_batch']['samples'] == summary['vs_batch']['of']
    assert set(summary['phases']) == {'refined', 'low_latency'}
    assert set(summary['cpu']) == {'observation_publisher', 'skeletal_tracker',
                                   'muscle_tracker', 'recorder'}
    assert (out / 'recording' / 'metadata.yaml').exists()
    assert not (out / 'recording' / 'stale.txt').exists()
