"""Saturated force-plate channels: found on synthetic impacts clipped at a known level,
never on unclipped noisy, thresholded or quantised loads; taken as missing by the
estimator and said on its events."""
from __future__ import annotations

import numpy as np

from nmt_ros.model.jumper import default_model
from nmt_ros.tracking.moving_horizon.estimator import MovingHorizonEstimator
from nmt_ros.tracking.plate_saturation import PlateSaturation

BW = 700.0
FS = 1080.0


def impacts(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """5 s at 1080 Hz: quiet stance, three landing impacts peaking at 3.5 BW, flights
    thresholded to exact zeros; 2 % BW noise on every channel."""
    t = np.arange(int(5 * FS)) / FS
    fy = np.full(t.size, BW)
    for t0 in (1.0, 2.5, 4.0):
        fy += 2.5 * BW * np.exp(-0.5 * ((t - t0) / 0.02) ** 2)
    w = np.column_stack([0.1 * fy, fy, 0.05 * fy]) + rng.normal(0, 0.02 * BW, (t.size, 3))
    flight = (t > 3.2) & (t < 3.5)
    w[flight] = 0.0
    return t, w


def run(det: PlateSaturation, w: np.ndarray) -> np.ndarray:
    """Samples found saturated (bool [n, 3]), the first of each run marked afterwards."""
    out = np.zeros(w.shape, bool)
    for i, y in enumerate(w):
        now, before, _ = det.check(y)
        out[i] = now
        if i:
            out[i - 1] |= before
    return out


def levels() -> np.ndarray:
    return 1.5 * BW * np.array([1.0, 1.0, 0.17])


def test_exactly_the_clipped_samples_are_found():
    t, w = impacts(np.random.default_rng(1))
    cap = 2.2 * BW
    clipped = w.copy()
    clipped[:, 1] = np.minimum(w[:, 1], cap)
    truth = w[:, 1] >= cap
    det = PlateSaturation(levels())
    found = run(det, clipped)
    assert truth.sum() > 60
    assert np.array_equal(found[:, 1], truth)
    assert not found[:, [0, 2]].any()
    assert det.runs == 3


def test_a_level_once_found_is_known_at_the_first_sample_of_a_later_run():
    det = PlateSaturation(levels())
    cap = 2.2 * BW
    first = run(det, np.array([[0, 1000.0, 0], [0, cap, 0], [0, cap, 0], [0, 1000.0, 0]]))
    assert first[:, 1].tolist() == [False, True, True, False]
    now, before, begins = det.check(np.array([0.0, cap, 0.0]))
    assert now[1] and not before.any() and begins


def test_unclipped_noisy_thresholded_and_quantised_loads_are_never_saturated():
    t, w = impacts(np.random.default_rng(2))
    assert not run(PlateSaturation(levels()), w).any()
    # a coarse converter (1 N steps) in quiet stance repeats readings, below the floor
    quiet = np.round(np.full((2000, 3), [70.0, BW, 35.0])
                     + np.random.default_rng(3).normal(0, 0.5, (2000, 3)))
    assert (np.diff(quiet[:, 1]) == 0).sum() > 100
    assert not run(PlateSaturation(levels()), quiet).any()


def test_the_estimator_takes_saturated_channels_as_missing_and_says_so():
    model = default_model()
    bw = model.p.body_weight
    cap = 2.2 * bw
    est = MovingHorizonEstimator(model)
    fy = np.array([bw, 2.0 * bw, cap, cap, cap, 2.1 * bw, bw])
    for i, f in enumerate(fy):
        est.add_wrench(i / FS, np.array([10.0 + i, f, 5.0 + i]))
    y = np.array([p[1] for p in est.pending_wrench])
    assert np.isnan(y[2:5, 1]).all()                 # the run's first sample too
    assert np.isfinite(np.delete(y[:, 1], [2, 3, 4])).all()
    assert np.isfinite(y[:, [0, 2]]).all()           # the other channels still measured
    said = [e for e in est.events if 'saturated' in e.message]
    assert len(said) == 1 and said[0].level == 'warn' and 'Fy' in said[0].message


def test_a_signal_held_between_samples_is_not_taken_for_saturation():
    """A 100 Hz plate up-sampled to 1000 Hz by repetition repeats every reading ten times,
    at high loads too: the detector sees the repeats at low loads and stops looking."""
    t, w = impacts(np.random.default_rng(4))
    held = np.repeat(w[::10], 10, axis=0)[:w.shape[0]]
    det = PlateSaturation(levels())
    found = run(det, held)
    assert det.held[1]
    first_high = int(np.argmax(np.abs(held[:, 1]) >= 1.5 * BW))
    assert not found[first_high:].any()        # judged held before the first impact
    # a noisy signal is never judged held
    det = PlateSaturation(levels())
    run(det, w)
    assert not det.held.any()
