"""The middleware's threads scheduled so that they stop preempting a node's computation.

Fast DDS runs its own threads in every node process (``dds.ev.*`` timed events, ``dds.shm.*``
and ``dds.udp.*`` receivers, ...), each waking for a few microseconds per message. With the
graph's ~4,400 messages/s on a 2-core machine, those wake-ups preempted the computation on
their core (2026-12-07, ``nmt demo``, ~65 s into the run): the skeletal tracker's main thread
had been switched out involuntarily 166,000 times, its own ``dds.*`` threads had woken
199,000 times, and the machine did 22,000-25,000 context switches a second (``vmstat``).
Each preemption costs the computation its caches (``bench/bench_preemption.py``, below);
with these threads under SCHED_BATCH the graph used 8-10 % less CPU for the same estimates
(README "The live graph").

Linux's ``SCHED_BATCH`` marks a thread whose wake-up does not preempt the running one: it
runs on an idle core at once, else at the next scheduler tick (4 ms here) or when the running
thread blocks. The middleware's work there is queueing (our trackers take their inputs in
10 ms batches), so nothing we measure waits for it. ``bench/bench_preemption.py`` shows the
mechanism: the estimator pinned to one CPU took 3.78 s of CPU alone, 4.16 s beside a process
waking 2,500 times a second on that CPU (8,963 involuntary switches), 3.74 s when that
process ran under SCHED_BATCH (961). No privilege is needed; elsewhere ``apply`` returns 0.
"""
from __future__ import annotations

from collections.abc import Sequence
import os
from pathlib import Path

#: thread name prefixes of Fast DDS (rmw_fastrtps_cpp, the middleware of these wheels)
MIDDLEWARE_THREAD_PREFIXES = ('dds.',)


class BatchThreads:
    """Puts this process's threads whose names start with ``prefixes`` under SCHED_BATCH;
    :meth:`apply` again after the middleware may have started more (it remembers which are
    done). The process's main thread is never changed. ``failed``: thread id -> why the
    system refused (the thread keeps its policy)."""

    def __init__(self, prefixes: Sequence[str] = MIDDLEWARE_THREAD_PREFIXES) -> None:
        self.prefixes = tuple(p for p in prefixes if p)
        self.done: set[int] = set()
        self.failed: dict[int, str] = {}
        self.supported = hasattr(os, 'sched_setscheduler') and Path('/proc/self/task').is_dir()

    def apply(self) -> int:
        """Threads newly put under SCHED_BATCH by this call."""
        if not (self.supported and self.prefixes):
            return 0
        changed = 0
        main = os.getpid()
        tids = thread_ids()
        self.done.intersection_update(tids)       # an ended thread's id may be reused
        for tid in tids:
            if tid == main or tid in self.done or tid in self.failed:
                continue
            name = thread_name(tid)
            if name is None or not name.startswith(self.prefixes):
                continue
            try:
                os.sched_setscheduler(tid, os.SCHED_BATCH, os.sched_param(0))
            except ProcessLookupError:    # the thread ended meanwhile
                continue
            except OSError as exc:        # refused (a sandbox's policy): kept, reported
                self.failed[tid] = f'{name}: {exc}'
                continue
            self.done.add(tid)
            changed += 1
        return changed


def thread_ids() -> list[int]:
    """This process's thread ids (Linux ``/proc/self/task``; [] elsewhere)."""
    try:
        return [int(tid) for tid in os.listdir('/proc/self/task')]
    except OSError:
        return []


def thread_name(tid: int) -> str | None:
    """The name of thread ``tid`` of this process (None: it has ended)."""
    try:
        return Path(f'/proc/self/task/{tid}/comm').read_text().strip()
    except OSError:
        return None
