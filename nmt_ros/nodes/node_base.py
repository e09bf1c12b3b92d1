"""The nodes' rclpy base classes: QoS profiles, parameters, /nmt/status, readiness.

Every node is an :class:`NmtNode`: parameters are declared once (with a
``ParameterDescriptor``) and copied to attributes; ``/nmt/status`` (DiagnosticArray) is
published every ``status_period_s`` and at once when something noteworthy happens; inputs
are opened only when the node's outputs have the subscribers listed in ``wait_for``
(``'/topic=N'``, ``nmt_ros.nodes.readiness``), so readiness propagates upstream and nothing is
published into the void.

QoS: data topics are RELIABLE, KEEP_LAST ``qos_depth`` (default 5000, several seconds of the
1080 Hz stream), VOLATILE: a replay through the graph is lossless while any subscriber keeps
within that backlog, and best-effort tools (``nmt echo``) still connect. ``/nmt/status`` is
RELIABLE, KEEP_LAST 100, TRANSIENT_LOCAL: a consumer that matched late still gets the
end-of-stream announcement (announcements carry the trial's first stamp, so stale ones are
ignored).

:class:`TrackerNode` is what the two trackers share: the trial parameters, the input path
(count, parse, gate, start/restart a trial: ``nmt_ros.nodes.input_gate``), the end-of-stream
protocol (``nmt_ros.nodes.end_of_stream.TrialBook``), the idle watchdog and the counted
publication of output batches. A tracker node subscribes, converts, calls its stream
(``nmt_ros.tracking.streaming``) and publishes.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import functools
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from msg_adapters.diagnostics import StatusRecord, from_diagnostic_array, to_diagnostic_array
from msg_adapters.series import CheckedBlock
from msg_adapters.stamps import time_to_ns
from nmt_ros.model import compiled
from nmt_ros.nodes.end_of_stream import STREAM_PART, TrialBook, end_of_stream_values
from nmt_ros.nodes.input_gate import Sample, StreamGate, TrialClock
from nmt_ros.nodes.input_thread import InputThread
from nmt_ros.nodes.node_status import ERROR, OK, WARN, NodeStatus, Report
from nmt_ros.nodes.polled_subscriptions import PolledSubscriptions
from nmt_ros.nodes.readiness import missing_subscribers, parse_wait_for
from nmt_ros.nodes.thread_policy import MIDDLEWARE_THREAD_PREFIXES, BatchThreads
from nmt_ros.topics import STATUS

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

    #: default of ``batch_thread_prefixes`` (``thread_policy``)
    BATCH_THREAD_PREFIXES: tuple[str, ...] = MIDDLEWARE_THREAD_PREFIXES

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
        self.batch_threads = BatchThreads(self.param(
            'batch_thread_prefixes', list(self.BATCH_THREAD_PREFIXES) or [''], "this "
            "process's threads whose names start with these run under Linux's SCHED_BATCH, "
            "so their wake-ups stop preempting the node's computation (the middleware's: Fast "
            "DDS 'dds.*'; [''] = none; nmt_ros.nodes.thread_policy)"))
        self._batch_refusals = 0
        self.batch_middleware_threads()
        self.wait_for_spec = self.param(
            'wait_for', [''], "outputs that must have subscribers before inputs are opened: "
            "'/topic=N' entries ('' = none)") if gated else []
        self.wait_timeout_s = self.param(
            'wait_timeout_s', 300.0, 'longest wait for those subscribers [s] (a first run '
            'compiles the estimators, minutes on 2 cores); then the inputs open anyway and the '
            'shortfall is reported', low=0.0, high=3600.0)
        self.exit_when_finished = self.param(
            'exit_when_finished', exit_default, 'leave the spin loop (end the process) once '
            'the work is finished and the outputs are acknowledged (nmt launch sets it)')
        self.wait_for = parse_wait_for(self.wait_for_spec)
        self.status_pub = self.create_publisher(DiagnosticArray, STATUS, STATUS_QOS)
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

    def fail_to_start(self, error: str) -> None:
        """Report and log why the node cannot work; the process ends with exit code 1."""
        self.status.error = error
        self.get_logger().error(error)
        self.exit_code = 1
        self.done = True

    # ------------------------------------------------------------------ status
    def status_values(self) -> None:
        """Hook: refresh ``self.status.extra`` before a report."""

    def notify(self, min_interval_s: float = 0.1) -> None:
        """Publish the status now unless that was done less than ``min_interval_s`` ago
        (rejections and events are reported promptly without flooding the topic)."""
        if time.monotonic() - self._last_status >= min_interval_s:
            self.publish_status()

    def batch_middleware_threads(self) -> None:
        """Put new ``batch_thread_prefixes`` threads under SCHED_BATCH (``thread_policy``); a
        refusal by the system is reported once per thread (a warning: they keep their
        policy, the node works on)."""
        self.batch_threads.apply()
        failed = list(self.batch_threads.failed.values())
        if len(failed) > self._batch_refusals:
            self.status.event(WARN, 'threads kept their scheduling policy (SCHED_BATCH '
                              f"refused): {'; '.join(failed[self._batch_refusals:])}")
            self._batch_refusals = len(failed)

    def publish_status(self, extra: Sequence[Report] = ()) -> None:
        self._last_status = time.monotonic()
        self.batch_middleware_threads()      # the middleware may have started more threads
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


class TrackerNode(NmtNode):
    """Base of the trackers: gated input streams, trials, end of stream, idle watchdog.

    A subclass names its ``INPUTS`` and ``OUTPUTS`` (topic -> message type), builds
    ``self.stream`` (``reset()`` starts a trial), ``self.gates`` (:meth:`stream_gates`) and,
    if the epoch is a parameter, ``self.clock``; then it calls :meth:`listen`. It implements
    :meth:`parse` (message -> stamp, values; ValueError rejects it), :meth:`feed` (the samples
    the gate let through) and :meth:`flush` (the last outputs of a trial), and publishes
    with :meth:`publish_batches`. A trial starts with the first accepted sample and ends
    (:meth:`_finish`) on the producers' end of stream, after ``idle_flush_s`` without input
    or at a gap longer than ``max_gap_s`` (new data then start the next trial).
    """

    INPUTS: Mapping[str, type] = {}
    OUTPUTS: Mapping[str, type] = {}

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        p = self.param
        self.gap_factor = p('gap_factor', 1.5, 'a spacing above this many periods is a gap '
                            '(filled by interpolation, reported)', low=1.01, high=100.0)
        self.max_gap_s = p('max_gap_s', 0.5, 'a longer gap ends the trial [s]', low=0.0,
                           high=3600.0)
        self.idle_flush_s = p('idle_flush_s', 1.0, 'end the trial after this long without '
                              'input [s] (0 = never)', low=0.0, high=3600.0)
        self.end_timeout_s = p('end_timeout_s', 2.0, 'after an end-of-stream announcement, '
                               'flush at the latest after this long even if messages are '
                               'missing [s]', low=0.0, high=3600.0)
        self.input_reliable = p('input_reliable', True, 'subscribe RELIABLE (lossless); '
                                'false: BEST_EFFORT, to accept best-effort sources')
        self.take_period_s = p('take_period_s', 0.01, 'inputs taken in batches this often '
                               '[s], merged in stamp order (one executor wake-up per batch '
                               'instead of per message; 0 = a callback per message)',
                               low=0.0, high=1.0)
        self.polled: InputThread | None = None
        self.input_overflow_said = False
        self.taking = False
        self.book = TrialBook(self.INPUTS)
        self.clock = TrialClock(0)
        self.gates: dict[str, StreamGate] = {}
        self.stream: Any = None
        self.tracking = False
        self.last_input = time.monotonic()
        self.newest_input_ns = 0
        self.newest_output_ns = 0
        self.pubs: dict[str, Any] = {}

    def stream_gates(self, periods_s: Mapping[str, float],
                     fill_gaps: bool = True) -> dict[str, StreamGate]:
        """One :class:`StreamGate` per input topic (nominal period [s] each; gaps filled by
        interpolation or, ``fill_gaps`` False, only reported)."""
        return {topic: StreamGate(topic, period, self.gap_factor, self.max_gap_s, fill_gaps)
                for topic, period in periods_s.items()}

    def listen(self) -> None:
        """Create the publishers and the watchdog, hear end-of-stream announcements and open
        the inputs once the outputs have their subscribers (``wait_for``)."""
        qos = data_qos(self.qos_depth)
        self.pubs = {topic: self.create_publisher(kind, topic, qos)
                     for topic, kind in self.OUTPUTS.items()}
        self.create_timer(0.05, self.watchdog)
        # the numerical core is built: say what it compiled (first run on a machine) or why
        # it runs in CasADi's virtual machine (no C compiler: several times slower)
        for note in compiled.notes():
            self.status.event(OK, note)
        if compiled.compile_problem() is not None:
            self.status.event(WARN, compiled.compile_problem())
        self.status.state = 'ready'
        # end-of-stream announcements (transient local: heard even if matched late)
        self.create_subscription(DiagnosticArray, STATUS, self.on_status, STATUS_QOS)
        self.open_inputs_when_ready(self._open_inputs)

    def _open_inputs(self) -> None:
        qos = data_qos(self.qos_depth, self.input_reliable)
        if self.take_period_s > 0:
            polled = PolledSubscriptions(self)
            # taken fastest stream first: while a long take of the force plate runs, newer
            # samples of the slower stream arrive and are taken after it, so a batch never
            # holds the fast stream far ahead of the slow one (a node that fell behind took
            # 0.3 s of force-plate data past its mocap and rejected mocap samples as late)
            periods = {topic: gate.period_ns for topic, gate in self.gates.items()}
            for topic in sorted(self.INPUTS, key=lambda t: periods.get(t, 0)):
                polled.add(topic, self.INPUTS[topic], qos, raw=True)
            # taken on a thread of their own: the middleware's history never overflows while
            # a batch is estimated (``input_thread``)
            self.polled = InputThread(polled, self.take_period_s)
            self.create_timer(self.take_period_s, self.take_inputs)
        else:
            for topic, kind in self.INPUTS.items():
                self.create_subscription(kind, topic, functools.partial(self.on_input, topic),
                                         qos)
        self.status.state = 'ready'

    def destroy_node(self) -> None:
        if self.polled is not None:
            self.polled.destroy()
            self.polled = None
        super().destroy_node()

    def take_inputs(self) -> None:
        """Every waiting input message, all topics merged in header-stamp order (equal
        stamps: in the order of ``INPUTS``), through :meth:`on_input`: what the trackers
        compute depends on the stamps alone, not on how arrivals were batched."""
        if self.polled is None or self.taking:
            return
        self.taking = True
        try:
            self._take_batch()
        finally:
            self.taking = False

    def _take_batch(self) -> None:
        taken = self.polled.take_all()
        if self.polled.overflowed and not self.input_overflow_said:
            self.input_overflow_said = True
            self.status.event(ERROR, f'more than {self.polled.max_messages} input messages '
                              'waiting: the node stopped taking more; the middleware keeps '
                              f'the newest {self.qos_depth} per topic, older ones are lost')
        if not taken:
            return
        # each topic's raw messages decoded and checked as one array (``parse_block``), then
        # handled one by one in (stamp, INPUTS order, arrival) order
        rank = {topic: k for k, topic in enumerate(self.INPUTS)}
        blocks = {topic: self.parse_block(topic, [blob for blob, _info in msgs])
                  for topic, msgs in taken.items()}
        topics = list(blocks)
        stamps = np.concatenate([b.stamp_ns for b in blocks.values()])
        which = np.concatenate([np.full(len(b), k) for k, b in enumerate(blocks.values())])
        index = np.concatenate([np.arange(len(b)) for b in blocks.values()])
        ranks = np.array([rank[t] for t in topics])[which]
        before = self.last_input
        for j in np.lexsort((index, ranks, stamps)).tolist():
            topic = topics[which[j]]
            block, i = blocks[topic], int(index[j])
            stamp = int(block.stamp_ns[i])
            error = block.errors[i]
            self.accept(topic, stamp if block.stamped[i] else None,
                        None if error else (stamp, block.values[i]),
                        f'{topic}: {error}' if error else None, time.monotonic())
        self.batch_done()
        if self.last_input != before:       # idle counts from when the batch was handled
            self.last_input = time.monotonic()

    def batch_done(self) -> None:
        """Hook: a batch of inputs went through :meth:`on_input` (a subclass may defer work
        to here, e.g. to see how far behind the data it is)."""

    # ------------------------------------------------------------------ hooks
    def parse(self, topic: str, msg: Any) -> tuple[int, np.ndarray]:
        """(stamp [ns], values) of an input message; ValueError rejects it."""
        raise NotImplementedError

    def parse_block(self, topic: str, blobs: Sequence[bytes]) -> CheckedBlock:
        """The CDR messages of one batch of ``topic``, each checked as :meth:`parse` checks
        one (values in the same columns, the same reasons for a refusal)."""
        raise NotImplementedError

    def feed(self, topic: str, samples: Sequence[Sample], stamp_ns: int,
             received: float) -> None:
        """Process the samples the gate let through for the message stamped ``stamp_ns``
        (received at monotonic time ``received``)."""
        raise NotImplementedError

    def flush(self) -> None:
        """Publish the trial's last outputs (the trial is ending)."""

    def on_trial_start(self, epoch_ns: int) -> None:
        """Reset per-trial state of the subclass."""

    def end_state(self) -> str:
        """``status.state`` of a finished trial."""
        return 'finished'

    # ------------------------------------------------------------------ inputs
    def on_input(self, topic: str, msg: Any) -> None:
        """One typed message (a callback per message: ``take_period_s`` 0)."""
        received = time.monotonic()
        try:
            parsed, error = self.parse(topic, msg), None
        except ValueError as exc:
            parsed, error = None, f'{topic}: {exc}'
        self.accept(topic, time_to_ns(msg.header.stamp), parsed, error, received)

    def accept(self, topic: str, header_ns: int | None,
               parsed: tuple[int, np.ndarray] | None, error: str | None,
               received: float) -> None:
        """One input message, parsed (``(stamp [ns], values)``) or refused (``error``): count
        it (``header_ns``: its header stamp, None if unreadable), gate it, feed it."""
        self.status.receive(topic)
        self.book.saw(topic, header_ns)
        if parsed is None:
            self.status.reject(topic, error or f'{topic}: refused')
            self.notify()
            return
        stamp_ns, values = parsed
        self.status.mark_active()
        self.last_input = received
        if not self.tracking:
            self._start_trial(stamp_ns)
        gate = self.gates[topic]
        result = gate.offer(stamp_ns, values)
        if result.rejected:
            self.status.reject(topic, result.rejected)
            self.notify()
            return
        if result.restart:
            self.status.event(WARN, result.restart)
            self._finish(result.restart, more_follows=True)
            self._start_trial(stamp_ns)      # this message stays counted (same stream)
            result = gate.offer(stamp_ns, values)
        if result.gap:
            self.status.interpolated += len(result.samples) - 1
            self.status.event(WARN, result.gap)
        self.feed(topic, result.samples, stamp_ns, received)
        # idle time counts from when the input was handled, not from its arrival: a long
        # computation (an estimator's re-initialisation) is not a silent input
        self.last_input = time.monotonic()

    def on_status(self, msg: DiagnosticArray) -> None:
        self.take_inputs()           # what was sent before an announcement counts first
        _, records = from_diagnostic_array(msg)
        if any(self.book.announcement(r.values, time.monotonic()) for r in records):
            self._check_end()

    # ------------------------------------------------------------------ trial
    def _start_trial(self, stamp_ns: int) -> None:
        trial = self.book.start()
        self.stream.reset()
        self.clock.reset()
        epoch = self.clock.start(stamp_ns)
        for gate in self.gates.values():
            gate.reset()
            gate.not_before_ns = epoch
        self.status.error = None
        self.tracking = True
        self.status.state = 'tracking'
        self.status.detail = f'trial {trial}'
        self.status.extra['trial'] = trial
        self.on_trial_start(epoch)

    def _check_end(self) -> None:
        if self.tracking:
            why = self.book.verdict(time.monotonic(), self.end_timeout_s)
            if why:
                if 'missing' in why:
                    self.status.event(ERROR, why)
                self._finish(why)

    def _finish(self, why: str, more_follows: bool = False) -> None:
        """End the trial (flush, announce); ``more_follows``: a new trial starts at once
        (a gap in the input), so an ``exit_when_finished`` node stays up."""
        if not self.tracking:
            return
        self.flush()
        self.tracking = False
        self.status.state = self.end_state()
        self.status.detail = f'trial {self.book.trial} finished: {why}'
        counts, firsts = self.book.finish(more_follows)
        self.announce_end(counts, firsts, trial=self.book.trial, reason=why)
        if self.exit_when_finished and not more_follows:
            self.done = True

    def watchdog(self) -> None:
        """Idle/publisher-gone detection and the end-of-stream timeout (judged after the
        inputs waiting in the middleware were taken)."""
        self.take_inputs()
        if not self.tracking:
            return
        self._check_end()
        if not self.tracking:
            return
        idle = time.monotonic() - self.last_input
        if self.idle_flush_s > 0 and idle > self.idle_flush_s:
            gone = [t for t in self.INPUTS if self.count_publishers(t) == 0]
            why = f'no input for {idle:.2f} s'
            if gone:
                why += '; publisher gone' + (f' on {gone}' if len(self.INPUTS) > 1 else '')
            self.status.event(ERROR if gone else WARN, why)
            self._finish(why)

    # ------------------------------------------------------------------ outputs
    def publish_batches(self, stamps: np.ndarray, batches: Mapping[str, Sequence[Any]]) -> None:
        """Publish one message per stamp and topic (interleaved by stamp); count them for the
        status and for our end-of-stream announcement."""
        for i in range(stamps.size):
            for topic, msgs in batches.items():
                self.pubs[topic].publish(msgs[i])
        for topic in batches:
            self.status.publish(topic, stamps.size)
            self.book.output(topic, int(stamps[0]), stamps.size)
        self.newest_output_ns = int(stamps[-1])

    def status_values(self) -> None:
        self.status.extra['data_lag_ms'] = (
            (self.newest_input_ns - self.newest_output_ns) / 1e6
            if self.newest_output_ns else float('nan'))

    def on_shutdown(self, interrupted: bool) -> None:
        if not interrupted:
            self.publish_status()
            if not self.wait_for_acks(10.0):
                self.exit_code = 1
