"""The nodes' ROS-free parts: input gates and trial time (nmt_ros.nodes.input_gate), readiness
(readiness), end of stream (end_of_stream) and status records (node_status)."""
from __future__ import annotations

import numpy as np
import pytest

from nmt_ros.nodes.end_of_stream import (
    EndOfStream,
    TrialBook,
    end_of_stream_values,
    parse_end_of_stream,
)
from nmt_ros.nodes.input_gate import StreamGate, TrialClock
from nmt_ros.nodes.node_status import ERROR, OK, WARN, NodeStatus, percentiles_ms
from nmt_ros.nodes.readiness import missing_subscribers, parse_wait_for

MS = 1_000_000


# --------------------------------------------------------------------------- gates

def test_gate_accepts_a_regular_stream():
    gate = StreamGate('/x', 0.001)
    for k in range(5):
        res = gate.offer(k * MS, np.array([k]))
        assert res.rejected is None and res.gap is None and res.restart is None
        assert [s.stamp_ns for s in res.samples] == [k * MS]


@pytest.mark.parametrize('stamp, words', [(2 * MS, 'duplicate stamp'),
                                          (1 * MS, '1.000 ms before the previous')])
def test_gate_rejects_duplicates_and_out_of_order(stamp, words):
    gate = StreamGate('/x', 0.001)
    gate.offer(1 * MS, np.zeros(1))
    gate.offer(2 * MS, np.zeros(1))
    res = gate.offer(stamp, np.zeros(1))
    assert res.samples == () and words in res.rejected and res.rejected.startswith('/x: ')
    assert gate.offer(3 * MS, np.zeros(1)).samples  # and goes on


def test_gate_rejects_stamps_before_the_trial():
    gate = StreamGate('/x', 0.001)
    gate.not_before_ns = 10 * MS
    assert 'before the trial start' in gate.offer(9 * MS, np.zeros(1)).rejected


def test_gate_fills_a_100_ms_gap_by_interpolation():
    gate = StreamGate('/x', 1 / 120)
    period = int(round(1e9 / 120))
    gate.offer(0, np.array([0.0, 10.0]))
    res = gate.offer(12 * period, np.array([12.0, 22.0]))   # 100 ms later
    assert 'gap of 100.0 ms' in res.gap and 'filled with 11 interpolated samples' in res.gap
    stamps = [s.stamp_ns for s in res.samples]
    assert stamps == [k * period for k in range(1, 13)]
    values = np.array([s.values for s in res.samples])
    np.testing.assert_allclose(values[:, 0], np.arange(1, 13), atol=1e-9)
    assert [s.interpolated for s in res.samples] == [True] * 11 + [False]


def test_gate_long_gap_restarts_the_trial():
    gate = StreamGate('/x', 0.001, max_gap_s=0.5)
    gate.offer(0, np.zeros(1))
    res = gate.offer(600 * MS, np.ones(1))
    assert 'exceeds max_gap_s' in res.restart and len(res.samples) == 1


def test_trial_clock_and_stamps_round_trip():
    clock = TrialClock()
    assert clock.start(1_700_000_000_000_000_000) == 1_700_000_000_000_000_000
    assert clock.start(5) == 1_700_000_000_000_000_000  # fixed by the first stamp
    t = np.arange(10) / 1080
    stamps = clock.stamps(t)
    np.testing.assert_allclose([clock.t(s) for s in stamps], t, atol=1e-9)
    assert TrialClock(42).start(7) == 42


def test_wait_for_entries():
    assert parse_wait_for(['/a=2', '/b', ' ', '/c=0']) == {'/a': 2, '/b': 1, '/c': 0}
    for bad in (['a=1'], ['/a=x'], ['/a=-1']):
        with pytest.raises(ValueError, match='wait_for entry'):
            parse_wait_for(bad)
    assert missing_subscribers({'/a': 2, '/b': 1}, {'/a': 1, '/b': 1}) == {'/a': '1/2'}


# --------------------------------------------------------------------------- end of stream

