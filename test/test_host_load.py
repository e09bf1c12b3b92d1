"""The machine's load during a run (nmt_ros.study.host_load): /proc/stat parsing and the
arithmetic of cores busy, ours, others' and steal, against hand-computed numbers."""
from __future__ import annotations

import time

import pytest

from nmt_ros.study.host_load import (
    CpuTimes,
    cpu_times,
    format_host_load,
    host_load,
    parse_context_switches,
    parse_proc_stat,
)

STAT = """cpu  1000 50 200 5000 100 10 40 300 0 0
cpu0 500 25 100 2500 50 5 20 150 0 0
intr 12345
ctxt 987654321
"""


def test_proc_stat_aggregate_line_in_seconds():
    busy, idle, steal = parse_proc_stat(STAT, 100.0)
    assert busy == pytest.approx((1000 + 50 + 200 + 10 + 40) / 100)
    assert idle == pytest.approx((5000 + 100) / 100)
    assert steal == pytest.approx(3.0)
    with pytest.raises(ValueError, match='no aggregate'):
        parse_proc_stat('cpu0 1 2 3 4\n', 100.0)


def test_cores_busy_ours_others_and_steal():
    a = CpuTimes(busy_s=100.0, idle_s=500.0, steal_s=10.0, ours_s=5.0, wall_s=1000.0, cores=2)
    # 10 s of wall time on 2 cores (20 CPU s): 16 busy (ours 13), 2 idle, 2 stolen
    b = CpuTimes(busy_s=116.0, idle_s=502.0, steal_s=12.0, ours_s=18.0, wall_s=1010.0,
                 cores=2)
    h = host_load(a, b)
    assert h['busy_cores'] == pytest.approx(1.6) and h['ours_cores'] == pytest.approx(1.3)
    assert h['other_cores'] == pytest.approx(0.3) and h['steal_pct'] == pytest.approx(10.0)
    assert h['busy'] and 'the machine was busy' in format_host_load(h)
    quiet = host_load(a, CpuTimes(busy_s=113.5, idle_s=506.4, steal_s=10.1, ours_s=18.0,
                                  wall_s=1010.0, cores=2))
    assert quiet['other_cores'] == pytest.approx(0.05) and not quiet['busy']
    assert 'busy' not in format_host_load(quiet).split(')')[-1]


def test_a_busy_loop_of_our_own_counts_as_ours():
    before = cpu_times()
    if before is None:
        pytest.skip('no /proc/stat')
    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    after = cpu_times()
    # CPU seconds, whatever else ran (both counters tick at 10 ms)
    ours_s = after.ours_s - before.ours_s
    assert ours_s >= 0.28
    assert after.busy_s - before.busy_s >= ours_s - 0.05     # the machine counted it too
    h = host_load(before, after)
    assert h['ours_cores'] == pytest.approx(ours_s / (after.wall_s - before.wall_s), abs=2e-3)


def test_context_switches_per_second():
    assert parse_context_switches(STAT) == 987654321
    assert parse_context_switches('cpu 1 2 3 4\n') == 0
    a = CpuTimes(busy_s=1.0, idle_s=1.0, steal_s=0.0, ours_s=0.0, wall_s=100.0, cores=2,
                 context_switches=1_000_000)
    b = CpuTimes(busy_s=2.0, idle_s=2.0, steal_s=0.0, ours_s=0.0, wall_s=104.0, cores=2,
                 context_switches=1_048_000)
    h = host_load(a, b)
    assert h['context_switches_per_s'] == 12_000
    assert '12,000 context switches/s' in format_host_load(h)


def test_a_thread_ping_pong_counts_its_switches():
    """N hand-overs between two threads that each block until handed the turn: at least N
    context switches on the machine's counter, whatever else ran."""
    import threading

    before = cpu_times()
    if before is None or not before.context_switches:
        pytest.skip('no ctxt in /proc/stat')
    n = 2000
    ping, pong = threading.Event(), threading.Event()

    def other() -> None:
        for _ in range(n):
            ping.wait()
            ping.clear()
            pong.set()

    thread = threading.Thread(target=other)
    thread.start()
    for _ in range(n):
        ping.set()
        pong.wait()
        pong.clear()
    thread.join()
    after = cpu_times()
    assert after.context_switches - before.context_switches >= n
