"""The import layers hold (README "Layout"), read from the source with ``ast`` (nothing runs).

Lowest first: model (and osim beside it), records and topics -> tracking -> msg_adapters ->
io -> study -> view -> nodes -> cli. A module may import its own layer and the layers below,
never one above (``io`` builds on ``msg_adapters``, never the reverse). ``model`` imports
nothing of ours but itself; ``topics`` nothing at all. No rclpy, ROS message or interface
package in model, osim, records, topics, tracking, study or view: they run without ROS.
Every ``import`` statement counts, at module level or inside a function. ``bench/`` and
``test/`` may import anything.
"""
from __future__ import annotations

import ast
from pathlib import Path
import re

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Layer of each package of ours (lower may be imported by higher).
LAYER = {
    'nmt_ros.model': 0, 'nmt_ros.osim': 0, 'nmt_ros.records': 0, 'nmt_ros.topics': 0,
    'nmt_ros': 0,   # the package itself (its __init__)
    'nmt_ros.tracking': 1,
    'msg_adapters': 2,
    'nmt_ros.io': 3,
    'nmt_ros.study': 4,
    'nmt_ros.view': 5,   # the live view's server (foxglove-sdk); the viewer node feeds it
    'nmt_ros.nodes': 6,
    'nmt_ros.cli': 7,
}
#: Within the bottom layer, what each package may import of ours.
BOTTOM = {
    'nmt_ros.model': {'nmt_ros.model'},
    'nmt_ros.osim': {'nmt_ros.osim', 'nmt_ros.model'},
    'nmt_ros.records': {'nmt_ros.model'},
    'nmt_ros.topics': set(),
    'nmt_ros': set(),
}
#: Packages that must run without ROS.
ROS_FREE = ('nmt_ros.model', 'nmt_ros.osim', 'nmt_ros.records', 'nmt_ros.topics',
            'nmt_ros.tracking', 'nmt_ros.study', 'nmt_ros.view', 'nmt_ros')
ROS_MODULE = re.compile(r'^(rclpy|rcl_interfaces|rosidl\w*|builtin_interfaces|\w+_msgs|'
                        r'\w+_interfaces)(\.|$)')


def package_of(module: str) -> str | None:
    """Our package (a key of LAYER) that ``module`` belongs to, or None if not ours."""
    best = None
    for pkg in LAYER:
        if (module == pkg or module.startswith(pkg + '.')) and (best is None
                                                                or len(pkg) > len(best)):
            best = pkg
    return best


def module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def imported_modules(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``source`` (relative ones resolved;
    ``from pkg import name`` counts as ``pkg.name``, which may be a submodule)."""
    out = []
    base = module.split('.') if is_package else module.split('.')[:-1]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = base[:len(base) - (node.level - 1)]
                target = '.'.join(anchor + ([node.module] if node.module else []))
            else:
                target = node.module
            out += [(node.lineno, f'{target}.{alias.name}') for alias in node.names]
    return out


def violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """What is wrong with the imports of one module (empty: nothing)."""
    own = package_of(module)
    if own is None:
        return []
    found = []
    for line, target in imported_modules(source, module, is_package):
        where = f'{module}:{line} imports {target}'
        if own in ROS_FREE and ROS_MODULE.match(target):
            found.append(f'{where}: ROS in {own}, which must run without ROS')
            continue
        theirs = package_of(target)
        if theirs is None or theirs == own:
            continue
        if LAYER[theirs] > LAYER[own]:
            found.append(f'{where}: {theirs} (layer {LAYER[theirs]}) is above {own} '
                         f'(layer {LAYER[own]})')
        elif LAYER[own] == LAYER[theirs] and (own not in BOTTOM
                                              or theirs not in BOTTOM[own]):
            found.append(f'{where}: {own} may not import {theirs} (same layer)')
    return found


def source_files() -> list[Path]:
    return sorted(p for folder in ('nmt_ros', 'msg_adapters')
                  for p in (REPO / folder).rglob('*.py'))


def test_every_import_points_down_and_the_core_is_ros_free():
    found = []
    for path in source_files():
        found += violations(path.read_text(encoding='utf-8'), module_name(path),
                            path.name == '__init__.py')
    assert not found, '\n'.join(found)


def test_every_package_has_a_layer():
    """A new package must be placed in LAYER (else its imports go unchecked)."""
    unplaced = sorted({module_name(p) for p in source_files()
                       if package_of(module_name(p)) is None})
    assert not unplaced, unplaced


@pytest.mark.parametrize('module, source, expected', [
    ('nmt_ros.tracking.x', 'from nmt_ros.study.pipeline import run_nmt', 'above'),
    ('nmt_ros.tracking.x', 'def f():\n    import nmt_ros.io.bags', 'above'),
    ('msg_adapters.x', 'from nmt_ros.io.series import JointStateSeries', 'above'),
    ('nmt_ros.io.x', 'from ..study import metrics', 'above'),
    ('nmt_ros.study.x', 'from nmt_ros import cli', 'above'),
    ('nmt_ros.study.x', 'import rclpy', 'without ROS'),
    ('nmt_ros.tracking.x', 'from sensor_msgs.msg import JointState', 'without ROS'),
    ('nmt_ros.model.x', 'from rcl_interfaces.msg import Log', 'without ROS'),
    ('nmt_ros.model.x', 'from nmt_ros.records import Truth', 'same layer'),
    ('nmt_ros.topics', 'from nmt_ros.model import jumper', 'same layer'),
    ('nmt_ros.records', 'from nmt_ros.model.jumper import JumperModel', None),
    ('nmt_ros.io.x', 'from msg_adapters.series import WrenchSeries\nfrom . import msgdefs', None),
    ('nmt_ros.nodes.x', 'import rclpy\nfrom nmt_ros.study import batch', None),
    ('nmt_ros.cli.x', 'from nmt_ros.nodes.runtime import cli_node', None),
])
def test_the_check_catches_what_it_should(module, source, expected):
    """The checker itself, on small sources: each forbidden kind is caught, allowed ones not."""
    found = violations(source, module)
    if expected is None:
        assert found == []
    else:
        assert len(found) == 1 and expected in found[0], found
