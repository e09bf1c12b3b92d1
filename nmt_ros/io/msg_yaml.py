"""ROS message -> text exactly as ``ros2 topic echo`` prints it (YAML or CSV).

``rosidl_runtime_py`` (which ``ros2 topic echo`` uses) is not installable from PyPI here, so
this module reproduces its documented behaviour:

- fields in ``.msg`` order (``get_fields_and_field_types()`` with ``SLOT_TYPES``);
- ``bytes`` become a string of the byte values as characters, numpy scalars plain Python
  numbers, ``array.array``/numpy/list/tuple a list;
- strings and sequences longer than ``truncate_length`` are cut, strings get a ``'...'``
  suffix and sequences a final ``'...'`` element;
- ``no_arr`` replaces sequences with ``<sequence type: T, length: N>`` (``T`` the IDL type
  name, e.g. ``double`` for ``float64``), ``no_str`` strings with ``<string length: <N>>``;
- YAML via ``yaml.dump(..., allow_unicode=True, width=sys.maxsize)`` with an ordered-mapping
  representer; the echo output appends ``---``.

No rclpy node code here; message classes and ``rosidl_parser`` types are only inspected.
"""
from __future__ import annotations

import array
from collections import OrderedDict
import sys
from typing import Any

import numpy as np
import yaml

_SEQUENCE_TYPES = (list, tuple, array.array, np.ndarray)


class _EchoDumper(yaml.Dumper):
    """The default PyYAML dumper plus an OrderedDict representer that keeps field order."""


def _represent_ordered(dumper: yaml.Dumper, data: OrderedDict) -> yaml.MappingNode:
    pairs = [(dumper.represent_data(k), dumper.represent_data(v)) for k, v in data.items()]
    return yaml.MappingNode('tag:yaml.org,2002:map', pairs)


_EchoDumper.add_representer(OrderedDict, _represent_ordered)


def _type_name(value_type: Any) -> str:
    kind = type(value_type).__name__
    if kind == 'BasicType':
        return value_type.typename
    if kind in ('UnboundedString', 'BoundedString'):
        return 'string'
    if kind in ('UnboundedWString', 'BoundedWString'):
        return 'wstring'
    if kind == 'NamedType':
        return value_type.name
    if kind == 'NamespacedType':
        return '/'.join(value_type.namespaced_name())
    return 'unknown'


def _abbreviate(value: Any, field_type: Any) -> str:
    kind = type(field_type).__name__
    name = _type_name(getattr(field_type, 'value_type', None))
    if kind == 'Array':
        return f'<array type: {name}[{field_type.size}]>'
    if kind == 'BoundedSequence':
        return f'<sequence type: {name}[{field_type.maximum_size}], length: {len(value)}>'
    if kind == 'UnboundedSequence':
        return f'<sequence type: {name}, length: {len(value)}>'
    return 'unknown'


def _convert(value: Any, field_type: Any = None, truncate_length: int | None = None,
             no_arr: bool = False, no_str: bool = False) -> Any:
    opts = {'truncate_length': truncate_length, 'no_arr': no_arr, 'no_str': no_str}
    if isinstance(value, bytes):
        cut = truncate_length is not None and len(value) > truncate_length
        text = ''.join(chr(c) for c in (value[:truncate_length] if cut else value))
        return text + '...' if cut else text
    if isinstance(value, str):
        if no_str:
            return f'<string length: <{len(value)}>>'
        if truncate_length is not None and len(value) > truncate_length:
            return value[:truncate_length] + '...'
        return value
    if isinstance(value, _SEQUENCE_TYPES):
        container = tuple if isinstance(value, tuple) else list
        if no_arr and field_type is not None:
            return _abbreviate(value, field_type)
        if truncate_length is not None and len(value) > truncate_length:
            items = [_convert(v, **opts) for v in value[:truncate_length]]
            return container(items + ['...'])
        return container(_convert(v, **opts) for v in value)
    if isinstance(value, dict):
        out = OrderedDict() if isinstance(value, OrderedDict) else {}
        for k, v in value.items():
            out[_convert(k)] = _convert(v, **opts)
        return out
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bool | int | float):
        return value
    return message_to_ordereddict(value, **opts)


def message_to_ordereddict(msg: Any, *, truncate_length: int | None = None,
                           no_arr: bool = False, no_str: bool = False) -> OrderedDict:
    """A message as an OrderedDict of plain values, in ``.msg`` field order."""
    out = OrderedDict()
    for name, field_type in zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES):
        out[name] = _convert(getattr(msg, name, None), field_type, truncate_length, no_arr,
                             no_str)
    return out


def message_to_yaml(msg: Any, *, truncate_length: int | None = None, no_arr: bool = False,
                    no_str: bool = False, flow_style: bool = False) -> str:
    """A message as the YAML text ``ros2 topic echo`` prints (without the ``---`` line)."""
    return yaml.dump(
        message_to_ordereddict(msg, truncate_length=truncate_length, no_arr=no_arr,
                               no_str=no_str),
        Dumper=_EchoDumper, allow_unicode=True, width=sys.maxsize,
        default_flow_style=flow_style)


def _csv_value(value: Any, field_type: Any, truncate_length: int | None, no_arr: bool,
               no_str: bool) -> str:
    if isinstance(value, _SEQUENCE_TYPES):
        if no_arr and field_type is not None:
            return _abbreviate(value, field_type)
        parts = []
        for i, v in enumerate(value):
            if truncate_length is not None and i >= truncate_length:
                parts.append('...')
                break
            parts.append(_csv_value(v, None, truncate_length, no_arr, no_str))
        return ','.join(parts)
    if isinstance(value, bool | bytes | float | int | str | np.number):
        if no_str and isinstance(value, str):
            value = f'<string length: <{len(value)}>>'
        elif isinstance(value, bytes | str) and truncate_length is not None and (
                len(value) > truncate_length):
            value = value[:truncate_length] + (b'...' if isinstance(value, bytes) else '...')
        return str(value)
    return message_to_csv(value, truncate_length=truncate_length, no_arr=no_arr, no_str=no_str)


def message_to_csv(msg: Any, *, truncate_length: int | None = None, no_arr: bool = False,
                   no_str: bool = False) -> str:
    """A message as one line of comma-separated leaf values (``ros2 topic echo --csv``)."""
    return ','.join(
        _csv_value(getattr(msg, name), field_type, truncate_length, no_arr, no_str)
        for name, field_type in zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES))


def format_echo(msg: Any, *, csv: bool = False, truncate_length: int | None = 128,
                no_arr: bool = False, no_str: bool = False, flow_style: bool = False) -> str:
    """The full text ``ros2 topic echo`` writes for one message (YAML + ``---``, or CSV)."""
    opts = {'truncate_length': truncate_length, 'no_arr': no_arr, 'no_str': no_str}
    if csv:
        return message_to_csv(msg, **opts) + '\n'
    return message_to_yaml(msg, flow_style=flow_style, **opts) + '---\n'
