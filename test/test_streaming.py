"""The streaming layer (nmt_ros.tracking.streaming) against the batch trackers: Stage 1 fed
sample by sample with a fixed look-ahead, Stage 2 in receding windows, and the joint
accelerations Stage 2's stream differentiates."""
from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from nmt_ros.tracking.streaming import (
    Decimator,
    Stage1Stream,
    Stage2Stream,
    initial_activations,
)

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'reference_jump'


# --------------------------------------------------------------------------- streaming = batch

@cache
def _trial():
    from nmt_ros.io.trial_bag import read_observations
    from nmt_ros.model.jumper import default_model
    from nmt_ros.tracking.conditioning import condition
    from nmt_ros.tracking.skeletal_tracker import SKTSettings
    from nmt_ros.tracking.streaming import track_stage1

    model = default_model()
    obs = read_observations(BAG)
    skt = SKTSettings().with_(substeps=1)
    batch = track_stage1(model, condition(obs.t_angles, obs.angles, obs.t_wrench, obs.wrench), skt)
    return model, obs, skt, batch


def _stream_stage1(lookahead_s: float):
    from nmt_ros.tracking.conditioning import ConditioningSettings

    model, obs, skt, _ = _trial()
    runner = Stage1Stream(model, skt, ConditioningSettings(lookahead_s=lookahead_s))
    events = sorted([(t, 0, i) for i, t in enumerate(obs.t_angles)]
                    + [(t, 1, i) for i, t in enumerate(obs.t_wrench)])
    outs = []
    for t, kind, i in events:
        if kind == 0:
            runner.add_angles(t, obs.angles[i])
        else:
            runner.add_wrench(t, obs.wrench[i])
        out = runner.poll()
        if out is not None:
            outs.append(out)
    n_streamed = sum(o.t.size for o in outs)
    outs.append(runner.finish())
    assert runner.finish() is None and runner.poll() is None
    return {k: np.concatenate([getattr(o, k) for o in outs]) for k in ('t', 'tau', 'q', 'qd')
            } | {'n_streamed': n_streamed}


@pytest.mark.slow
def test_stage1_stream_equals_batch_with_enough_lookahead():
    _, _, _, batch = _trial()
    out = _stream_stage1(0.1)
    np.testing.assert_allclose(out['t'], batch.t, atol=1e-12)
    assert 0 < out['n_streamed'] < batch.t.size       # most streamed, the rest flushed
    rms = np.sqrt(np.mean((out['tau'] - batch.tau) ** 2, axis=0))
    assert (rms / np.abs(batch.tau).max(axis=0) < 0.02).all(), rms


@pytest.mark.slow
def test_stage1_flush_alone_is_the_batch_tracker():
    """A look-ahead longer than the trial: nothing is final until the end, and the flush
    filters the whole trial at once, exactly what the batch tracker does."""
    _, _, _, batch = _trial()
    out = _stream_stage1(1.0)
    assert out['n_streamed'] == 0
    np.testing.assert_allclose(out['tau'], batch.tau, rtol=0, atol=1e-6 * np.abs(
        batch.tau).max())


