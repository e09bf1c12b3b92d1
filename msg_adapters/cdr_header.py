"""Header stamps straight from serialised (CDR) messages, without deserialising them.

Every message type whose first field is ``std_msgs/Header`` (JointState, WrenchStamped,
DiagnosticArray, ...) starts, after the 4-byte CDR encapsulation header, with
``int32 sec, uint32 nanosec``. Reading those 8 bytes is enough to pair recorded messages by
the observation instant they refer to (latency analysis of a recording), and it is
vectorised over a whole topic.
"""
from __future__ import annotations

from collections.abc import Sequence
import struct

import numpy as np

NS_PER_S = 1_000_000_000
_ENCAPSULATION = 4


def header_stamp_ns(blob: bytes) -> int:
    """Header stamp [ns] of one CDR message whose first field is a ``std_msgs/Header``
    (``struct``, a few us: the live view reads one per message)."""
    if len(blob) < _ENCAPSULATION + 8:
        raise ValueError(f'CDR message too short to carry a header ({len(blob)} bytes)')
    sec, nsec = struct.unpack_from('<iI' if blob[1] == 1 else '>iI', blob, _ENCAPSULATION)
    if nsec >= NS_PER_S:
        raise ValueError(f'CDR message: nanosec {nsec} out of range (not a Header?)')
    return sec * NS_PER_S + nsec


def header_stamps_ns(blobs: Sequence[bytes]) -> np.ndarray:
    """Header stamps [ns] ``int64[n]`` of CDR messages that start with a Header."""
    n = len(blobs)
    out = np.empty(n, dtype=np.int64)
    if n == 0:
        return out
    heads = b''.join(bytes(b[:_ENCAPSULATION + 8]) for b in blobs)
    if len(heads) != n * (_ENCAPSULATION + 8):
        short = next(i for i, b in enumerate(blobs) if len(b) < _ENCAPSULATION + 8)
        raise ValueError(f'CDR message {short} is too short to carry a header '
                         f'({len(blobs[short])} bytes)')
    raw = np.frombuffer(heads, dtype=np.uint8).reshape(n, _ENCAPSULATION + 8)
    little = raw[:, 1] == 1
    body = raw[:, _ENCAPSULATION:]
    sec = np.where(little, body[:, :4].copy().view('<i4')[:, 0],
                   body[:, :4].copy().view('>i4')[:, 0]).astype(np.int64)
    nsec = np.where(little, body[:, 4:].copy().view('<u4')[:, 0],
                    body[:, 4:].copy().view('>u4')[:, 0]).astype(np.int64)
    if (nsec >= NS_PER_S).any():
        i = int(np.flatnonzero(nsec >= NS_PER_S)[0])
        raise ValueError(f'CDR message {i}: nanosec {nsec[i]} out of range (not a Header?)')
    out[:] = sec * NS_PER_S + nsec
    return out


def with_header_stamp(blob: bytes, stamp_ns: int) -> bytes:
    """A copy of a CDR message that starts with a ``std_msgs/Header`` with its stamp set to
    ``stamp_ns`` [ns] (the rest of the bytes unchanged), in the message's own byte order."""
    if len(blob) < _ENCAPSULATION + 8:
        raise ValueError(f'CDR message too short to carry a header ({len(blob)} bytes)')
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    if not -(1 << 31) <= sec < (1 << 31):
        raise ValueError(f'stamp {stamp_ns} ns does not fit a builtin_interfaces/Time')
    order = '<' if blob[1] == 1 else '>'
    head = struct.pack(f'{order}iI', sec, nanosec)
    return bytes(blob[:_ENCAPSULATION]) + head + bytes(blob[_ENCAPSULATION + 8:])
