"""``nmt export-osim``: write the jumper model as an OpenSim 4 model (.osim).

OpenSim runs in a subprocess (``python -m nmt_ros.osim.export``): it cannot share a process
with casadi, which the CLI process may already have loaded.
"""
from __future__ import annotations

import argparse
import subprocess
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', required=True, help='output .osim file')
    parser.add_argument('--with-contact-spheres', action='store_true',
                        help='also add APPROXIMATE smooth contact spheres at heel and toe '
                             '(visualisation/Moco only; not our contact law)')
    parser.add_argument('--data-file', default=None,
                        help='model data file (default: the packaged jumper.yaml)')


def run(args: argparse.Namespace) -> int:
    cmd = [sys.executable, '-m', 'nmt_ros.osim.export', '--out', str(args.out)]
    if args.with_contact_spheres:
        cmd.append('--with-contact-spheres')
    if getattr(args, 'data_file', None):
        cmd += ['--data-file', str(args.data_file)]
    return subprocess.run(cmd, check=False).returncode
