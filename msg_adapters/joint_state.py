"""``sensor_msgs/msg/JointState`` <-> (stamp, names, position, velocity, effort) arrays.

Empty arrays: we never publish one. rclpy (Fast-CDR typesupport) serialises a JointState
whose ``float64[]`` arrays are partly empty with up to 8 extra trailing bytes, and the
``rosbags`` reader, which our bags must satisfy, rejects such a message ("CDR message size
mismatch"; measured: every combination with an empty ``position``, ``velocity`` or
``effort`` fails except empty position followed by two filled arrays). So every message built
here fills **all three arrays with one value per name**; a quantity the topic does not carry
is filled with NaN (:data:`NOT_PROVIDED`), meaning "not provided". E.g. joint torques:
``effort`` = torques, ``position`` and ``velocity`` NaN. Each topic fills the same arrays in
every message, so its layout (and serialised size) is constant, which also lets
``msg_adapters.cdr_arrays`` decode a whole bag topic at once.

Readers map empty arrays of foreign messages to NaN as well, so the arrays returned here are
always ``[k]`` (single message) or ``[n, k]`` (batch). Provided data are validated: NaN/inf,
wrong lengths, missing or duplicate names raise ``ValueError`` with a precise message.
"""
from __future__ import annotations

import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import functools
from typing import Any

import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from .cdr_arrays import block_arrays, encode_joint_states, group_joint_states
from .series import CheckedBlock, JointStateSeries
from .stamps import stamps_to_ns, time_to_ns, times_from_ns, to_time
from .validation import as_matrix, as_vector, check_finite, check_names, reorder_index

NOT_PROVIDED = float('nan')
FIELDS = ('position', 'velocity', 'effort')


@dataclass(frozen=True)
class JointStateSample:
    """One JointState as arrays (NaN where the message carried no value)."""

    stamp_ns: int
    names: tuple[str, ...]
    position: np.ndarray  # [k]
    velocity: np.ndarray  # [k]
    effort: np.ndarray    # [k]
    frame_id: str = ''


def _doubles(values: np.ndarray) -> array.array:
    out = array.array('d')
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def to_joint_state(stamp: Any, names: Sequence[str], position: Any = None,
                   velocity: Any = None, effort: Any = None, *,
                   frame_id: str = '') -> JointState:
    """Build one JointState; fields left ``None`` are NaN-filled (see module docstring)."""
    names = check_names(names)
    k = len(names)
    msg = JointState(header=Header(stamp=to_time(stamp), frame_id=frame_id), name=list(names))
    given = {'position': position, 'velocity': velocity, 'effort': effort}
    if all(v is None for v in given.values()):
        raise ValueError('JointState needs at least one of position, velocity, effort')
    for field, values in given.items():
        vec = np.full(k, NOT_PROVIDED) if values is None else as_vector(values, k, field, names)
        setattr(msg, field, _doubles(vec))
    return msg


def _field(msg: JointState, field: str, k: int) -> np.ndarray:
    values = np.frombuffer(getattr(msg, field), dtype=np.float64) if len(
        getattr(msg, field)) else np.full(k, NOT_PROVIDED)
    if values.shape[0] != k:
        raise ValueError(f'JointState {field} has {values.shape[0]} values for {k} names')
    return values


