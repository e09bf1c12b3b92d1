"""Planar ground wrench ``s = [Fx, Fy, Mz]`` <-> ``geometry_msgs/msg/WrenchStamped``.

The jumper lives in the sagittal plane: the force plate and the tracked model's contact
springs give three numbers, ``s[3]`` = fore-aft force ``force.x`` [N], vertical force
``force.y`` [N] and the moment ``torque.z`` [N m] about the point named by
``header.frame_id`` (``'foot_com'`` for our topics). The out-of-plane components are written
as zero and ignored when reading. Arrays are ``[n, 3]`` for batches, ``[3]`` for one message;
values are validated (finite, right shape) with the ``ValueError`` messages of
``msg_adapters.validation``.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np

from .cdr_arrays import block_arrays, group_wrenches
from .series import CheckedBlock
from .validation import as_matrix, as_vector, check_finite
from .wrench import from_wrench_stamped, wrench_blobs, wrenches_from_arrays, wrenches_to_arrays

PLANAR = ('force.x', 'force.y', 'torque.z')
_CHECKED = 'WrenchStamped (force.x, force.y, torque.z)'   # what a refused value is called


def planar_to_xyz(s: Any) -> tuple[np.ndarray, np.ndarray]:
    """``s[n, 3]`` -> (force ``[n, 3]``, torque ``[n, 3]``) with zero out-of-plane parts."""
    s = np.asarray(s, dtype=np.float64)
    n = s.shape[0]
    force = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    force[:, :2] = s[:, :2]
    torque[:, 2] = s[:, 2]
    return force, torque


def to_planar_wrench(stamp: Any, frame_id: str, s: Any) -> WrenchStamped:
    """One ``s[3]`` -> WrenchStamped (stamp: int ns or float s)."""
    vec = as_vector(s, 3, 'planar wrench', PLANAR)
    return planar_wrenches_from_arrays(np.array([stamp]), frame_id, vec[None])[0]


def planar_wrenches_from_arrays(stamps: Any, frame_id: str, s: Any) -> list[WrenchStamped]:
    """``n`` stamps and ``s[n, 3]`` -> ``n`` WrenchStamped messages."""
    stamps = np.asarray(stamps)
    s = as_matrix(s, stamps.shape[0], 3, 'planar wrench', PLANAR)
    force, torque = planar_to_xyz(s)
    return wrenches_from_arrays(stamps, frame_id, force, torque)


def planar_wrench_blobs(stamps: Any, frame_id: str, s: Any) -> list[bytes]:
    """The messages of :func:`planar_wrenches_from_arrays`, serialised (``wrench_blobs``)."""
    stamps = np.asarray(stamps)
    s = as_matrix(s, stamps.shape[0], 3, 'planar wrench', PLANAR)
    force, torque = planar_to_xyz(s)
    return wrench_blobs(stamps, frame_id, force, torque)


def from_planar_wrench(msg: WrenchStamped, frame_id: str | None = None,
                       allow_nan: bool = False) -> tuple[int, np.ndarray]:
    """One WrenchStamped -> (stamp ns, ``s[3]``); ``frame_id`` given: must match.

    Only the in-plane components are read and checked (NaN/inf raise ``ValueError``; with
    ``allow_nan`` a NaN passes as a missing value, inf never).
    """
    sample = from_wrench_stamped(msg, frame_id, check=False)
    s = np.array([sample.force[0], sample.force[1], sample.torque[2]])
    check_finite(s, _CHECKED, PLANAR, allow_nan=allow_nan)
    return sample.stamp_ns, s


def planar_wrenches_from_blobs(blobs: Sequence[bytes], frame_id: str | None = None,
                               allow_nan: bool = False) -> CheckedBlock:
    """CDR WrenchStamped messages (a live node's raw batch) -> :class:`CheckedBlock` of
    ``s[n, 3]``, each message checked exactly as :func:`from_planar_wrench` checks one (same
    reasons), those sharing a layout as one array (``cdr_arrays.group_wrenches``)."""
    groups, unreadable = group_wrenches(blobs)
    stamp_ns, values, errors, stamped = block_arrays(blobs, groups, unreadable, 3)
    for group in groups:
        if frame_id is not None and group.frame_id != frame_id:
            for i in group.index:
                errors[i] = (f'WrenchStamped frame_id is {group.frame_id!r}, '
                             f'expected {frame_id!r}')
            continue
        s = group.arrays['values'][:, [0, 1, 5]]
        bad = (np.isinf(s) if allow_nan else ~np.isfinite(s)).any(axis=1)
        for r in np.flatnonzero(bad):
            try:
                check_finite(s[r], _CHECKED, PLANAR, allow_nan=allow_nan)
            except ValueError as exc:
                errors[group.index[r]] = str(exc)
        values[group.index[~bad]] = s[~bad]
    return CheckedBlock(stamp_ns, values, tuple(errors), stamped)


def planar_from_wrenches(msgs: Sequence[WrenchStamped], frame_id: str | None = None,
                         ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` messages -> (stamps ns ``[n]``, ``s[n, 3]``), vectorised."""
    series = wrenches_to_arrays(msgs, frame_id, check=False)
    s = np.column_stack([series.force[:, 0], series.force[:, 1], series.torque[:, 2]])
    check_finite(s, _CHECKED, PLANAR)
    return series.stamp_ns, s
