"""``geometry_msgs/msg/WrenchStamped`` <-> (stamp, frame_id, force xyz, torque xyz).

WrenchStamped has no variable-length arrays, so the rosbags CDR padding issue of JointState
does not arise. Values are validated (finite, three components) before a message is built.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
import numpy as np
from std_msgs.msg import Header

from .cdr_arrays import encode_wrenches
from .series import WrenchSeries
from .stamps import stamps_to_ns, time_to_ns, times_from_ns, to_time
from .validation import as_matrix, as_vector, check_finite

AXES = ('x', 'y', 'z')


@dataclass(frozen=True)
class WrenchSample:
    """One WrenchStamped as arrays."""

    stamp_ns: int
    frame_id: str
    force: np.ndarray   # [3] N
    torque: np.ndarray  # [3] N m


def _vec(values: np.ndarray) -> Vector3:
    return Vector3(x=float(values[0]), y=float(values[1]), z=float(values[2]))


def to_wrench_stamped(stamp: Any, frame_id: str, force: Any,
                      torque: Any = (0.0, 0.0, 0.0)) -> WrenchStamped:
    """Build one WrenchStamped from xyz force [N] and torque [N m]."""
    f = as_vector(force, 3, 'force', AXES)
    t = as_vector(torque, 3, 'torque', AXES)
    return WrenchStamped(header=Header(stamp=to_time(stamp), frame_id=frame_id),
                         wrench=Wrench(force=_vec(f), torque=_vec(t)))


def _values(msg: WrenchStamped) -> tuple[float, ...]:
    f, t = msg.wrench.force, msg.wrench.torque
    return (f.x, f.y, f.z, t.x, t.y, t.z)


def from_wrench_stamped(msg: WrenchStamped, frame_id: str | None = None,
                        check: bool = True) -> WrenchSample:
    """One WrenchStamped -> arrays; ``frame_id`` given: must match; ``check``: finite."""
    if frame_id is not None and msg.header.frame_id != frame_id:
        raise ValueError(f'WrenchStamped frame_id is {msg.header.frame_id!r}, '
                         f'expected {frame_id!r}')
    values = np.array(_values(msg))
    if check:
        check_finite(values, 'WrenchStamped (force xyz, torque xyz)')
    return WrenchSample(stamp_ns=time_to_ns(msg.header.stamp), frame_id=msg.header.frame_id,
                        force=values[:3], torque=values[3:])


def wrenches_from_arrays(stamps: Any, frame_id: str, force: Any,
                         torque: Any = None, allow_nan: bool = False) -> list[WrenchStamped]:
    """``n`` stamps, ``[n, 3]`` force and torque (default zero) -> ``n`` messages
    (``allow_nan``: NaN values allowed, for missing samples; inf is refused)."""
    stamp_ns = stamps_to_ns(stamps)
    n = stamp_ns.shape[0]
    f = as_matrix(force, n, 3, 'force', AXES, allow_nan=allow_nan)
    t = (np.zeros((n, 3)) if torque is None
         else as_matrix(torque, n, 3, 'torque', AXES, allow_nan=allow_nan))
    rows = np.hstack([f, t]).tolist()
    return [
        WrenchStamped(header=Header(stamp=stamp, frame_id=frame_id), wrench=Wrench(
            force=Vector3(x=r[0], y=r[1], z=r[2]), torque=Vector3(x=r[3], y=r[4], z=r[5])))
        for stamp, r in zip(times_from_ns(stamp_ns), rows)
    ]


def wrench_blobs(stamps: Any, frame_id: str, force: Any, torque: Any = None,
                 allow_nan: bool = False) -> list[bytes]:
    """The messages of :func:`wrenches_from_arrays` (same arguments, same checks),
    serialised (CDR, padding zero) without building message objects."""
    stamp_ns = stamps_to_ns(stamps)
    n = stamp_ns.shape[0]
    f = as_matrix(force, n, 3, 'force', AXES, allow_nan=allow_nan)
    t = (np.zeros((n, 3)) if torque is None
         else as_matrix(torque, n, 3, 'torque', AXES, allow_nan=allow_nan))
    return encode_wrenches(stamp_ns, f, t, frame_id)


def wrenches_to_arrays(msgs: Sequence[WrenchStamped], frame_id: str | None = None,
                       check: bool = True) -> WrenchSeries:
    """``n`` messages -> :class:`~msg_adapters.series.WrenchSeries` (one frame_id required)."""
    n = len(msgs)
    if n == 0:
        return WrenchSeries(np.empty(0, dtype=np.int64), frame_id or '', np.empty((0, 3)),
                            np.empty((0, 3)))
    frame = msgs[0].header.frame_id if frame_id is None else frame_id
    for i, m in enumerate(msgs):
        if m.header.frame_id != frame:
            raise ValueError(f'WrenchStamped message {i} has frame_id {m.header.frame_id!r}, '
                             f'expected {frame!r}')
    stamp_ns = np.fromiter((time_to_ns(m.header.stamp) for m in msgs), dtype=np.int64, count=n)
    values = np.array([_values(m) for m in msgs], dtype=np.float64).reshape(n, 6)
    if check:
        check_finite(values, 'WrenchStamped (force xyz, torque xyz)',
                     ('force.x', 'force.y', 'force.z', 'torque.x', 'torque.y', 'torque.z'))
    return WrenchSeries(stamp_ns=stamp_ns, frame_id=frame, force=values[:, :3],
                        torque=values[:, 3:])

