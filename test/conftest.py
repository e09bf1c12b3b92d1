"""Shared pytest fixtures for nmt_ros.

The ROS environment is fixed here, at import time, before any test module imports rclpy:
DDS stays on loopback and this test session gets a ROS_DOMAIN_ID of its own (1..100, from
the pid; ``NMT_TEST_DOMAIN_ID`` overrides), so parallel sessions on one machine do not see
each other's topics. ``AMENT_PREFIX_PATH`` points at the venv so the .msg files are found.
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
import sys

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_LOCALHOST_ONLY'] = '1'
os.environ['ROS_DOMAIN_ID'] = os.environ.get('NMT_TEST_DOMAIN_ID', str(1 + os.getpid() % 100))
os.environ['AMENT_PREFIX_PATH'] = sys.prefix
# one BLAS thread (set before numpy loads OpenBLAS): see the Makefile
for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')


@pytest.fixture
def ros_context():
    """A private, initialised rclpy Context (shut down after the test)."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def tmp_bag(tmp_path: Path):
    """Factory of fresh (not yet existing) bag folder paths: ``tmp_bag('name') -> Path``."""
    counter = itertools.count()

    def make(name: str = 'bag') -> Path:
        return tmp_path / f'{name}_{next(counter)}'

    return make


_BATCH_SAMPLES: list[int] = []


def batch_samples() -> int:
    """Output samples of Stage 1 run offline on the shipped bag with the graph's default
    estimator (the moving-horizon estimator fed the whole recording: what a full live run
    must match, instant for instant)."""
    if not _BATCH_SAMPLES:
        from nmt_ros.io.trial_bag import read_observations
        from nmt_ros.model.jumper import default_model
        from nmt_ros.tracking.moving_horizon.estimator import estimate

        obs = read_observations(Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump')
        run = estimate(default_model(), obs.t_angles, obs.angles, obs.t_wrench, obs.wrench)
        _BATCH_SAMPLES.append(int(run.refined.t.size))
    return _BATCH_SAMPLES[0]


REFERENCE_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'


@pytest.fixture(scope='session')
def model():
    """The jumper model built from the shipped data file (once per session)."""
    from nmt_ros.model.jumper import default_model

    return default_model()


@pytest.fixture(scope='session')
def truth():
    """The shipped reference jump's truth (``/truth/*`` of bags/reference_jump)."""
    from nmt_ros.io.trial_bag import read_truth

    return read_truth(REFERENCE_BAG)


@pytest.fixture(scope='session')
def obs():
    """The shipped reference jump's observations."""
    from nmt_ros.io.trial_bag import read_observations

    return read_observations(REFERENCE_BAG)


@pytest.fixture(scope='session', autouse=True)
def compiled_kernels():
    """The C kernels of the graphs the suite runs (the shipped jumper's bags and the real drop
    jump's subject at its rates) compiled, or loaded from the machine's cache, before any test
    starts a node. On a fresh machine each takes 15-30 s to compile; inside a node or launch
    test that time counted against the test's waits (a first CI run on a cold cache failed 7
    of them, the second passed)."""
    from nmt_ros.cli.launch import bag_parameters
    from nmt_ros.model.subject import load_subject_model
    from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator
    from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings
    from nmt_ros.tracking.stage2 import NeuromuscularTracker, load_stage2_settings
    from nmt_ros.tracking.streaming import Stage2Stream

    repo = Path(__file__).resolve().parents[1]
    for bag in (repo / 'bags' / 'reference_jump', repo / 'bags' / 'real_dropjump'):
        params = bag_parameters(bag)['skeletal_tracker']
        model = load_subject_model(bag)
        MovingHorizonEstimator(model, MovingHorizonSettings().with_(
            angle_rate_hz=params['angle_rate_hz'], wrench_rate_hz=params['wrench_rate_hz']))
        Stage2Stream(model, NeuromuscularTracker(model, load_stage2_settings()),
                     rate_hz=params['wrench_rate_hz'])
