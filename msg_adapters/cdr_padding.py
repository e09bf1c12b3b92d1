"""Deterministic bytes for serialised messages: CDR alignment padding set to zero.

rclpy's serializer leaves the alignment padding of a CDR message (after a string, before
the first double of a sequence) as whatever was in memory, so the same message serialises
to different bytes from run to run (the values are equal). A bag written from the same data
must be the same file, so the padding of the message types our bags carry (``JointState``,
``WrenchStamped``) is zeroed by walking their layout; other types are returned unchanged.
Alignment in CDR counts from the end of the 4-byte encapsulation header.
"""
from __future__ import annotations

import struct

_ENC = 4


class _Walker:
    def __init__(self, blob: bytes) -> None:
        if len(blob) < _ENC or blob[1] not in (0, 1):
            raise ValueError('not a plain CDR message (encapsulation header)')
        self.b = bytearray(blob)
        self.fmt = '<I' if blob[1] == 1 else '>I'
        self.pos = _ENC

    def align(self, size: int) -> None:
        pad = (-(self.pos - _ENC)) % size
        self.b[self.pos:self.pos + pad] = bytes(pad)
        self.pos += pad

    def uint32(self) -> int:
        self.align(4)
        (value,) = struct.unpack_from(self.fmt, self.b, self.pos)
        self.pos += 4
        return value

    def string(self) -> None:
        n = self.uint32()          # (not `self.pos += self.uint32()`: pos is read first)
        self.pos += n

    def header(self) -> None:
        self.uint32()
        self.uint32()
        self.string()

    def doubles(self, n: int) -> None:
        if n:
            self.align(8)
            self.pos += 8 * n

    def done(self) -> bytes:
        if self.pos > len(self.b):
            raise ValueError('CDR message shorter than its layout')
        self.b[self.pos:] = bytes(len(self.b) - self.pos)   # trailing alignment
        return bytes(self.b)


def zero_padding(blob: bytes, msgtype: str) -> bytes:
    """``blob`` (a CDR message of ``msgtype``) with its alignment padding zeroed."""
    if msgtype == 'sensor_msgs/msg/JointState':
        w = _Walker(blob)
        w.header()
        for _ in range(w.uint32()):
            w.string()
        for _ in range(3):                   # position, velocity, effort
            w.doubles(w.uint32())
        return w.done()
    if msgtype == 'geometry_msgs/msg/WrenchStamped':
        w = _Walker(blob)
        w.header()
        w.doubles(6)
        return w.done()
    return blob