def test_stage1_polled_one_sample_at_a_time_is_the_batch_tracker():
    """Polled one force-plate sample at a time, Stage 1 gives the batch outputs, joint angles
    included; tracking then ends at the first sample of a poll, which yields no row."""
    from nmt_ros.tracking.conditioning import condition

    model, obs, skt, batch = _trial()
    stream = Stage1Stream(model, skt, conditioner=condition(obs.t_angles, obs.angles,
                                                            obs.t_wrench, obs.wrench))
    outs, empty = [], 0
    for k in range(obs.t_wrench.size):
        out = stream.poll(t_end=k / 1080)
        if out is not None:
            outs.append(out)
            empty += out.t.size == 0
    assert stream.ended_s is not None and empty == 1
    cat = {f: np.concatenate([getattr(o, f) for o in outs])
           for f in ('t', 'tau', 'q', 'joint_angles', 'joint_rates')}
    np.testing.assert_array_equal(cat['t'], batch.t)
    np.testing.assert_allclose(cat['tau'], batch.tau, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(cat['q'], batch.q, rtol=1e-12, atol=1e-12)
    # OpenSim joint angles: ankle = foot - shank, knee = shank - thigh, hip = thigh - HAT
    np.testing.assert_allclose(cat['joint_angles'], -np.diff(batch.q[:, :4], axis=1),
                               atol=1e-12)
    np.testing.assert_allclose(cat['joint_rates'], -np.diff(batch.qd[:, :4], axis=1),
                               atol=1e-12)


@pytest.mark.slow
def test_stage2_stream_equals_batch_windowed():
    from nmt_ros.tracking.stage2 import NeuromuscularTracker

    model, _, _, batch = _trial()
    n = 120
    t, tau = batch.t[:n], batch.tau[:n]
    th, thd, thdd = (model.batch(model.joint_angles, x[:n])[0]
                     for x in (batch.q, batch.qd, batch.qdd))
    tracker = NeuromuscularTracker(model)
    runner = Stage2Stream(model, tracker, window_length_s=0.03, window_stride_s=0.005)
    outs = []
    for i in range(n):
        runner.add(1000 + i, t[i], tau[i], th[i], thd[i])
        if i % 9 == 8:        # bursts, as Stage 1 publishes them
            outs.append(runner.process())
    outs.append(runner.process(final=True))
    outs = [o for o in outs if o is not None]
    f = np.concatenate([o.f for o in outs])
    stamps = np.concatenate([o.stamp_ns for o in outs])
    np.testing.assert_array_equal(stamps, 1000 + np.arange(n))
    a0, problem = initial_activations(model, th[0], tau[0], thd[0])
    assert problem is None
    np.testing.assert_allclose(runner.a0, a0)
    ref = tracker.track(t, tau, th, thd, thdd, a0, mode='windowed', window_length=0.03,
                        window_stride=0.005)
    # only the (unused here) Eq. 9 report depends on theta_ddot: forces match to round-off
    np.testing.assert_allclose(f, ref.f, atol=1e-6 * tracker.f0.max())
    lmt = np.concatenate([o.l_mt for o in outs])
    np.testing.assert_allclose(lmt, model.batch(model.musculotendon_lengths, th)[0])


def test_joint_accelerations_are_central_differences():
    from nmt_ros.model.jumper import default_model

    runner = Stage2Stream.__new__(Stage2Stream)
    runner.model = default_model()
    runner.rate_hz = 100.0          # the samples' grid (input times are snapped to it)
    runner.reset()
    t = np.arange(6) * 0.01
    v = np.column_stack([t ** 2, 3 * t, np.ones_like(t)])
    for i in range(6):
        runner.add(i, t[i], np.zeros(3), np.zeros(3), v[i])
    acc = runner._accelerations(runner.pending[:3])        # rows 0..2, row 3 is next
    np.testing.assert_allclose(acc[:, 0], [0.01, 0.02, 0.04])  # one-sided at the start
    np.testing.assert_allclose(acc[:, 1], 3.0)
    np.testing.assert_allclose(acc[:, 2], 0.0)


def test_stage2_input_times_are_snapped_to_the_grid():
    """Header stamps are whole nanoseconds, so trial times come in up to 0.5 ns off the grid
    k / rate_hz; Stage 2 joins its windows on an exact grid, so the stream puts them back."""
    runner = Stage2Stream.__new__(Stage2Stream)
    runner.rate_hz = 1080.0
    runner.reset()
    k = np.arange(1, 6)
    stamps = np.rint(k / 1080.0 * 1e9).astype(np.int64)          # what the publisher sends
    for s in stamps:
        runner.add(int(s), int(s) * 1e-9, np.zeros(3), np.zeros(3), np.zeros(3))
    t = np.array([row[1] for row in runner.pending])
    assert np.abs(stamps * 1e-9 - k / 1080.0).max() > 0      # off the grid as received
    np.testing.assert_array_equal(t, k / 1080.0)                # exactly on it once queued


def _stage2_in_chunks(chunk_sizes, window_length_s: float = 0.04,
                      window_stride_s: float = 0.01) -> dict:
    """The reference jump's true torques and joint kinematics through ``Stage2Stream``,
    ``process`` called after each chunk of samples (sizes cycled from ``chunk_sizes``)."""
    from nmt_ros.io.trial_bag import read_truth
    from nmt_ros.model.jumper import default_model

    model = default_model()
    tr = read_truth(BAG)
    J = np.column_stack([model.call(model.joint_angles, e)[0] for e in np.eye(6)])
    theta, theta_dot = tr.q @ J.T, tr.qd @ J.T
    stamps = 1_000_000 + np.rint(tr.t * 1e9).astype(np.int64)
    stream = Stage2Stream(model, window_length_s=window_length_s,
                          window_stride_s=window_stride_s)
    outs, i, k, streamed = [], 0, 0, 0
    while i < tr.t.size:
        n = int(chunk_sizes[k % len(chunk_sizes)])
        for j in range(i, min(i + n, tr.t.size)):
            stream.add(stamps[j], tr.t[j], tr.tau[j], theta[j], theta_dot[j])
        i, k = i + n, k + 1
        out = stream.process()
        if out is not None:
            outs.append(out)
            streamed += out.t.size
    outs.append(stream.process(final=True))
    assert stream.process(final=True) is None
    cat = {key: np.concatenate([getattr(o, key) for o in outs])
           for key in ('stamp_ns', 't', 'f', 'a', 'u', 'saturated')}
    np.testing.assert_array_equal(cat['stamp_ns'], stamps)       # every sample, once
    return cat | {'streamed': streamed}


def test_stage2_stream_output_does_not_depend_on_how_the_input_was_cut():
    """Issue 13: the live Stage 2 must be a function of its input stream, not of when its
    work ran. The same samples fed one at a time (a fast, idle node), in random bursts of
    1-120 (a loaded node catching up) and all in one call give identical
    outputs, bit for bit, through the jump's push-off, saturation and lift-off."""
    rng = np.random.default_rng(13)
    one = _stage2_in_chunks([1])
    bursts = _stage2_in_chunks(rng.integers(1, 121, size=64))
    whole = _stage2_in_chunks([10 ** 6])
    assert one['streamed'] > 0.6 * one['t'].size        # most outputs before the end
    assert one['saturated'].any() and not one['saturated'].all()
    for key in ('t', 'f', 'a', 'u', 'saturated'):
        np.testing.assert_array_equal(bursts[key], one[key], err_msg=key)
        np.testing.assert_array_equal(whole[key], one[key], err_msg=key)


def test_decimator_keeps_one_instant_per_period_whatever_the_rate_and_blocks():
    # 1080 Hz thinned to 120 Hz: exactly the multiples of 1/120 s (every 9th instant)
    t = np.arange(2160) / 1080.0
    kept = Decimator(120.0).keep(t)
    assert np.array_equal(np.nonzero(kept)[0], np.arange(0, 2160, 9))
    # the same split into uneven blocks
    d = Decimator(120.0)
    cuts = [0, 5, 6, 100, 101, 1500, 2160]
    split = np.concatenate([d.keep(t[a:b]) for a, b in zip(cuts[:-1], cuts[1:])])
    assert np.array_equal(split, kept)
    # a slower stream (100 Hz, 0.25 s offset) is not thinned at 120 Hz: every instant kept
    t100 = 0.25 + np.arange(300) / 100.0
    assert Decimator(120.0).keep(t100).all()
    # 1000 Hz thinned to 120 Hz: one instant per 1/120 s period, the first in it
    t1000 = np.arange(1000) / 1000.0
    mask = Decimator(120.0).keep(t1000)
    periods = np.floor(t1000 * 120.0 + 1e-6)
    assert mask.sum() == np.unique(periods).size == 120
    assert np.array_equal(t1000[mask], np.array([t1000[periods == k][0]
                                                 for k in np.unique(periods)]))
    with pytest.raises(ValueError, match='positive'):
        Decimator(0.0)
