"""The camera's frame clock recovered from stamps: against the true frame instants of
synthetic streams (uniform, jittered, drifting, with dropped frames, reset)."""
from __future__ import annotations

import numpy as np
import pytest

from nmt_ros.model.jumper import default_model
from nmt_ros.tracking.frame_clock import FrameClock
from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator

T = 1 / 120.0


def instants(stamps: np.ndarray, clock: FrameClock) -> np.ndarray:
    return np.array([clock.instant(float(s)) for s in stamps])


def test_uniform_stamps_pass_through_bit_for_bit():
    for start, period in ((0.0, T), (12.345, 1 / 100.0), (3.0, 1 / 60.0)):
        t = start + np.arange(3000) * period
        t = np.delete(t, np.r_[500:520])                 # dropped frames counted, not moved
        clock = FrameClock(period)
        assert np.array_equal(instants(t, clock), t)
        assert clock.regularised == 0 and clock.resyncs == 0


@pytest.mark.parametrize('drift', [1.0, 1.001])
def test_jittered_stamps_are_put_back_on_the_frame_clock(drift):
    """+-2 ms of arrival jitter (a quarter of a frame at 120 Hz), a camera clock 0.1 %
    slower than nominal, 30 and 10 dropped frames: the instants within 0.25 ms RMS of
    the true frame instants (the stamps: 1.15 ms), always increasing."""
    rng = np.random.default_rng(11)
    true = np.arange(7200) * T * drift
    true = np.delete(true, np.r_[100:130, 3000:3010])
    stamps = true + rng.uniform(-0.002, 0.002, true.size)
    clock = FrameClock(T)
    got = instants(stamps, clock)
    settled = slice(200, None)
    err_ms = (got - true)[settled] * 1e3
    raw_ms = (stamps - true)[settled] * 1e3
    assert np.sqrt((err_ms ** 2).mean()) < 0.25, np.sqrt((err_ms ** 2).mean())
    assert np.sqrt((raw_ms ** 2).mean()) > 1.0
    assert np.abs(err_ms).max() < 1.0
    assert (np.diff(got) > 0).all()
    assert np.sqrt(((got - true)[10:100] ** 2).mean()) < 0.4e-3   # a fresh clock settles
    assert clock.resyncs == 0
    assert abs(clock.period_s / (T * drift) - 1) < 2e-4
    assert 1.0 < clock.jitter_rms_ms < 1.4              # uniform +-2 ms: 1.15 ms RMS


def test_a_clock_reset_restarts_the_clock_at_the_stamp():
    from nmt_ros.tracking.frame_clock import RESYNC_AFTER

    t = np.r_[np.arange(100) * T, 100 * T + 0.47 * T + np.arange(100) * T]   # ~half a frame
    clock = FrameClock(T)
    got = instants(t, clock)
    assert clock.resyncs == 1
    run = slice(100, 100 + RESYNC_AFTER - 1)     # the run that tells a reset from jitter
    assert np.array_equal(np.delete(got, np.r_[run]), np.delete(t, np.r_[run]))
    assert np.abs(got[run] - t[run]).max() < 0.5 * T
    assert (np.diff(got) > 0).all()


@pytest.mark.parametrize('jitter_ms, clock_better', [(3.0, True), (5.0, False)])
def test_jitter_too_large_to_tell_frames_apart_leaves_the_stamps(jitter_ms, clock_better):
    """+-3 ms at 120 Hz (0.36 of a period): the clock's instants within 0.4 ms RMS of the
    frames. +-5 ms: a stamp can sit nearer the next frame than its own, so the clock
    would assign frames wrongly; the stamps are returned (after the first 50 frames) and
    the instants stay increasing."""
    rng = np.random.default_rng(3)
    true = np.arange(3000) * T
    stamps = true + rng.uniform(-jitter_ms, jitter_ms, true.size) * 1e-3
    keep = np.r_[True, np.diff(stamps) > 0]
    true, stamps = true[keep], stamps[keep]
    clock = FrameClock(T)
    got = instants(stamps, clock)
    assert (np.diff(got) > 0).all()
    if clock_better:
        assert np.sqrt(np.mean((got - true)[100:] ** 2)) < 0.4e-3
        assert clock.passed_through == 0
    else:
        assert np.array_equal(got[100:], stamps[100:])
        assert clock.passed_through > 0.9 * true.size


def test_bad_periods_are_refused():
    with pytest.raises(ValueError, match='frame period'):
        FrameClock(0.0)
    with pytest.raises(ValueError, match='alpha'):
        FrameClock(T, alpha=0.0)


def test_the_estimator_takes_mocap_samples_at_the_clocks_instants_and_says_so():
    model = default_model()
    rng = np.random.default_rng(5)
    true = np.arange(240) * T
    stamps = true + rng.uniform(-0.002, 0.002, true.size)
    est = MovingHorizonEstimator(model)
    for s in stamps:
        est.add_angles(float(s), np.zeros(4))
    taken = np.array([p[0] for p in est.pending_angles])
    assert np.sqrt(((taken - true)[120:] ** 2).mean()) < 0.4e-3
    said = [e for e in est.events if 'jitter' in e.message]
    assert len(said) == 1 and said[0].level == 'warn'
    assert 0.8 < said[0].values['stamp_jitter_rms_ms'] < 1.6
    with pytest.raises(ValueError, match='not after the previous'):
        est.add_angles(float(stamps[-1]), np.zeros(4))   # a repeated stamp is not a frame


def test_a_known_camera_latency_is_taken_off_the_stamps():
    from nmt_ros.tracking.moving_horizon.settings import MovingHorizonSettings

    model = default_model()
    true = 3.0 + np.arange(120) * T
    est = MovingHorizonEstimator(model, MovingHorizonSettings(angle_latency_s=0.012))
    for s in true + 0.012:                       # stamped on arrival, 12 ms after the frame
        est.add_angles(float(s), np.zeros(4))
    taken = np.array([p[0] for p in est.pending_angles])
    assert np.abs(taken - true).max() < 1e-12
    with pytest.raises(ValueError, match='angle_latency_s'):
        MovingHorizonEstimator(model, MovingHorizonSettings(angle_latency_s=-0.01))
