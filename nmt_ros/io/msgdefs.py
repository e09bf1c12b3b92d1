"""ROS 2 message definitions from the installed ``.msg`` files (no rclpy needed).

A recorder must store each topic's full message definition in the MCAP schema record
(encoding ``ros2msg``). rosbag2 builds it from the ``share/<pkg>/msg/<Type>.msg`` files found
through the ament index; the ROS wheels install these files under ``<venv>/share``, so
``AMENT_PREFIX_PATH=sys.prefix`` makes them findable (``sys.prefix`` is also searched as a
fallback).

The full text follows ``rosbag2/docs/message_definition_encoding.md``: the top-level ``.msg``
text as installed (comments kept), then for every dependency, depth first, each once, and in
sorted order per level: a newline, a line of 80 ``=``, ``MSG: <pkg>/<Type>`` and that
definition. The REP-2011 type hash (``RIHS01_...``) is read from the ``.json`` type
description installed next to each ``.msg``.
"""
from __future__ import annotations

import functools
import importlib
import json
import os
from pathlib import Path
import sys

PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring',
})
SEPARATOR = '=' * 80


def normalize_type_name(type_name: str) -> str:
    """``'pkg/Type'`` or ``'pkg/msg/Type'`` -> ``'pkg/msg/Type'``."""
    parts = type_name.strip().split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and parts[1] == 'msg':
        return '/'.join(parts)
    raise ValueError(f'not a message type name: {type_name!r} (expected pkg/msg/Type)')


def message_type_name(msg_or_class: object) -> str:
    """The ``pkg/msg/Type`` name of an rclpy message instance or class."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    package = cls.__module__.split('.')[0]
    if not hasattr(cls, 'get_fields_and_field_types'):
        raise TypeError(f'{cls.__module__}.{cls.__name__} is not a ROS message class')
    return f'{package}/msg/{cls.__name__}'


@functools.cache
def get_message_class(type_name: str) -> type:
    """Import the Python class of ``pkg/msg/Type`` (the role of rosidl_runtime_py.get_message)."""
    package, _, name = normalize_type_name(type_name).split('/')
    try:
        module = importlib.import_module(f'{package}.msg')
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f'message type {type_name!r} is not installed: {exc}') from None


def share_prefixes() -> list[Path]:
    """Install prefixes searched for ``share/<pkg>/msg``: AMENT_PREFIX_PATH, then sys.prefix.

    sys.prefix is searched too because the ROS wheels install their ``.msg`` files under the
    venv's ``share/``, which a process started outside ``make``/``nmt`` (no
    ``AMENT_PREFIX_PATH``) must still find; the environment variable comes first.
    """
    prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    if Path(sys.prefix) not in prefixes:
        prefixes.append(Path(sys.prefix))
    return prefixes


def _find_share_file(type_name: str, suffix: str) -> Path | None:
    package, _, name = normalize_type_name(type_name).split('/')
    for prefix in share_prefixes():
        candidate = prefix / 'share' / package / 'msg' / f'{name}{suffix}'
        if candidate.is_file():
            return candidate
    return None


@functools.cache
def msg_text(type_name: str) -> str:
    """The installed ``.msg`` text of one type, exactly as in the file."""
    path = _find_share_file(type_name, '.msg')
    if path is None:
        searched = ', '.join(str(p) for p in share_prefixes())
        raise FileNotFoundError(
            f'no .msg file for {type_name!r} under share/ of: {searched} '
            '(set AMENT_PREFIX_PATH to the environment holding the ROS message wheels)')
    return path.read_text(encoding='utf-8')


def field_dependencies(text: str, package: str) -> list[str]:
    """Non-primitive field types of a ``.msg`` text as ``pkg/Type``, sorted, unique.

    Comments, constants (``type NAME=value``) of primitive type and array/bound suffixes are
    handled; a type without a package is taken from ``package`` (same-package reference).
    """
    deps = set()
    for raw_line in text.splitlines():
        line = raw_line.split('#', 1)[0].strip()
        if not line:
            continue
        field_type = line.split()[0]
        base = field_type.split('[', 1)[0].split('<', 1)[0]
        if base in PRIMITIVE_TYPES:
            continue
        if '/' not in base:
            base = f'{package}/{base}'
        elif base.count('/') == 2:  # pkg/msg/Type written out in full
            pkg, _, name = base.split('/')
            base = f'{pkg}/{name}'
        deps.add(base)
    return sorted(deps)


@functools.cache
def full_definition(type_name: str) -> str:
    """The concatenated ``ros2msg`` definition of ``type_name``, as rosbag2 writes it."""
    root = normalize_type_name(type_name)
    seen: set[str] = set()

    def expand(name: str) -> str:
        package = name.split('/')[0]
        text = msg_text(name)
        parts = [text]
        for dep in field_dependencies(text, package):
            if dep in seen:
                continue
            seen.add(dep)
            parts.append(f'\n{SEPARATOR}\nMSG: {dep}\n')
            parts.append(expand(dep))
        return ''.join(parts)

    return expand(root)


@functools.cache
def type_hash(type_name: str) -> str:
    """REP-2011 type hash ``RIHS01_<hex>`` of ``type_name``, or ``''`` when the installed
    message package has no type description.

    The ``.json`` type descriptions exist from ROS 2 Iron on; a package without them has no
    hash, and rosbag2 then writes an empty ``topic_type_hash`` too. A description that exists
    but cannot be read or does not describe ``type_name`` is an error (ValueError).
    """
    name = normalize_type_name(type_name)
    path = _find_share_file(name, '.json')
    if path is None:
        return ''
    try:
        hashes = json.loads(path.read_text(encoding='utf-8'))['type_hashes']
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f'unreadable type description {path}: {exc!r}') from None
    for entry in hashes:
        if entry.get('type_name') == name and entry.get('hash_string'):
            return str(entry['hash_string'])
    raise ValueError(f'type description {path} has no hash for {name}')
