"""Inputs taken from the middleware on a thread of their own, into a queue the node drains.

A tracker node works through its inputs in batches (``TrackerNode.take_inputs``). While one
batch is estimated, new messages used to wait in the middleware's reader history (KEEP_LAST
``qos_depth``): a node more than ``qos_depth`` messages behind (5000: 4.2 s of the skeletal
tracker's two inputs) lost the oldest of them there, reported only as a gap in the stamps,
and its ``max_backlog_s`` skip, decided on the data it had taken, came too late (found with
``nmt demo`` beside a busy loop, README "Known limitations"). ``InputThread`` takes every
``period_s`` from ``PolledSubscriptions`` (whose helper node no executor ever runs, so this
thread is the only user of its handles) into a Python list, so the middleware's history
stays short (Fast DDS's cost per received message grows with it) and the node sees its whole
backlog. The queue is bounded by ``max_messages``: beyond it the thread stops taking (the
middleware's history fills, as before) and ``overflowed`` says so, never silently.
"""
from __future__ import annotations

import threading
from typing import Any

from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions


class InputThread:
    """``take_all()`` of a ``PolledSubscriptions``, fed by a background thread."""

    def __init__(self, polled: PolledSubscriptions, period_s: float,
                 max_messages: int = 2_000_000) -> None:
        self.polled = polled
        self.period_s = float(period_s)
        self.max_messages = int(max_messages)
        self.overflowed = False
        self._lock = threading.Lock()          # the queue
        self._pulling = threading.Lock()       # the subscriptions' handles: one taker at a time
        self._queue: dict[str, list[tuple[Any, dict]]] = {}
        self._count = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='input_take', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.pull()

    def pull(self) -> None:
        """Take what waits in the middleware into the queue (unless the queue is full)."""
        if self._count >= self.max_messages:
            self.overflowed = True
            return
        with self._pulling:
            taken = self.polled.take_all()
        if not taken:
            return
        with self._lock:
            for topic, msgs in taken.items():
                self._queue.setdefault(topic, []).extend(msgs)
                self._count += len(msgs)

    def take_all(self) -> dict[str, list[tuple[Any, dict]]]:
        """topic -> every message queued so far (and what waits in the middleware now)."""
        self.pull()
        with self._lock:
            out, self._queue, self._count = self._queue, {}, 0
        return out

    def __len__(self) -> int:
        return len(self.polled)

    def destroy(self) -> None:
        """Stop the thread, then destroy the subscriptions."""
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.polled.destroy()
