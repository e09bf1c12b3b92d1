"""``rosgraph_msgs/msg/Clock`` (the ``/clock`` topic) <-> stamps."""
from __future__ import annotations

from typing import Any

from rosgraph_msgs.msg import Clock

from .stamps import time_to_ns, to_time


def to_clock(stamp: Any) -> Clock:
    """A stamp (int ns or float s) -> Clock."""
    return Clock(clock=to_time(stamp))


def clock_to_ns(msg: Clock) -> int:
    """Clock -> int ns."""
    return time_to_ns(msg.clock)
