"""A bag writer on its own thread, fed through a bounded queue (a recorder's write path).

A recorder must take messages from the middleware as fast as they arrive; serialising MCAP
records, compressing chunks (zstd) and writing files belongs elsewhere. The receive path
calls :meth:`BackgroundBagWriter.put` with a batch of already serialised messages, which only
appends the batch to a queue; a writer thread pops batches and hands them to a
:class:`~nmt_ros.io.bags.BagWriter` (which splits files and compresses chunks).

Memory is bounded: the queue holds at most ``max_queue_bytes`` of message payload (a batch
larger than that on its own is still accepted when the queue is empty). When it is full,
``put`` blocks until the writer has made room (back-pressure: the messages then wait in the
middleware's history, nothing is dropped here) and the time spent blocked is counted. While
no batch arrives the thread flushes the open chunk every ``flush_period_s``, so an idle
recorder that is killed loses nothing it had received.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
import threading
import time
from typing import Any

from .bags import BagError, BagInfo, BagWriter

#: one queued message: (topic, CDR bytes, log time [ns], publish time [ns])
QueuedMessage = tuple[str, bytes, int, int]


@dataclass
class QueueStats:
    """How the queue behaved: peaks and the time ``put`` waited for room."""

    batches: int = 0
    messages: int = 0
    max_bytes: int = 0
    max_batches: int = 0
    blocked_s: float = 0.0


class BackgroundBagWriter:
    """``put`` batches of serialised messages; a thread writes them with ``writer``.

    ``add_topic`` is synchronous (it raises at once for an unknown type) and ordered before
    the messages queued after it. ``close`` writes what is queued, finishes the bag and
    returns its :class:`~nmt_ros.io.bags.BagInfo`. An error on the writer thread (disk full)
    is raised by the next ``put``/``add_topic``/``close`` as a :class:`~nmt_ros.io.bags.BagError`.
    """

    def __init__(self, writer: BagWriter, *, max_queue_bytes: int = 256 * 1024 * 1024,
                 flush_period_s: float = 1.0) -> None:
        if max_queue_bytes <= 0:
            raise ValueError(f'max_queue_bytes must be > 0, got {max_queue_bytes}')
        self.writer = writer
        self.max_queue_bytes = int(max_queue_bytes)
        self.flush_period_s = float(flush_period_s)
        self.stats = QueueStats()
        self._queue: deque[tuple[Sequence[QueuedMessage], int]] = deque()
        self._queued_bytes = 0
        self._cond = threading.Condition()
        self._write_lock = threading.Lock()   # the BagWriter is used by one thread at a time
        self._stopping = False
        self._error: BaseException | None = None
        self._info: BagInfo | None = None
        self._thread = threading.Thread(target=self._run, name='bag_writer', daemon=True)
        self._thread.start()

    @property
    def queued_bytes(self) -> int:
        return self._queued_bytes

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise BagError(f'writing {self.writer.path} failed: {self._error!r}')

    def add_topic(self, topic: str, msgtype: str, qos: Any = None, **kwargs: Any) -> None:
        """Declare a topic now (see :meth:`BagWriter.add_topic`)."""
        self._raise_if_failed()
        with self._write_lock:
            self.writer.add_topic(topic, msgtype, qos, **kwargs)

    def put(self, batch: Sequence[QueuedMessage]) -> None:
        """Queue a batch of messages; blocks only while the queue is full."""
        if not batch:
            return
        self._raise_if_failed()
        size = sum(len(m[1]) for m in batch)
        with self._cond:
            if self._stopping:
                raise BagError(f'bag {self.writer.path} is closing; no more messages')
            if self._queue and self._queued_bytes + size > self.max_queue_bytes:
                start = time.monotonic()
                while (self._queue and self._queued_bytes + size > self.max_queue_bytes
                       and self._error is None):
                    self._cond.wait(0.1)
                self.stats.blocked_s += time.monotonic() - start
                self._raise_if_failed()
            self._queue.append((batch, size))
            self._queued_bytes += size
            self.stats.batches += 1
            self.stats.messages += len(batch)
            self.stats.max_bytes = max(self.stats.max_bytes, self._queued_bytes)
            self.stats.max_batches = max(self.stats.max_batches, len(self._queue))
            self._cond.notify_all()

    def _run(self) -> None:
        dirty = False
        try:
            while True:
                with self._cond:
                    if not self._queue and not self._stopping:
                        self._cond.wait(self.flush_period_s)
                    if not self._queue:
                        if self._stopping:
                            return
                        if dirty:  # idle: hand the open chunk to the OS
                            with self._write_lock:
                                self.writer.flush()
                            dirty = False
                        continue
                    batch, size = self._queue.popleft()
                with self._write_lock:
                    write = self.writer.write
                    for topic, data, log_ns, pub_ns in batch:
                        write(topic, data, log_ns, pub_ns)
                dirty = True
                with self._cond:
                    self._queued_bytes -= size
                    self._cond.notify_all()
        except BaseException as exc:  # noqa: BLE001 - reported by the next put/close
            with self._cond:
                self._error = exc
                self._cond.notify_all()

    def close(self, timeout_s: float | None = None) -> BagInfo:
        """Write everything queued, finish the bag (summary, ``metadata.yaml``); idempotent."""
        if self._info is not None:
            return self._info
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise BagError(f'the writer of {self.writer.path} did not finish within '
                           f'{timeout_s} s ({len(self._queue)} batches queued)')
        with self._write_lock:
            try:
                self._info = self.writer.close()
            except Exception:
                if self._error is None:
                    raise
        self._raise_if_failed()
        assert self._info is not None
        return self._info

    def __enter__(self) -> BackgroundBagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
