"""``diagnostic_msgs/msg/DiagnosticArray`` from small status records (for ``/nmt/status``).

A :class:`StatusRecord` is one DiagnosticStatus: level (OK/WARN/ERROR/STALE or 0..3), name,
message, hardware id and key/values. Values are turned into strings: bools as
``true``/``false``, floats with ``repr`` (shortest round-trip form), others with ``str``.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from std_msgs.msg import Header

from .stamps import time_to_ns, to_time

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {'OK': OK, 'WARN': WARN, 'ERROR': ERROR, 'STALE': STALE}


@dataclass(frozen=True)
class StatusRecord:
    """One DiagnosticStatus entry."""

    level: int | str
    name: str
    message: str = ''
    values: Mapping[str, Any] = field(default_factory=dict)
    hardware_id: str = ''


def level_value(level: int | str) -> int:
    """``'WARN'`` / ``1`` -> 1; ValueError for anything but OK/WARN/ERROR/STALE."""
    if isinstance(level, str):
        try:
            return LEVEL_NAMES[level.upper()]
        except KeyError:
            raise ValueError(f'unknown diagnostic level {level!r} '
                             f'(expected one of {list(LEVEL_NAMES)})') from None
    value = int(level)
    if value not in LEVEL_NAMES.values():
        raise ValueError(f'diagnostic level must be 0..3, got {level!r}')
    return value


def format_value(value: Any) -> str:
    """A key/value value as text."""
    if isinstance(value, bool | np.bool_):
        return 'true' if value else 'false'
    if isinstance(value, float | np.floating):
        v = float(value)
        return repr(v) if math.isfinite(v) else str(v)
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def to_status(record: StatusRecord | tuple) -> DiagnosticStatus:
    """One record (or a tuple ``(level, name, message, values, hardware_id)``, trailing
    items optional) -> DiagnosticStatus."""
    if not isinstance(record, StatusRecord):
        record = StatusRecord(*record)
    return DiagnosticStatus(
        level=bytes([level_value(record.level)]), name=str(record.name),
        message=str(record.message), hardware_id=str(record.hardware_id),
        values=[KeyValue(key=str(k), value=format_value(v)) for k, v in record.values.items()])


def to_diagnostic_array(stamp: Any,
                        records: Iterable[StatusRecord | tuple]) -> DiagnosticArray:
    """Records -> DiagnosticArray stamped ``stamp`` (int ns or float s)."""
    return DiagnosticArray(header=Header(stamp=to_time(stamp)),
                           status=[to_status(r) for r in records])


def from_diagnostic_array(msg: DiagnosticArray) -> tuple[int, list[StatusRecord]]:
    """DiagnosticArray -> (stamp ns, records with string values)."""
    records = []
    for s in msg.status:
        level = s.level[0] if isinstance(s.level, bytes | bytearray) else int(s.level)
        records.append(StatusRecord(level=level, name=s.name, message=s.message,
                                    values={kv.key: kv.value for kv in s.values},
                                    hardware_id=s.hardware_id))
    return time_to_ns(msg.header.stamp), records
