"""CDR-serialised JointState / WrenchStamped messages straight to and from numpy arrays.

A topic's messages normally share one layout (same joint names, same array lengths, same
frame id), hence the same byte length. Then the serialised messages are stacked into a
``[n, nbytes]`` uint8 matrix and every field is a column slice: no per-message Python work.
The layout is taken from the first message; a message that differs in length or in any
structural byte (string lengths and characters, sequence counts) is decoded individually.
Padding bytes are ignored (rclpy leaves them uninitialised).

Encoding is the same idea backwards (``encode_joint_states``, ``encode_wrenches``): one
message of the topic's layout is written field by field (little endian, padding zero), its
rows are tiled and the stamps and values written into columns; a live node publishes the
bytes (``Publisher.publish`` takes serialised messages) instead of building a Python message
object per sample (~50 us each at 1080 Hz).

CDR (XCDR1, plain): 4-byte encapsulation header (byte 1: 0x01 little endian, 0x00 big
endian), then each primitive aligned to its size relative to the end of that header; strings
are ``uint32`` length (including the NUL) + bytes; sequences are ``uint32`` count + elements.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import functools
import struct

import numpy as np

from .cdr_header import header_stamp_ns
from .series import JointStateSeries, WrenchSeries

_HEADER = 4  # encapsulation header bytes


class _Cursor:
    """Sequential CDR reader that also records which bytes carry structure vs values."""

    def __init__(self, data: bytes) -> None:
        if len(data) < _HEADER + 8:
            raise ValueError(f'CDR message too short ({len(data)} bytes)')
        self.data = data
        self.little = data[1] == 1
        self.order = '<' if self.little else '>'
        self.pos = _HEADER
        # byte ranges that must match between messages decoded as one block
        self.structural: list[tuple[int, int]] = [(0, _HEADER)]

    def align(self, size: int) -> None:
        self.pos += (-(self.pos - _HEADER)) % size

    def _unpack(self, fmt: str, size: int) -> int:
        self.align(size)
        if self.pos + size > len(self.data):
            raise ValueError('CDR message truncated')
        (value,) = struct.unpack_from(self.order + fmt, self.data, self.pos)
        self.pos += size
        return value

    def count(self) -> int:
        start = (self.pos + (-(self.pos - _HEADER)) % 4)
        value = self._unpack('I', 4)
        self.structural.append((start, start + 4))
        return value

    def string(self) -> str:
        n = self.count()
        if n == 0 or self.pos + n > len(self.data):
            raise ValueError('bad CDR string')
        text = self.data[self.pos:self.pos + n - 1].decode('utf-8')
        self.structural.append((self.pos, self.pos + n))
        self.pos += n
        return text

    def stamp(self) -> tuple[int, int]:
        sec = self._unpack('i', 4)
        nanosec = self._unpack('I', 4)
        return sec, nanosec

    def float64s(self, n: int) -> tuple[int, np.ndarray]:
        """Offset and values of ``n`` float64 (aligned only when ``n > 0``)."""
        if n == 0:
            return self.pos, np.empty(0)
        self.align(8)
        end = self.pos + 8 * n
        if end > len(self.data):
            raise ValueError('CDR message truncated')
        values = np.frombuffer(self.data, dtype=self.order + 'f8', count=n, offset=self.pos)
        offset, self.pos = self.pos, end
        return offset, values


def _stamps(matrix: np.ndarray, little: bool) -> np.ndarray:
    order = '<' if little else '>'
    raw = np.ascontiguousarray(matrix[:, _HEADER:_HEADER + 8])
    sec = raw[:, :4].copy().view(order + 'i4')[:, 0].astype(np.int64)
    nanosec = raw[:, 4:].copy().view(order + 'u4')[:, 0].astype(np.int64)
    return sec * 1_000_000_000 + nanosec


def _floats(matrix: np.ndarray, offset: int, n: int, little: bool) -> np.ndarray:
    block = np.ascontiguousarray(matrix[:, offset:offset + 8 * n])
    return block.view(('<' if little else '>') + 'f8').astype(np.float64, copy=False)


def _uniform_rows(blobs: Sequence[bytes], structural: list[tuple[int, int]],
                  index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Stack the messages that have the first message's length and structure (``index``:
    the structural byte positions, if already listed).

    Returns the ``[m, nbytes]`` matrix of those messages and their boolean mask over ``blobs``.
    """
    length = len(blobs[0])
    lengths = np.fromiter((len(b) for b in blobs), dtype=np.int64, count=len(blobs))
    same_len = lengths == length
    chosen = blobs if same_len.all() else [b for b, ok in zip(blobs, same_len) if ok]
    matrix = np.frombuffer(b''.join(chosen), dtype=np.uint8).reshape(len(chosen), length)
    if index is None:
        index = np.concatenate([np.arange(a, b) for a, b in structural])
    same_struct = (matrix[:, index] == matrix[0, index]).all(axis=1)
    if same_struct.all() and len(chosen) == len(blobs):
        return matrix, np.ones(len(blobs), dtype=bool)
    mask = np.zeros(len(blobs), dtype=bool)
    mask[np.flatnonzero(same_len)[same_struct]] = True
    return matrix[same_struct], mask


