"""Stamps: integer nanoseconds or float seconds <-> ``builtin_interfaces/msg/Time``.

Convention used by every adapter: a Python/numpy **integer** stamp is nanoseconds, a
**float** stamp is seconds. Prefer integer nanoseconds for wall-clock (epoch) times: a float
holds an epoch time only to about 0.2 us. ``Time`` is ``{sec: int32, nanosec: uint32}`` with
``nanosec`` in [0, 1e9); negative times are floored (-1.7 s -> sec -2, nanosec 3e8).
"""
from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Time
import numpy as np

NS_PER_S = 1_000_000_000
_INT32 = (-(1 << 31), (1 << 31) - 1)


def to_ns(stamp: Any) -> int:
    """One stamp (int ns, float s, or a ``Time``-like object with sec/nanosec) -> int ns."""
    if hasattr(stamp, 'sec') and hasattr(stamp, 'nanosec'):
        return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)
    if isinstance(stamp, bool):
        raise ValueError(f'stamp must be int ns or float s, got {stamp!r}')
    if isinstance(stamp, int | np.integer):
        return int(stamp)
    if isinstance(stamp, float | np.floating):
        if not np.isfinite(stamp):
            raise ValueError(f'stamp is not finite: {stamp!r}')
        return int(round(float(stamp) * NS_PER_S))
    raise ValueError(f'stamp must be int ns, float s or builtin_interfaces/Time, got '
                     f'{type(stamp).__name__}')


def to_time(stamp: Any) -> Time:
    """A stamp (int ns or float s) -> ``builtin_interfaces/msg/Time``."""
    sec, nanosec = divmod(to_ns(stamp), NS_PER_S)
    if not _INT32[0] <= sec <= _INT32[1]:
        raise ValueError(f'stamp {stamp!r} is outside the int32 seconds range of '
                         'builtin_interfaces/Time')
    return Time(sec=sec, nanosec=nanosec)


def time_to_ns(t: Any) -> int:
    """``builtin_interfaces/msg/Time`` -> int ns."""
    return int(t.sec) * NS_PER_S + int(t.nanosec)


def stamps_to_ns(stamps: Any) -> np.ndarray:
    """An array of stamps -> int64 ns ``[n]`` (integer dtype: ns; float dtype: seconds)."""
    arr = np.asarray(stamps)
    if arr.ndim != 1:
        raise ValueError(f'stamps must be a 1-D array, got shape {arr.shape}')
    if arr.dtype.kind in 'iu':
        return arr.astype(np.int64, copy=False)
    if arr.dtype.kind == 'f':
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f'stamps: non-finite value {arr[i]} at index {i}')
        return np.rint(arr * NS_PER_S).astype(np.int64)
    raise ValueError(f'stamps must be integer ns or float seconds, got dtype {arr.dtype}')


def split_ns(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """int64 ns ``[n]`` -> (sec ``[n]``, nanosec ``[n]``) as Time wants them (floored)."""
    sec, nanosec = np.divmod(np.asarray(stamp_ns, dtype=np.int64), NS_PER_S)
    if sec.size and (sec.min() < _INT32[0] or sec.max() > _INT32[1]):
        raise ValueError('stamps outside the int32 seconds range of builtin_interfaces/Time')
    return sec, nanosec


def times_from_ns(stamp_ns: np.ndarray) -> list[Time]:
    """int64 ns ``[n]`` -> list of ``Time`` messages."""
    sec, nanosec = split_ns(stamp_ns)
    return [Time(sec=s, nanosec=n) for s, n in zip(sec.tolist(), nanosec.tolist())]
