"""OpenSim work of the lab import, run in a subprocess (OpenSim cannot share a process with
casadi): ``python -m nmt_ros.osim.subject`` measures a model and poses it along an IK file."""
from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile

import numpy as np


def _run(args: list[str]) -> None:
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, '-m', 'nmt_ros.osim.subject', *args],
                          capture_output=True, text=True, env=env, timeout=600)
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr or '').splitlines() if 'vtp' not in ln]
        raise ValueError('OpenSim: ' + ('\n'.join(lines[-8:]) or proc.stdout).strip())


def measure_model(model: str | os.PathLike) -> dict:
    """Masses, segment lengths, markers and landmarks of an .osim in its default pose."""
    if not Path(model).exists():
        raise ValueError(f'{model}: no such model file')
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / 'measure.json'
        _run(['measure', '--model', str(model), '--out', str(out)])
        return json.loads(out.read_text())


def ik_landmarks(model: str | os.PathLike, ik: str | os.PathLike) -> dict[str, np.ndarray]:
    """The model's landmarks in ground [n, 3] at every row of an IK .mot (time under 'time')."""
    for path in (model, ik):
        if not Path(path).exists():
            raise ValueError(f'{path}: no such file')
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / 'kinematics.npz'
        _run(['kinematics', '--model', str(model), '--ik', str(ik), '--out', str(out)])
        with np.load(out) as d:
            return {k: d[k] for k in d.files}


def subject_moment_arms(model: str | os.PathLike, spec: dict) -> dict:
    """``python -m nmt_ros.osim.subject moment-arms`` on a model (see
    ``nmt_ros.osim.subject.group_moment_arms`` for ``spec`` and the result)."""
    if not Path(model).exists():
        raise ValueError(f'{model}: no such model file')
    with tempfile.TemporaryDirectory() as tmp:
        spec_file, out = Path(tmp) / 'spec.json', Path(tmp) / 'arms.json'
        spec_file.write_text(json.dumps(spec))
        _run(['moment-arms', '--model', str(model), '--spec', str(spec_file), '--out', str(out)])
        return json.loads(out.read_text())