def test_end_of_stream_values_round_trip_as_strings():
    values = end_of_stream_values({'/a': 3}, {'/a': 17}, trial=2)
    text = {k: str(v) for k, v in values.items()}
    assert parse_end_of_stream(text) == {'/a': (3, 17)}
    assert parse_end_of_stream({'state': 'running'}) is None


def test_trial_book_counts_not_order():
    book = TrialBook(['/a', '/b'])
    book.start()
    book.saw('/a', 100)
    ann = {k: str(v) for k, v in end_of_stream_values({'/a': 2, '/b': 1, '/other': 5},
                                                      {'/a': 100, '/b': 200}).items()}
    assert book.announcement(ann, now=0.0)
    assert book.verdict(0.1, timeout_s=1.0) is None      # /b not seen yet, /a short
    book.saw('/a', 101)
    book.saw('/b', 200)
    assert 'every message received' in book.verdict(0.2, timeout_s=1.0)
    counts, firsts = book.finish()
    assert not book.active and book.seen == {}


def test_trial_book_times_out_and_ignores_stale_announcements():
    book = TrialBook(['/a'])
    book.start()
    book.saw('/a', 500)
    stale = {k: str(v) for k, v in end_of_stream_values({'/a': 1}, {'/a': 100}).items()}
    book.announcement(stale, now=0.0)
    assert book.verdict(10.0, timeout_s=1.0) is None      # another trial's announcement
    fresh = {k: str(v) for k, v in end_of_stream_values({'/a': 3}, {'/a': 500}).items()}
    book.announcement(fresh, now=1.0)
    assert book.verdict(1.5, timeout_s=1.0) is None
    why = book.verdict(2.5, timeout_s=1.0)
    assert 'still missing' in why and "'/a': 2" in why
    book.output('/out', 7, 4)
    book.output('/out', 9, 3)
    assert book.finish() == ({'/out': 7}, {'/out': 7})


def test_trial_book_ends_the_last_trial_of_a_stream_split_by_gaps():
    """A gap ends a trial inside one producer stream (more follows): the producer's end of
    stream, counted from its first message, still ends the trial that runs at the end."""
    book = TrialBook(['/a'])
    book.start()
    for stamp in (100, 101, 102):
        book.saw('/a', stamp)
    book.finish(more_follows=True)           # a gap: the next trial starts at once
    book.start()
    book.saw('/a', 900)
    ann = {k: str(v) for k, v in end_of_stream_values({'/a': 5}, {'/a': 100}).items()}
    assert book.announcement(ann, now=0.0)
    assert book.verdict(0.1, timeout_s=1.0) is None      # 4 of 5 seen
    book.saw('/a', 901)
    assert 'every message received' in book.verdict(0.2, timeout_s=1.0)
    book.finish()
    assert book.seen == {} and book.first_seen == {}


def test_end_of_stream_needs_an_announcement():
    end = EndOfStream(['/a'])
    assert not end.complete({'/a': 10}, {'/a': 1})
    assert not end.announce({'/z': (1, None)}, 0.0)


# --------------------------------------------------------------------------- status

def test_status_reports_levels_reasons_and_timing():
    clock = iter(np.arange(0.0, 100.0, 0.5))
    status = NodeStatus('/n', process_time=lambda: 1.0, monotonic=lambda: next(clock))
    status.mark_active()
    status.receive('/in', 3)
    status.publish('/out', 2)
    status.delay(0.010)
    status.delay(0.020)
    first = status.reports()
    assert first[0].level == OK and first[0].values['received./in'] == 3
    assert first[0].values['published./out'] == 2
    assert first[0].values['processing_delay_max_ms'] == pytest.approx(20.0)
    status.reject('/in', '/in: JointState position has a non-finite value nan at index 1')
    assert status.has_news
    reports = status.reports()
    assert not status.has_news
    assert reports[0].level == WARN and reports[0].values['rejected./in'] == 1
    assert reports[1].name == '/n: rejected samples' and 'non-finite' in reports[1].message
    status.state = 'lost_control'
    status.event(ERROR, 'loss of control at t = 0.1 s', t=0.1)
    reports = status.reports()
    assert reports[0].level == ERROR and reports[-1].message.startswith('loss of control')
    assert np.isnan(percentiles_ms([])['p50_ms'])
