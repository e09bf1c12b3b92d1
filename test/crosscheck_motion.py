"""A push-off simulated by our model, shared by the OpenSim cross-check tests.

From the static squat (``solve_static_squat``), the excitations of the hip, knee and ankle
extensors ramp smoothly to full over 0.2 s (flexors switched off, RF and HAMS partly on) and
``simulate_excitations`` integrates the musculoskeletal ODE with its contact springs; the
motion is sampled at 1 kHz until 10 ms after lift-off. Built once per test session.

Also: helpers that run OpenSim in subprocesses (it cannot share a process with casadi).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
import subprocess
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RATE_HZ = 1000.0
RAMP_S = 0.2
AFTER_LIFTOFF_S = 0.01
# Target excitations of the push-off (data-file muscle order is checked below).
TARGET = {'gmax': 1.0, 'ilpso': 0.0, 'hams': 0.6, 'bfsh': 0.0, 'rf': 0.3, 'vas': 1.0,
          'gas': 1.0, 'sol': 1.0, 'ta': 0.0}


@dataclass(frozen=True)
class Motion:
    t: np.ndarray            # [n] s
    q: np.ndarray            # [n, 6]
    qd: np.ndarray           # [n, 6]
    a: np.ndarray            # [n, 9]
    x0: np.ndarray           # [2] contact anchors
    tau: np.ndarray          # [n, 3] muscle joint torques (the truth for ID)
    f: np.ndarray            # [n, 9] musculotendon forces
    points: np.ndarray       # [n, 2, 2] contact points (rows x, y; heel, toe)
    forces: np.ndarray       # [n, 2, 2] contact forces
    liftoff_s: float
    build_s: float


@lru_cache(maxsize=1)
def push_off() -> Motion:
    from nmt_ros.model.jumper import default_model
    from nmt_ros.model.simulation import simulate_excitations
    from nmt_ros.model.squat import solve_static_squat

    start = time.perf_counter()
    model = default_model()
    assert tuple(model.p.muscles.names) == tuple(TARGET)
    squat = solve_static_squat(model)
    target = np.array(list(TARGET.values()))

    def excitation(t: float) -> np.ndarray:
        s = min(max(t / RAMP_S, 0.0), 1.0)
        return squat.u + s * s * (3.0 - 2.0 * s) * (target - squat.u)

    x_init = np.concatenate([squat.q, np.zeros(6), squat.a])
    t_end = 0.4
    t_eval = np.arange(0.0, t_end, 1.0 / RATE_HZ)
    sim = simulate_excitations(model, x_init, squat.x0, excitation, t_end, t_eval=t_eval)
    assert sim.success, sim.message
    assert np.isfinite(sim.liftoff_s)
    keep = sim.t <= sim.liftoff_s + AFTER_LIFTOFF_S
    t = sim.t[keep]
    q, qd, a = sim.x[keep, :6], sim.x[keep, 6:12], sim.x[keep, 12:]
    tau, f = model.batch(model.muscle_torques, q, qd, a)
    points = model.batch(model.positions, q)[4]
    forces, = model.batch(model.contact_forces, q, qd, sim.x0)
    return Motion(t=t, q=q, qd=qd, a=a, x0=sim.x0, tau=tau, f=f, points=points, forces=forces,
                  liftoff_s=sim.liftoff_s, build_s=time.perf_counter() - start)


def run_python(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python ARGS`` in the repository (a fresh process: OpenSim may be imported there)."""
    proc = subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


def crosscheck(*args: str) -> subprocess.CompletedProcess:
    return run_python('-m', 'nmt_ros.osim.crosscheck', *args)


def export_model(path: Path) -> Path:
    run_python('-m', 'nmt_ros.cli.main', 'export-osim', '--out', str(path))
    assert path.is_file()
    return path
