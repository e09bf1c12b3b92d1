"""Running the nodes: ``main()`` of every node and a node for a CLI verb.

:func:`run_node` is the ``main()`` of every node: ``rclpy.init`` (with our own SIGINT/SIGTERM
handling, so a node can finish cleanly: the recorder closes its bag, the trackers wait until
their last messages are acknowledged), spin until the node is done or a signal arrives, then
``destroy_node`` and ``try_shutdown``. A node started by ``nmt launch`` also gets SIGTERM
when the launcher dies (``launcher_link``). :func:`make_executor` picks the executor. With
``NMT_PROFILE_DIR`` set, the node's main thread runs under cProfile and its statistics go to
``$NMT_PROFILE_DIR/<node name>.prof`` when it ends (``python -m pstats FILE``: where a node's
CPU goes, measured in the running graph). The profile's clock is the main thread's CPU time
(``time.thread_time``): cProfile's default wall clock also counted the executor's waits and
every time the thread was switched out on the busy cores (``time.process_time`` then showed
at ~190 us a call in the muscle tracker's profile, the waits in ``spin_once`` at 5.8 s of a
20 s run).
:func:`cli_node` gives a CLI verb (``nmt echo``, ``nmt bag play``) a node in its own rclpy
context.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
import cProfile
import os
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from nmt_ros.nodes.launcher_link import end_with_launcher
from nmt_ros.nodes.node_base import NmtNode


class _Stop:
    """Set by SIGINT/SIGTERM; the spin loop checks it between callbacks."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signum = 0

    def __call__(self, signum: int, _frame: object) -> None:
        if not self.event.is_set():
            self.signum = signum
            self.event.set()


def make_executor(kind: str = 'single') -> Any:
    """``'single'``: rclpy's SingleThreadedExecutor; ``'events'``: the (experimental in Jazzy)
    EventsExecutor, 2-3x cheaper per typed message (``bench/bench_transport.py``), for nodes
    whose subscriptions need no message info (it calls a raw callback with the bytes only).
    A raw recorder takes its messages in batches instead (``polled_subscriptions``)."""
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor

            return EventsExecutor()
        except ImportError:
            pass
    return SingleThreadedExecutor()


def run_node(factory: Callable[..., NmtNode], args: Sequence[str] | None = None,
             executor: str = 'single') -> int:
    """``main()`` of a node: init, spin until done or signalled, finish, destroy, shutdown."""
    rclpy.init(args=list(sys.argv if args is None else args),
               signal_handler_options=SignalHandlerOptions.NO)
    stop = _Stop()
    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    end_with_launcher(signal.SIGTERM)      # started by `nmt launch`: end when it dies
    node = None
    profile_dir = os.environ.get('NMT_PROFILE_DIR')
    profile = cProfile.Profile(time.thread_time) if profile_dir else None
    try:
        node = factory()
        executor = make_executor(executor)
        executor.add_node(node)
        if profile is not None:
            profile.enable()
        while rclpy.ok() and not stop.event.is_set() and not node.done:
            executor.spin_once(timeout_sec=0.05)
        node.on_shutdown(interrupted=stop.event.is_set())
        return node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        if node is not None:
            node.on_shutdown(interrupted=True)
        return 0 if node is None else node.exit_code
    finally:
        if profile is not None:
            profile.disable()
            if node is not None:
                Path(profile_dir).mkdir(parents=True, exist_ok=True)
                profile.dump_stats(str(Path(profile_dir) / f'{node.get_name()}.prof'))
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def cli_node(args: Any, name: str, **kwargs: Any) -> Iterator[Node]:
    """A node of a CLI verb in its own rclpy context (``args.extra`` goes to ``rclpy.init``);
    destroyed and the context shut down on leaving."""
    context = Context()
    rclpy.init(args=['nmt'] + list(getattr(args, 'extra', [])), context=context)
    try:
        node = rclpy.create_node(name, context=context, **kwargs)
        try:
            yield node
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