def _parse_joint_state(blob: bytes, strict: bool = True) -> dict:
    """One CDR JointState; ``strict``: an array must be empty or have one value per name
    (``ValueError`` otherwise; ``strict`` False leaves that check to the caller)."""
    cur = _Cursor(blob)
    sec, nanosec = cur.stamp()
    frame_id = cur.string()
    names = tuple(cur.string() for _ in range(cur.count()))
    fields = {}
    for field in ('position', 'velocity', 'effort'):
        n = cur.count()
        if strict and n not in (0, len(names)):
            raise ValueError(
                f'JointState {field} has {n} values for {len(names)} names')
        fields[field] = cur.float64s(n)
    return {'stamp_ns': sec * 1_000_000_000 + nanosec, 'frame_id': frame_id, 'names': names,
            'fields': fields, 'structural': cur.structural, 'little': cur.little}


def decode_joint_states(blobs: Sequence[bytes],
                        log_time_ns: np.ndarray | None = None) -> JointStateSeries:
    """CDR ``sensor_msgs/msg/JointState`` messages -> :class:`JointStateSeries`.

    All messages must carry the same joint names in the same order (``ValueError`` naming the
    first offending message otherwise). Arrays a message leaves empty become NaN rows.
    """
    n = len(blobs)
    if n == 0:
        empty = np.empty((0, 0))
        return JointStateSeries(np.empty(0, dtype=np.int64), (), empty, empty, empty, '',
                                None if log_time_ns is None else np.asarray(log_time_ns))
    first = _parse_joint_state(blobs[0])
    names, k = first['names'], len(first['names'])
    stamp_ns = np.empty(n, dtype=np.int64)
    out = {f: np.full((n, k), np.nan) for f in ('position', 'velocity', 'effort')}
    matrix, fast = _uniform_rows(blobs, first['structural'])
    if matrix.shape[0]:
        stamp_ns[fast] = _stamps(matrix, first['little'])
        for field, (offset, values) in first['fields'].items():
            if values.size:
                out[field][fast] = _floats(matrix, offset, k, first['little'])
    for i in np.flatnonzero(~fast):
        parsed = _parse_joint_state(blobs[i])
        if parsed['names'] != names:
            raise ValueError(
                f'JointState message {i} has names {list(parsed["names"])}, '
                f'expected {list(names)} as in message 0')
        stamp_ns[i] = parsed['stamp_ns']
        for field, (_, values) in parsed['fields'].items():
            if values.size:
                out[field][i] = values
    return JointStateSeries(
        stamp_ns=stamp_ns, names=names, position=out['position'], velocity=out['velocity'],
        effort=out['effort'], frame_id=first['frame_id'],
        log_time_ns=None if log_time_ns is None else np.asarray(log_time_ns, dtype=np.int64))


def _parse_wrench(blob: bytes) -> dict:
    cur = _Cursor(blob)
    sec, nanosec = cur.stamp()
    frame_id = cur.string()
    offset, values = cur.float64s(6)
    return {'stamp_ns': sec * 1_000_000_000 + nanosec, 'frame_id': frame_id,
            'offset': offset, 'values': values, 'structural': cur.structural,
            'little': cur.little}


