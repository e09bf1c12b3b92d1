"""``thread_policy.BatchThreads``: the threads named by prefix, and only those, are put under
SCHED_BATCH (as the kernel itself reports: ``os.sched_getscheduler``); the main thread never;
threads started later are caught by the next ``apply``; a node does it for the middleware's
threads when it is made."""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading

import pytest

from nmt_ros.nodes.thread_policy import BatchThreads, thread_ids, thread_name

pytestmark = pytest.mark.skipif(not os.path.isdir('/proc/self/task')
                                or not hasattr(os, 'sched_setscheduler'),
                                reason='Linux thread scheduling')

PR_SET_NAME = 15


class NamedThread:
    """A thread that gives itself an OS-level name (as Fast DDS names its threads) and waits."""

    def __init__(self, name: str) -> None:
        self.ready, self.stop = threading.Event(), threading.Event()
        self.tid = 0
        self.name = name
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.ready.wait(5.0)

    def _run(self) -> None:
        libc = ctypes.CDLL(ctypes.util.find_library('c'), use_errno=True)
        libc.prctl(PR_SET_NAME, self.name.encode(), 0, 0, 0)
        self.tid = threading.get_native_id()
        self.ready.set()
        self.stop.wait(30.0)

    def policy(self) -> int:
        return os.sched_getscheduler(self.tid)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)


def test_only_the_named_threads_go_batch_and_later_ones_are_caught() -> None:
    middleware, worker = NamedThread('dds.probe.1'), NamedThread('worker.1')
    late = None
    try:
        assert thread_name(middleware.tid) == 'dds.probe.1'
        assert {middleware.tid, worker.tid, os.getpid()} <= set(thread_ids())
        batch = BatchThreads(('dds.probe.',))
        assert batch.apply() == 1
        assert middleware.policy() == os.SCHED_BATCH
        assert worker.policy() == os.SCHED_OTHER
        assert os.sched_getscheduler(os.getpid()) == os.SCHED_OTHER
        assert batch.apply() == 0                     # nothing new
        late = NamedThread('dds.probe.2')
        assert late.policy() == os.SCHED_OTHER
        assert batch.apply() == 1
        assert late.policy() == os.SCHED_BATCH
    finally:
        for t in (middleware, worker, late):
            if t is not None:
                t.close()


def test_no_prefixes_change_nothing() -> None:
    thread = NamedThread('dds.probe.3')
    try:
        assert BatchThreads(('',)).apply() == 0
        assert BatchThreads(()).apply() == 0
        assert thread.policy() == os.SCHED_OTHER
    finally:
        thread.close()


def test_a_node_puts_the_middlewares_threads_under_batch(ros_context) -> None:
    from nmt_ros.nodes.node_base import NmtNode

    node = NmtNode('thread_policy_test', context=ros_context)
    try:
        dds = [tid for tid in thread_ids() if (thread_name(tid) or '').startswith('dds.')]
        assert dds, 'Fast DDS started no dds.* threads'
        policies = {thread_name(tid): os.sched_getscheduler(tid) for tid in dds}
        assert set(policies.values()) == {os.SCHED_BATCH}, policies
        assert os.sched_getscheduler(os.getpid()) == os.SCHED_OTHER
    finally:
        node.destroy_node()


def _refuse(tid: int, policy: int, param: object) -> None:
    raise PermissionError(1, 'Operation not permitted')


def test_a_refusal_is_kept_and_the_thread_keeps_its_policy(monkeypatch) -> None:
    thread = NamedThread('dds.probe.4')
    try:
        batch = BatchThreads(('dds.probe.4',))
        monkeypatch.setattr(os, 'sched_setscheduler', _refuse)
        assert batch.apply() == 0
        assert 'dds.probe.4' in batch.failed[thread.tid]
        assert thread.policy() == os.SCHED_OTHER
        monkeypatch.undo()
        assert batch.apply() == 0                    # refused once: not retried
    finally:
        thread.close()


def test_a_node_reports_a_refusal_once_and_works_on(ros_context, monkeypatch) -> None:
    from nmt_ros.nodes.node_base import NmtNode
    from nmt_ros.nodes.node_status import WARN

    monkeypatch.setattr(os, 'sched_setscheduler', _refuse)
    node = NmtNode('thread_policy_refused', context=ros_context)
    try:
        node.publish_status()
        node.publish_status()
        warned = [e for e in node.status.events
                  if e.level == WARN and 'SCHED_BATCH refused' in e.message]
        assert len(warned) == 1, node.status.events
        assert 'dds.' in warned[0].message
    finally:
        node.destroy_node()
