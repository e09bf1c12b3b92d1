"""rclpy glue shared by the nodes: QoS profiles, parameters, /nmt/status, readiness, main().

Every node is an :class:`NmtNode`: parameters are declared once (with a
``ParameterDescriptor``) and copied to attributes; ``/nmt/status`` (DiagnosticArray) is
published every ``status_period_s`` and at once when something noteworthy happens; inputs
are opened only when the node's outputs have the subscribers listed in ``wait_for``
(``'/topic=N'``), so readiness propagates upstream and nothing is published into the void.

QoS: data topics are RELIABLE, KEEP_LAST ``qos_depth`` (default 5000, several seconds of the
1080 Hz stream), VOLATILE: a replay through the graph is lossless while any subscriber keeps
within that backlog, and best-effort tools (``nmt echo``) still connect. ``/nmt/status`` is
RELIABLE, KEEP_LAST 100, TRANSIENT_LOCAL: a consumer that matched late still gets the
end-of-stream announcement (announcements carry the trial's first stamp, so stale ones are
ignored).

:func:`run_node` is the ``main()`` of every node: ``rclpy.init`` (with our own SIGINT/SIGTERM
handling, so a node can finish cleanly: the recorder closes its bag, the trackers wait until
their last messages are acknowledged), spin until the node is done or a signal arrives, then
``destroy_node`` and ``try_shutdown``.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
import signal
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from msg_adapters.diagnostics import StatusRecord, to_diagnostic_array
from nmt_ros.nodes._core import (
    STREAM_PART,
    NodeStatus,
    Report,
    end_of_stream_values,
    missing_subscribers,
    parse_wait_for,
)

STATUS_TOPIC = '/nmt/status'
STATUS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def data_qos(depth: int, reliable: bool = True) -> QoSProfile:
    """QoS of data topics: KEEP_LAST ``depth``, RELIABLE (or BEST_EFFORT), VOLATILE."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=DurabilityPolicy.VOLATILE)


def to_records(reports: Sequence[Report]) -> list[StatusRecord]:
    return [StatusRecord(r.level, r.name, r.message, r.values) for r in reports]


class NmtNode(Node):
    """Base of the nmt_ros nodes: parameters, status, readiness gate, done/exit code."""

    def __init__(self, name: str, *, exit_default: bool = False, gated: bool = True,
                 **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.done = False
        self.exit_code = 0
        self.inputs_open = False
        self.status = NodeStatus(self.get_fully_qualified_name())
        self.status_period_s = self.param(
            'status_period_s', 0.5, 'period of the /nmt/status summary [s]', low=0.01, high=60.0)
        self.qos_depth = self.param(
            'qos_depth', 5000, 'KEEP_LAST depth of the data topics (publishers and '
            'subscriptions); the backlog a slow reader may build without loss', low=1,
            high=1_000_000)
        self.wait_for_spec = self.param(
            'wait_for', [''], "outputs that must have subscribers before inputs are opened: "
            "'/topic=N' entries ('' = none)") if gated else []
        self.wait_timeout_s = self.param(
            'wait_timeout_s', 30.0, 'longest wait for those subscribers [s]; then the inputs '
            'open anyway and the shortfall is reported', low=0.0, high=3600.0)
        self.exit_when_finished = self.param(
            'exit_when_finished', exit_default, 'leave the spin loop (end the process) once '
            'the work is finished and the outputs are acknowledged (nmt launch sets it)')
        self.wait_for = parse_wait_for(self.wait_for_spec)
        self.status_pub = self.create_publisher(DiagnosticArray, STATUS_TOPIC, STATUS_QOS)
        self._status_timer = self.create_timer(self.status_period_s, self.publish_status)
        self._gate_started = time.monotonic()
        self._last_status = 0.0
        self._gate_timer = None

    # ------------------------------------------------------------------ parameters
    def param(self, name: str, default: Any, description: str, *, low: float | None = None,
              high: float | None = None, read_only: bool = True) -> Any:
        """Declare one parameter (type of ``default``) and return its value."""
        descriptor = ParameterDescriptor(description=description, read_only=read_only)
        if low is not None and isinstance(default, float):
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(low), to_value=float(high), step=0.0)]
        elif low is not None and isinstance(default, int) and not isinstance(default, bool):
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                                     step=0)]
        if isinstance(default, list) and default == ['']:
            # an empty string array must be typed explicitly
            value = self.declare_parameter(name, Parameter.Type.STRING_ARRAY, descriptor)
            got = value.value
            return [v for v in (got or []) if v]
        return self.declare_parameter(name, default, descriptor).value

    # ------------------------------------------------------------------ status
    def status_values(self) -> None:
        """Hook: refresh ``self.status.extra`` before a report."""

    def notify(self, min_interval_s: float = 0.1) -> None:
        """Publish the status now unless that was done less than ``min_interval_s`` ago
        (rejections and events are reported promptly without flooding the topic)."""
        if time.monotonic() - self._last_status >= min_interval_s:
            self.publish_status()

    def publish_status(self, extra: Sequence[Report] = ()) -> None:
        self._last_status = time.monotonic()
        self.status_values()
        reports = self.status.reports() + list(extra)
        self.status_pub.publish(to_diagnostic_array(self.get_clock().now().nanoseconds,
                                                    to_records(reports)))

    def announce_end(self, counts: dict[str, int], first_stamps: dict[str, int],
                     **extra: object) -> None:
        """Publish the end-of-stream record for our outputs (consumers flush on it)."""
        record = Report(0, f'{self.status.node}: {STREAM_PART}', 'finished',
                        end_of_stream_values(counts, first_stamps, **extra))
        self.publish_status([record])

    # ------------------------------------------------------------------ readiness
    def open_inputs_when_ready(self, open_inputs: Callable[[], None]) -> None:
        """Call ``open_inputs`` once every ``wait_for`` topic has its subscribers."""
        if not self.wait_for:
            self.inputs_open = True
            open_inputs()
            return
        self.status.state = 'waiting'

        def check() -> None:
            counts = {t: self.count_subscribers(t) for t in self.wait_for}
            missing = missing_subscribers(self.wait_for, counts)
            waited = time.monotonic() - self._gate_started
            if missing and waited < self.wait_timeout_s:
                self.status.detail = f'waiting for subscribers: {missing}'
                return
            self._gate_timer.cancel()
            self.destroy_timer(self._gate_timer)
            if missing:
                self.status.event(1, f'opened inputs after {waited:.1f} s without the '
                                  f'expected subscribers: {missing}')
            self.status.detail = ''
            self.inputs_open = True
            open_inputs()
            self.publish_status()

        self._gate_timer = self.create_timer(0.02, check)

    # ------------------------------------------------------------------ shutdown
    def wait_for_acks(self, timeout_s: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged all our publications."""
        ok = True
        for pub in list(self.publishers):
            try:
                ok &= bool(pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9))))
            except Exception:  # noqa: BLE001 - a destroyed publisher or shut down context
                ok = False
        return ok

    def on_shutdown(self, interrupted: bool) -> None:
        """Hook run by :func:`run_node` after the spin loop (before destroy_node)."""


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
    EventsExecutor, several times cheaper per callback, for nodes without raw subscriptions."""
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
    node = None
    try:
        node = factory()
        executor = make_executor(executor)
        executor.add_node(node)
        while rclpy.ok() and not stop.event.is_set() and not node.done:
            executor.spin_once(timeout_sec=0.05)
        node.on_shutdown(interrupted=stop.event.is_set())
        return node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        if node is not None:
            node.on_shutdown(interrupted=True)
        return 0 if node is None else node.exit_code
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler)