def decode_wrenches(blobs: Sequence[bytes],
                    log_time_ns: np.ndarray | None = None) -> WrenchSeries:
    """CDR ``geometry_msgs/msg/WrenchStamped`` messages -> :class:`WrenchSeries`.

    All messages must share one ``header.frame_id`` (``ValueError`` otherwise).
    """
    n = len(blobs)
    log = None if log_time_ns is None else np.asarray(log_time_ns, dtype=np.int64)
    if n == 0:
        return WrenchSeries(np.empty(0, dtype=np.int64), '', np.empty((0, 3)),
                            np.empty((0, 3)), log)
    first = _parse_wrench(blobs[0])
    stamp_ns = np.empty(n, dtype=np.int64)
    values = np.empty((n, 6))
    matrix, fast = _uniform_rows(blobs, first['structural'])
    if matrix.shape[0]:
        stamp_ns[fast] = _stamps(matrix, first['little'])
        values[fast] = _floats(matrix, first['offset'], 6, first['little'])
    for i in np.flatnonzero(~fast):
        parsed = _parse_wrench(blobs[i])
        if parsed['frame_id'] != first['frame_id']:
            raise ValueError(
                f'WrenchStamped message {i} has frame_id {parsed["frame_id"]!r}, expected '
                f'{first["frame_id"]!r} as in message 0')
        stamp_ns[i] = parsed['stamp_ns']
        values[i] = parsed['values']
    return WrenchSeries(stamp_ns=stamp_ns, frame_id=first['frame_id'], force=values[:, :3],
                        torque=values[:, 3:], log_time_ns=log)


# ------------------------------------------------------------ live blocks, message by message
@dataclass(frozen=True)
class LayoutGroup:
    """Messages of one block that share a layout, their fields as carried (unchecked)."""

    index: np.ndarray                 # [m] positions of these messages in the block
    stamp_ns: np.ndarray              # [m] int64 header stamps
    frame_id: str
    names: tuple[str, ...]            # JointState: the names as carried; WrenchStamped: ()
    arrays: dict[str, np.ndarray]     # field -> [m, count] float64, count as carried


#: layouts seen: (kind, message length) -> [(structural byte positions, their bytes, parse)]
_LAYOUTS: dict[tuple[str, int], list[tuple[np.ndarray, bytes, dict]]] = {}


def block_arrays(blobs: Sequence[bytes], groups: Sequence[LayoutGroup],
                 unreadable: dict[int, str], width: int,
                 ) -> tuple[np.ndarray, np.ndarray, list[str | None], np.ndarray]:
    """The arrays of a ``CheckedBlock`` under construction for ``blobs`` grouped as
    ``group_*`` returned them: (stamps [n] ns, values [n, width] NaN, reasons [n] with the
    unreadable messages', stamped [n]: False where even the header stamp is unreadable)."""
    n = len(blobs)
    stamp_ns = np.zeros(n, dtype=np.int64)
    errors: list[str | None] = [None] * n
    stamped = np.ones(n, dtype=bool)
    for i, reason in unreadable.items():
        errors[i] = reason
        try:
            stamp_ns[i] = header_stamp_ns(blobs[i])
        except ValueError:
            stamped[i] = False
    for group in groups:
        stamp_ns[group.index] = group.stamp_ns
    return stamp_ns, np.full((n, width), np.nan), errors, stamped


def _layout_of(kind: str, blob: bytes, parse: Callable[[bytes], dict]) -> dict:
    """``parse(blob)``, or the parse of an earlier message with the same length and the same
    structural bytes (string lengths and characters, sequence counts, encapsulation): the
    parse reads exactly those bytes to find its way, so it would take the same path (a live
    node decodes a small batch of one layout every 10 ms; parsing its first message in
    Python cost more than decoding the batch)."""
    known = _LAYOUTS.setdefault((kind, len(blob)), [])
    if known:
        raw = np.frombuffer(blob, dtype=np.uint8)
        for index, expected, parsed in known:
            if raw[index].tobytes() == expected:
                return parsed
    parsed = parse(blob)
    index = np.concatenate([np.arange(a, b) for a, b in parsed['structural']])
    parsed['structural_index'] = index
    if len(known) >= 4:
        known.pop(0)
    known.append((index, np.frombuffer(blob, dtype=np.uint8)[index].tobytes(), parsed))
    return parsed


