"""The lift-off rule (model/contact.py): one rule for the truth, the simulations and the
trackers, online and batch. Checked against closed forms (a force ramp) and against itself
fed in arbitrary blocks (online = batch)."""
import numpy as np
from scipy.integrate import solve_ivp

from nmt_ros.model.contact import LiftoffDetector, liftoff_event, liftoff_time


def ramp(t):
    """Loaded at 800 N, falls at 4000 N/s from t = 0.1 s: crosses 20 N at 0.295 s."""
    return np.where(t < 0.1, 800.0, 800.0 - 4000.0 * (t - 0.1))


def test_interpolated_instant_of_a_ramp_is_exact():
    t = np.arange(0, 400) / 1080
    assert abs(liftoff_time(t, ramp(t), 20.0) - 0.295) < 1e-12
    assert abs(liftoff_time(t, ramp(t), 1.0) - (0.1 + 799 / 4000)) < 1e-12


def test_online_in_any_blocks_equals_batch():
    rng = np.random.default_rng(0)
    t = np.arange(0, 400) / 1080
    fy = ramp(t) + rng.normal(0, 5, t.size)
    whole = LiftoffDetector(20.0)
    i_whole = whole.update(t, fy)
    assert t[i_whole] == whole.known_s and fy[i_whole] <= 20.0 < fy[i_whole - 1]
    for _ in range(20):
        cuts = np.sort(rng.choice(np.arange(1, t.size), size=12, replace=False))
        det = LiftoffDetector(20.0)
        known_at = [det.update(tb, fb) for tb, fb in zip(np.split(t, cuts), np.split(fy, cuts))]
        assert det.liftoff_s == whole.liftoff_s and det.known_s == whole.known_s
        assert sum(k is not None for k in known_at) == 1   # reported once, in its block


def test_lift_off_needs_loading_first():
    t = np.arange(0, 100) / 1000
    rising_then_falling = np.interp(t, [0, 0.02, 0.05, 0.09], [0, 0, 100, 0])
    assert 0.05 < liftoff_time(t, rising_then_falling, 1.0) < 0.09   # not at t = 0
    assert np.isnan(liftoff_time(t, np.zeros_like(t), 1.0))           # never loaded
    assert np.isnan(liftoff_time(t, np.full_like(t, 700.0), 1.0))     # never unloaded
    nan_gap = np.full_like(t, 700.0)
    nan_gap[60] = np.nan               # NaN is not above: lift-off known there, instant unknown
    det = LiftoffDetector(1.0)
    assert det.update(t, nan_gap) == 60 and det.known_s == t[60] and np.isnan(det.liftoff_s)


def test_continuous_event_is_the_same_rule():
    """solve_ivp with the event on fy(y) = y, ydot = -4000 N/s from 800 N: lift-off at
    (800 - 1) / 4000 s, as the sampled rule on the same ramp."""
    event = liftoff_event(lambda y: float(y[0]), 1.0)
    sol = solve_ivp(lambda _t, y: [-4000.0], (0.0, 0.4), [800.0], events=event, rtol=1e-12,
                    atol=1e-12)
    assert abs(sol.t_events[0][0] - 799 / 4000) < 1e-9
    t = np.arange(0, 433) / 1080
    assert abs(liftoff_time(t, 800 - 4000 * t, 1.0) - sol.t_events[0][0]) < 1e-9