def _layout(carried: Sequence[str], counts: dict[str, int],
            names: Sequence[str] | None) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, column index) of messages carrying joints ``carried`` and ``counts`` values
    per field: the checks of :func:`from_joint_state` that do not depend on the values."""
    got = check_names(carried, 'JointState name')
    for f in FIELDS:
        if counts[f] not in (0, len(got)):
            raise ValueError(f'JointState {f} has {counts[f]} values for {len(got)} names')
    if names is None:
        return got, np.arange(len(got))
    names = check_names(names)
    return names, reorder_index(got, names, 'JointState name')


def from_joint_state(msg: JointState, names: Sequence[str] | None = None,
                     require: Iterable[str] = (), allow_nan: bool = False) -> JointStateSample:
    """One JointState -> arrays, optionally reordered to ``names``.

    ``require`` lists fields that must be present and finite (e.g. ``('position',)`` for
    observed angles; with ``allow_nan`` NaN entries pass as missing values, inf never);
    other fields may hold NaN.
    """
    got, index = _layout(msg.name, {f: len(getattr(msg, f)) for f in FIELDS}, names)
    k = len(msg.name)
    fields = {f: _field(msg, f, k)[index] for f in FIELDS}
    for f in require:
        check_finite(fields[f], f'JointState {f}', got, allow_nan=allow_nan)
    return JointStateSample(stamp_ns=time_to_ns(msg.header.stamp), names=tuple(got),
                            frame_id=msg.header.frame_id,
                            **{f: np.array(v) for f, v in fields.items()})


@functools.lru_cache(maxsize=64)
def _checked_names(names: tuple[str, ...]) -> tuple[str, ...]:
    return check_names(names)


@functools.lru_cache(maxsize=64)
def _cached_layout(carried: tuple[str, ...], counts: tuple[int, ...],
                   names: tuple[str, ...]) -> tuple[np.ndarray | None, str | None]:
    """(column index, None) of :func:`_layout`, or (None, the reason it refuses)."""
    try:
        return _layout(carried, dict(zip(FIELDS, counts)), names)[1], None
    except ValueError as exc:
        return None, str(exc)


def joint_states_from_blobs(blobs: Sequence[bytes], names: Sequence[str],
                            fields: Sequence[str], require: Iterable[str] = (),
                            allow_nan: bool = False) -> CheckedBlock:
    """CDR JointState messages (a live node's raw batch) -> :class:`CheckedBlock` of
    ``fields`` (e.g. ``('effort', 'position')``: ``[n, 2k]``) for the joints ``names``.

    Each message is checked exactly as :func:`from_joint_state` checks one (same reasons);
    the messages that share a layout are decoded and checked as one array
    (``msg_adapters.cdr_arrays.group_joint_states``), at ~1 us per message instead of the
    ~60 us of rclpy's deserialisation plus :func:`from_joint_state`.
    """
    names = _checked_names(tuple(names))
    require = tuple(require)
    k = len(names)
    groups, unreadable = group_joint_states(blobs)
    stamp_ns, values, errors, stamped = block_arrays(blobs, groups, unreadable,
                                                     k * len(fields))
    for group in groups:
        m = group.index.size
        index, problem = _cached_layout(
            group.names, tuple(group.arrays[f].shape[1] for f in FIELDS), names)
        if problem is not None:
            for i in group.index:
                errors[i] = problem
            continue
        carried = {f: (group.arrays[f][:, index] if group.arrays[f].shape[1]
                       else np.full((m, k), NOT_PROVIDED)) for f in set(fields) | set(require)}
        bad = np.zeros(m, dtype=bool)
        for f in require:          # a row's reason: its first required field that fails
            a = carried[f]
            new = (np.isinf(a) if allow_nan else ~np.isfinite(a)).any(axis=1) & ~bad
            if new.any():
                for r in np.flatnonzero(new):
                    try:
                        check_finite(a[r], f'JointState {f}', names, allow_nan=allow_nan)
                    except ValueError as exc:
                        errors[group.index[r]] = str(exc)
                bad |= new
        keep = group.index[~bad] if bad.any() else group.index
        rows = ~bad if bad.any() else slice(None)
        values[keep] = np.hstack([carried[f][rows] for f in fields])
    return CheckedBlock(stamp_ns, values, tuple(errors), stamped)


def _checked_blocks(stamps: Any, names: Sequence[str], position: Any, velocity: Any,
                    effort: Any, allow_nan: bool,
                    ) -> tuple[tuple[str, ...], np.ndarray, dict[str, np.ndarray]]:
    """(names, stamps [n] ns, {field: [n, k]}) checked; a field not given is NOT_PROVIDED."""
    names = check_names(names)
    stamp_ns = stamps_to_ns(stamps)
    n, k = stamp_ns.shape[0], len(names)
    given = {'position': position, 'velocity': velocity, 'effort': effort}
    if all(v is None for v in given.values()):
        raise ValueError('JointState needs at least one of position, velocity, effort')
    blocks = {f: (np.full((n, k), NOT_PROVIDED) if v is None
                  else as_matrix(v, n, k, f, names, allow_nan=allow_nan))
              for f, v in given.items()}
    return names, stamp_ns, blocks


def joint_states_from_arrays(stamps: Any, names: Sequence[str], position: Any = None,
                             velocity: Any = None, effort: Any = None, *,
                             frame_id: str = '', allow_nan: bool = False) -> list[JointState]:
    """``n`` stamps and ``[n, k]`` arrays -> ``n`` JointState messages (validated at once).

    ``allow_nan``: provided values may be NaN (a measurement that is missing, e.g. an
    occluded segment in a mocap stream); inf is refused all the same."""
    names, stamp_ns, blocks = _checked_blocks(stamps, names, position, velocity, effort,
                                              allow_nan)
    raw = {f: np.ascontiguousarray(b).tobytes() for f, b in blocks.items()}
    row = 8 * len(names)
    name_list = list(names)
    out = []
    for i, stamp in enumerate(times_from_ns(stamp_ns)):
        msg = JointState(header=Header(stamp=stamp, frame_id=frame_id), name=name_list)
        for f in FIELDS:
            values = array.array('d')
            values.frombytes(raw[f][i * row:(i + 1) * row])
            setattr(msg, f, values)
        out.append(msg)
    return out


def joint_state_blobs(stamps: Any, names: Sequence[str], position: Any = None,
                      velocity: Any = None, effort: Any = None, *, frame_id: str = '',
                      allow_nan: bool = False) -> list[bytes]:
    """The messages of :func:`joint_states_from_arrays` (same arguments, same checks),
    serialised (CDR, padding zero) without building message objects: what a node publishes
    at high rates (``Publisher.publish`` takes bytes)."""
    names, stamp_ns, blocks = _checked_blocks(stamps, names, position, velocity, effort,
                                              allow_nan)
    return encode_joint_states(stamp_ns, names, blocks['position'], blocks['velocity'],
                               blocks['effort'], frame_id)


def joint_states_to_arrays(msgs: Sequence[JointState], names: Sequence[str] | None = None,
                           require: Iterable[str] = ()) -> JointStateSeries:
    """``n`` JointState messages -> :class:`~msg_adapters.series.JointStateSeries`.

    All messages must carry the same names (in any order when ``names`` is given, else in
    the first message's order); empty arrays become NaN; ``require`` as in
    :func:`from_joint_state`.
    """
    n = len(msgs)
    if n == 0:
        k = 0 if names is None else len(names)
        empty = np.empty((0, k))
        return JointStateSeries(np.empty(0, dtype=np.int64), tuple(names or ()), empty,
                                empty.copy(), empty.copy())
    first = tuple(msgs[0].name)
    target = check_names(names if names is not None else first)
    k = len(target)
    stamp_ns = np.fromiter((time_to_ns(m.header.stamp) for m in msgs), dtype=np.int64, count=n)
    same = all(tuple(m.name) == first for m in msgs)
    if not same and names is None:
        i = next(i for i, m in enumerate(msgs) if tuple(m.name) != first)
        raise ValueError(f'JointState message {i} has names {list(msgs[i].name)}, expected '
                         f'{list(first)} as in message 0')
    out = {}
    if same:
        index = reorder_index(first, target, 'JointState name')
        kk = len(first)
        for f in FIELDS:
            lengths = np.fromiter((len(getattr(m, f)) for m in msgs), dtype=np.int64, count=n)
            if (lengths == kk).all():
                block = np.frombuffer(b''.join(getattr(m, f).tobytes() for m in msgs),
                                      dtype=np.float64).reshape(n, kk)
            else:
                block = np.stack([_field(m, f, kk) for m in msgs])
            out[f] = block[:, index]
    else:
        samples = [from_joint_state(m, target) for m in msgs]
        for f in FIELDS:
            out[f] = np.stack([getattr(s, f) for s in samples])
    for f in require:
        check_finite(out[f], f'JointState {f}', target)
    return JointStateSeries(stamp_ns=stamp_ns, names=target, frame_id=msgs[0].header.frame_id,
                            **out)


def series_to_joint_states(series: JointStateSeries) -> list[JointState]:
    """A series back to messages: an all-NaN field is "not provided", others are validated."""
    fields = {f: (None if np.isnan(getattr(series, f)).all() else getattr(series, f))
              for f in FIELDS}
    return joint_states_from_arrays(series.stamp_ns, series.names, frame_id=series.frame_id,
                                    **fields)
