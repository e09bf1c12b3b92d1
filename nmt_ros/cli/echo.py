"""``nmt echo TOPIC [TYPE]``: print a topic's messages like ``ros2 topic echo``.

The type is discovered from the ROS graph (``get_topic_names_and_types``), waiting for a
publisher when the topic is not there yet. The subscription QoS adapts to the publishers as
ros2cli does: start from the sensor-data profile (best effort, depth 5) and ask for RELIABLE
or TRANSIENT_LOCAL only when every publisher offers it; ``--qos-*`` options override. The text
comes from ``nmt_ros.io.msg_yaml`` (YAML then ``---``, or ``--csv`` lines).

``--timeout S`` bounds the whole run: with ``--once`` it is the time allowed for the first
message (exit 1 if none came), otherwise echo stops after S seconds.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable
import copy
from dataclasses import dataclass
import os
import sys
import time
from typing import Any

from nmt_ros.io.msg_yaml import format_echo

ACCEPTS_EXTRA_ARGS = True  # --ros-args ... goes to rclpy.init

_RELIABILITY = ('system_default', 'reliable', 'best_effort')
_DURABILITY = ('system_default', 'transient_local', 'volatile')
_HISTORY = ('system_default', 'keep_last', 'keep_all')
_PROFILES = ('system_default', 'sensor_data', 'services_default', 'parameters',
             'parameter_events', 'action_status_default')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('topic_name', help="name of the topic to echo (e.g. '/chatter')")
    parser.add_argument('message_type', nargs='?',
                        help="type of the message (e.g. 'sensor_msgs/msg/JointState'); "
                             'discovered from the graph when omitted')
    parser.add_argument('--once', action='store_true', help='print the first message and exit')
    parser.add_argument('--timeout', type=float, default=None, metavar='S',
                        help='give up after S seconds (with --once: exit 1 if nothing came)')
    parser.add_argument('--csv', action='store_true', help='comma-separated values')
    parser.add_argument('--truncate-length', '-l', type=int, default=128, metavar='N',
                        help='truncate arrays, bytes and strings to N (default 128)')
    parser.add_argument('--full-length', '-f', action='store_true',
                        help='do not truncate (overrides --truncate-length)')
    parser.add_argument('--no-arr', action='store_true', help='do not print arrays')
    parser.add_argument('--no-str', action='store_true', help='do not print strings')
    parser.add_argument('--flow-style', action='store_true', help='YAML flow style')
    parser.add_argument('--qos-profile', choices=_PROFILES,
                        help='QoS preset to start from (default: adapt to the publishers)')
    parser.add_argument('--qos-depth', type=int, default=None, metavar='N')
    parser.add_argument('--qos-history', choices=_HISTORY)
    parser.add_argument('--qos-reliability', choices=_RELIABILITY)
    parser.add_argument('--qos-durability', choices=_DURABILITY)


@dataclass
class EchoOptions:
    """How to format and when to stop."""

    once: bool = False
    timeout_s: float | None = None
    csv: bool = False
    truncate_length: int | None = 128
    no_arr: bool = False
    no_str: bool = False
    flow_style: bool = False

    def format(self, msg: Any) -> str:
        return format_echo(msg, csv=self.csv, truncate_length=self.truncate_length,
                           no_arr=self.no_arr, no_str=self.no_str, flow_style=self.flow_style)


def choose_qos(node: Any, topic: str, *, profile: str | None = None, depth: int | None = None,
               history: str | None = None, reliability: str | None = None,
               durability: str | None = None, warn: Callable[[str], None] | None = None) -> Any:
    """The subscription QoS (ros2cli's rule; explicit settings win)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSPresetProfiles, ReliabilityPolicy
    explicit = any(v is not None for v in (profile, depth, history, reliability, durability))
    # a copy: the preset is rclpy's module-level profile object, shared by the whole process
    qos = copy.copy(QoSPresetProfiles.get_from_short_key(profile or 'sensor_data'))
    if explicit:
        if depth is not None:
            qos.depth = depth
        if history is not None:
            qos.history = HistoryPolicy[history.upper()]
        if reliability is not None:
            qos.reliability = ReliabilityPolicy[reliability.upper()]
        if durability is not None:
            qos.durability = DurabilityPolicy[durability.upper()]
        return qos
    infos = node.get_publishers_info_by_topic(topic)
    if not infos:
        return qos
    # the stronger policy only if every publisher offers it
    for policy, strong, weak in (
            ('reliability', ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT),
            ('durability', DurabilityPolicy.TRANSIENT_LOCAL, DurabilityPolicy.VOLATILE)):
        offering = sum(getattr(i.qos_profile, policy) == strong for i in infos)
        if 0 < offering < len(infos) and warn:
            warn(f'Some, but not all, publishers are offering {_policy_name(strong)}. '
                 f'Falling back to {_policy_name(weak)} as it will connect to all publishers')
        setattr(qos, policy, strong if offering == len(infos) else weak)
    return qos


def _policy_name(value: Any) -> str:
    """``ReliabilityPolicy.RELIABLE`` (as ros2cli prints it)."""
    return f'{type(value).__name__}.{value.name}'


def wait_for_topic_type(node: Any, executor: Any, topic: str, deadline: float | None,
                        warn: Callable[[str], None] | None = None) -> str | None:
    """The topic's type once a publisher/subscriber announced it (None at the deadline)."""
    warned = False
    while True:
        types = dict(node.get_topic_names_and_types()).get(topic)
        if types:
            if len(types) > 1:
                raise ValueError(f'topic {topic} has more than one type: {types}; '
                                 'pass the type explicitly')
            return types[0]
        if warn and not warned:
            warn(f'WARNING: topic [{topic}] does not appear to be published yet')
            warned = True
        if deadline is not None and time.monotonic() >= deadline:
            return None
        executor.spin_once(timeout_sec=0.05)


def echo(node: Any, executor: Any, topic: str, *, msg_type: str | None = None,
         options: EchoOptions | None = None, qos: Any = None,
         write: Callable[[str], Any] = sys.stdout.write,
         warn: Callable[[str], None] | None = None, stop: Any = None) -> int:
    """Subscribe on ``node`` and write formatted messages until done; returns the count.

    ``executor`` must have ``node`` added; it is spun here. ``stop``: ``threading.Event``-like
    object ending the loop. Raises ``TimeoutError`` if the type cannot be discovered in time.
    """
    from nmt_ros.io.msgdefs import get_message_class
    options = options or EchoOptions()
    topic = node.resolve_topic_name(topic)
    deadline = None if options.timeout_s is None else time.monotonic() + options.timeout_s
    if msg_type is None:
        msg_type = wait_for_topic_type(node, executor, topic, deadline, warn)
        if msg_type is None:
            raise TimeoutError(f'could not determine the type of {topic} within '
                               f'{options.timeout_s:g} s (no publisher?)')
    msg_class = get_message_class(msg_type)
    if qos is None:
        qos = choose_qos(node, topic, warn=warn)
    count = 0

    def callback(msg: Any) -> None:
        nonlocal count
        if options.once and count:
            return
        write(options.format(msg))
        count += 1

    subscription = node.create_subscription(msg_class, topic, callback, qos)
    try:
        while not (options.once and count):
            if stop is not None and stop.is_set():
                break
            if deadline is not None and time.monotonic() >= deadline:
                break
            executor.spin_once(timeout_sec=0.05)
    finally:
        node.destroy_subscription(subscription)
    return count


def run(args: argparse.Namespace) -> int:
    from rclpy.executors import SingleThreadedExecutor

    from nmt_ros.nodes.runtime import cli_node

    options = EchoOptions(
        once=args.once, timeout_s=args.timeout, csv=args.csv,
        truncate_length=None if args.full_length else args.truncate_length,
        no_arr=args.no_arr, no_str=args.no_str, flow_style=args.flow_style)

    def warn(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def write(text: str) -> None:
        sys.stdout.write(text)
        sys.stdout.flush()

    with cli_node(args, f'_nmt_echo_{os.getpid()}', start_parameter_services=False) as node:
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        try:
            topic = node.resolve_topic_name(args.topic_name)
            qos = None
            if any(v is not None for v in (args.qos_profile, args.qos_depth, args.qos_history,
                                           args.qos_reliability, args.qos_durability)):
                qos = choose_qos(node, topic, profile=args.qos_profile, depth=args.qos_depth,
                                 history=args.qos_history, reliability=args.qos_reliability,
                                 durability=args.qos_durability)
            count = echo(node, executor, topic, msg_type=args.message_type, options=options,
                         qos=qos, write=write, warn=warn)
            if options.once and count == 0:
                warn(f'no message received on {topic} within {options.timeout_s:g} s')
                return 1
            return 0
        except (TimeoutError, ValueError) as exc:
            warn(f'error: {exc}')
            return 1
        except KeyboardInterrupt:
            return 0
        finally:
            executor.shutdown()
