"""OpenSim work of the lab import, run in a subprocess (OpenSim cannot share a process with
casadi): ``python -m nmt_ros.osim.subject`` measures a model and poses it along an IK file."""
from __future__ import annotations

import hashlib
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
    ``nmt_ros.osim.subject.group_moment_arms`` for ``spec`` and the result), kept in the
    machine's cache (``moment_arms_cache_file``): they depend on the model file, the spec,
    the code that measures them and OpenSim's version alone, not on the trial, and cost
    ~100 s of OpenSim per model on a 2-core machine, so the trials of one subject after
    the first import in seconds."""
    if not Path(model).exists():
        raise ValueError(f'{model}: no such model file')
    cached = moment_arms_cache_file(model, spec)
    try:
        return json.loads(cached.read_text())
    except (OSError, ValueError):        # not cached yet (or unreadable): measured again
        pass
    with tempfile.TemporaryDirectory() as tmp:
        spec_file, out = Path(tmp) / 'spec.json', Path(tmp) / 'arms.json'
        spec_file.write_text(json.dumps(spec))
        _run(['moment-arms', '--model', str(model), '--spec', str(spec_file), '--out', str(out)])
        text = out.read_text()
        arms = json.loads(text)
    try:                                  # written whole, then renamed: never half a file
        staged = cached.with_suffix(f'.{os.getpid()}.tmp')
        staged.write_text(text)
        os.replace(staged, cached)
    except OSError:
        pass
    return arms


def moment_arms_cache_file(model: str | os.PathLike, spec: dict) -> Path:
    """Where ``subject_moment_arms`` keeps a model's moment arms: a file in the cache
    (``model.compiled.cache_dir``'s root, ``osim/``) named by the hash of the model file's
    bytes, the spec, the measuring code and OpenSim's installed version."""
    from importlib import metadata

    from nmt_ros.model.compiled import cache_dir

    try:
        opensim = metadata.version('opensim')
    except metadata.PackageNotFoundError:
        opensim = 'unknown'
    code = (Path(__file__).parent / 'subject.py').read_bytes()
    digest = hashlib.sha256(Path(model).read_bytes() + json.dumps(spec, sort_keys=True).encode()
                            + code + opensim.encode()).hexdigest()
    folder = cache_dir().parent / 'osim'
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f'moment_arms_{digest[:24]}.json'
