"""How busy the machine was during a run, besides the work we measure (Linux ``/proc/stat``).

A latency measured on a shared machine depends on what else ran: on this 2-core VM the same
commit's 60 s demo gave a refined-torque p99 of 0.4 s in one run and 5.4 s in the next. So
``nmt demo`` samples the machine's CPU counters before and after the graph and says how many
cores were busy, how many of them were the graph's (the node processes and the launcher:
``os.times`` of this process and its waited-for children), how many were other processes',
and how much time the hypervisor took from the virtual CPUs (steal), and how many context
switches a second the machine made (every message the graph passes wakes threads; those that
preempt the computation cost it its caches: README "Transport", SCHED_BATCH).
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import time

#: Other processes' cores or steal above these: the run's latencies are pessimistic.
BUSY_OTHER_CORES = 0.2
BUSY_STEAL_PCT = 5.0


@dataclass(frozen=True)
class CpuTimes:
    """The machine's CPU counters [s, summed over cores] and ours at one instant."""

    busy_s: float        # user + nice + system + irq + softirq (guest is inside user)
    idle_s: float        # idle + iowait
    steal_s: float       # taken by the hypervisor while the virtual CPU wanted to run
    ours_s: float        # this process and its waited-for children (user + system)
    wall_s: float        # monotonic clock
    cores: int
    context_switches: int = 0    # the machine's, since boot (``ctxt``)


def parse_proc_stat(text: str, clock_ticks: float) -> tuple[float, float, float]:
    """(busy, idle, steal) [s] from the aggregate ``cpu`` line of ``/proc/stat``."""
    for line in text.splitlines():
        fields = line.split()
        if fields and fields[0] == 'cpu':
            v = [float(x) for x in fields[1:]] + [0.0] * 10
            user, nice, system, idle, iowait, irq, softirq, steal = v[:8]
            return ((user + nice + system + irq + softirq) / clock_ticks,
                    (idle + iowait) / clock_ticks, steal / clock_ticks)
    raise ValueError('no aggregate "cpu" line in /proc/stat')


def parse_context_switches(text: str) -> int:
    """The machine's context switches since boot (the ``ctxt`` line of ``/proc/stat``; 0
    without one)."""
    for line in text.splitlines():
        fields = line.split()
        if len(fields) == 2 and fields[0] == 'ctxt':
            return int(fields[1])
    return 0


def cpu_times(proc_stat: Path = Path('/proc/stat')) -> CpuTimes | None:
    """The counters now; None where ``/proc/stat`` is not readable (not Linux)."""
    try:
        text = proc_stat.read_text()
    except OSError:
        return None
    busy, idle, steal = parse_proc_stat(text, float(os.sysconf('SC_CLK_TCK')))
    t = os.times()
    return CpuTimes(busy_s=busy, idle_s=idle, steal_s=steal,
                    ours_s=t.user + t.system + t.children_user + t.children_system,
                    wall_s=time.monotonic(), cores=os.cpu_count() or 1,
                    context_switches=parse_context_switches(text))


def host_load(before: CpuTimes, after: CpuTimes) -> dict[str, float | int | bool]:
    """Cores busy between two samples [cores = CPU s per s of wall time]: in all, ours,
    others'; steal as a percentage of the machine's CPU time; context switches per second;
    ``busy``: others or steal above the thresholds (``BUSY_OTHER_CORES``,
    ``BUSY_STEAL_PCT``)."""
    wall = max(after.wall_s - before.wall_s, 1e-9)
    busy = (after.busy_s - before.busy_s) / wall
    ours = (after.ours_s - before.ours_s) / wall
    steal = after.steal_s - before.steal_s
    total = (after.busy_s + after.idle_s + after.steal_s
             - before.busy_s - before.idle_s - before.steal_s)
    steal_pct = 100.0 * steal / total if total > 0 else 0.0
    other = max(busy - ours, 0.0)
    return {'cores': after.cores, 'wall_s': round(wall, 2), 'busy_cores': round(busy, 3),
            'ours_cores': round(ours, 3), 'other_cores': round(other, 3),
            'steal_pct': round(steal_pct, 2),
            'context_switches_per_s': round((after.context_switches
                                             - before.context_switches) / wall),
            'busy': bool(other > BUSY_OTHER_CORES or steal_pct > BUSY_STEAL_PCT)}


def format_host_load(h: dict) -> str:
    """One line for a report."""
    text = (f"machine during the run: {h['busy_cores']:.2f} of {h['cores']} cores busy "
            f"(the graph and its launcher {h['ours_cores']:.2f}, other processes "
            f"{h['other_cores']:.2f}), steal {h['steal_pct']:.1f} %")
    if h.get('context_switches_per_s'):
        text += f", {h['context_switches_per_s']:,} context switches/s"
    if h['busy']:
        text += ' - the machine was busy: latencies are pessimistic'
    return text