def _groups(kind: str, blobs: Sequence[bytes], parse: Callable[[bytes], dict],
            columns: Callable[[np.ndarray, dict], dict[str, np.ndarray]],
            ) -> tuple[list[LayoutGroup], dict[int, str]]:
    """Group ``blobs`` by layout: the messages laid out as the first readable one are
    decoded as one block (``columns``: field arrays from their byte matrix), any other
    message alone; unreadable ones -> {position: reason}."""
    groups: list[LayoutGroup] = []
    unreadable: dict[int, str] = {}
    first = None
    for i, blob in enumerate(blobs):
        try:
            first = (i, _layout_of(kind, blob, parse))
            break
        except (ValueError, UnicodeDecodeError, struct.error) as exc:
            unreadable[i] = f'unreadable CDR message: {exc}'
    if first is None:
        return groups, unreadable
    start, parsed = first
    rest = blobs[start:]
    matrix, fast = _uniform_rows(rest, parsed['structural'], parsed.get('structural_index'))
    every = fast.all()
    fast_index = np.arange(start, len(blobs)) if every else np.flatnonzero(fast) + start
    groups.append(LayoutGroup(fast_index, _stamps(matrix, parsed['little']),
                              parsed['frame_id'], parsed.get('names', ()),
                              columns(matrix, parsed)))
    for i in () if every else np.flatnonzero(~fast) + start:
        try:
            one = parse(blobs[i])
        except (ValueError, UnicodeDecodeError, struct.error) as exc:
            unreadable[int(i)] = f'unreadable CDR message: {exc}'
            continue
        groups.append(LayoutGroup(np.array([i]), np.array([one['stamp_ns']], dtype=np.int64),
                                  one['frame_id'], one.get('names', ()),
                                  {k: v[None, :] for k, v in one['values'].items()}))
    return groups, unreadable


def group_joint_states(blobs: Sequence[bytes]) -> tuple[list[LayoutGroup], dict[int, str]]:
    """CDR ``sensor_msgs/msg/JointState`` messages of a live block grouped by layout, fields
    as carried (arrays of any length: ``msg_adapters.joint_state.joint_states_from_blobs``
    checks them as one message is checked); unreadable messages -> {position: reason}."""
    def parse(blob: bytes) -> dict:
        one = _parse_joint_state(blob, strict=False)
        one['values'] = {f: values for f, (_, values) in one['fields'].items()}
        return one

    def columns(matrix: np.ndarray, first: dict) -> dict[str, np.ndarray]:
        return {f: _floats(matrix, offset, values.size, first['little']).reshape(
                    matrix.shape[0], values.size)
                for f, (offset, values) in first['fields'].items()}

    return _groups('JointState', blobs, parse, columns)


def group_wrenches(blobs: Sequence[bytes]) -> tuple[list[LayoutGroup], dict[int, str]]:
    """CDR ``geometry_msgs/msg/WrenchStamped`` messages of a live block grouped by layout
    (field ``'values'``: force xyz, torque xyz [m, 6]); unreadable -> {position: reason}."""
    def parse(blob: bytes) -> dict:
        one = _parse_wrench(blob)
        one['values'] = {'values': one['values']}
        return one

    def columns(matrix: np.ndarray, first: dict) -> dict[str, np.ndarray]:
        return {'values': _floats(matrix, first['offset'], 6, first['little'])}

    return _groups('WrenchStamped', blobs, parse, columns)


# ---------------------------------------------------------------------------- encoding
class _Writer:
    """Sequential little-endian CDR writer (padding zero)."""

    def __init__(self) -> None:
        self.b = bytearray(b'\x00\x01\x00\x00')

    def align(self, size: int) -> None:
        self.b += bytes((-(len(self.b) - _HEADER)) % size)

    def uint32(self, value: int) -> None:
        self.align(4)
        self.b += struct.pack('<I', value)

    def string(self, text: str) -> None:
        raw = text.encode('utf-8') + b'\x00'
        self.uint32(len(raw))
        self.b += raw

    def header(self, frame_id: str) -> None:
        self.uint32(0)           # sec, nanosec: written per message
        self.uint32(0)
        self.string(frame_id)

    def float64s(self, n: int) -> None:
        if n:
            self.align(8)
            self.b += bytes(8 * n)

    def done(self) -> bytes:
        return bytes(self.b)


def _fill(template: bytes, stamp_ns: np.ndarray,
          blocks: Sequence[tuple[int, np.ndarray]]) -> list[bytes]:
    """Rows of ``template`` with header stamps ``stamp_ns [n]`` and float64 ``blocks``
    (offset, values [n, k]) written in; one bytes object per row."""
    n = stamp_ns.shape[0]
    matrix = np.tile(np.frombuffer(template, dtype=np.uint8), (n, 1))
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    sec, nanosec = np.divmod(stamp_ns, 1_000_000_000)
    if n and (sec.min() < -2 ** 31 or sec.max() >= 2 ** 31):
        raise ValueError('header stamp outside the int32 seconds of builtin_interfaces/Time')
    matrix[:, _HEADER:_HEADER + 4] = sec.astype('<i4').view(np.uint8).reshape(n, 4)
    matrix[:, _HEADER + 4:_HEADER + 8] = nanosec.astype('<u4').view(np.uint8).reshape(n, 4)
    for offset, values in blocks:
        k = values.shape[1]
        matrix[:, offset:offset + 8 * k] = np.ascontiguousarray(
            values, dtype='<f8').view(np.uint8).reshape(n, 8 * k)
    row = matrix.shape[1]
    flat = matrix.tobytes()
    return [flat[i * row:(i + 1) * row] for i in range(n)]


@functools.lru_cache(maxsize=64)
def _joint_state_template(names: tuple[str, ...], frame_id: str) -> tuple[bytes, dict]:
    """A JointState of ``names`` with every array one value per name, zeros (CDR), and its
    fields' (offset, values)."""
    k = len(names)
    w = _Writer()
    w.header(frame_id)
    w.uint32(k)
    for name in names:
        w.string(name)
    for _ in range(3):
        w.uint32(k)
        w.float64s(k)
    template = w.done()
    return template, _parse_joint_state(template)['fields']


@functools.lru_cache(maxsize=64)
def _wrench_template(frame_id: str) -> tuple[bytes, int]:
    """A WrenchStamped of zeros (CDR) and the offset of its six values."""
    w = _Writer()
    w.header(frame_id)
    w.float64s(6)
    template = w.done()
    return template, _parse_wrench(template)['offset']


def encode_joint_states(stamp_ns: np.ndarray, names: Sequence[str], position: np.ndarray,
                        velocity: np.ndarray, effort: np.ndarray,
                        frame_id: str = '') -> list[bytes]:
    """``sensor_msgs/msg/JointState`` CDR messages (little endian, padding zero) from stamps
    [n] (ns) and [n, k] position, velocity, effort for the k ``names`` (already validated:
    ``msg_adapters.joint_state.joint_state_blobs`` is the checked entry point)."""
    k = len(names)
    template, fields = _joint_state_template(tuple(names), frame_id)
    return _fill(template, stamp_ns, [(fields[f][0], np.asarray(v, dtype=float).reshape(-1, k))
                                      for f, v in (('position', position),
                                                   ('velocity', velocity),
                                                   ('effort', effort)) if k])


def encode_wrenches(stamp_ns: np.ndarray, force: np.ndarray, torque: np.ndarray,
                    frame_id: str = '') -> list[bytes]:
    """``geometry_msgs/msg/WrenchStamped`` CDR messages (little endian, padding zero) from
    stamps [n] (ns), force and torque [n, 3] (already validated: see
    ``msg_adapters.wrench.wrench_blobs``)."""
    template, offset = _wrench_template(frame_id)
    values = np.hstack([np.asarray(force, dtype=float).reshape(-1, 3),
                        np.asarray(torque, dtype=float).reshape(-1, 3)])
    return _fill(template, stamp_ns, [(offset, values)])
