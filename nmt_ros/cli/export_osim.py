"""``nmt export-osim``: write the jumper model (or a subject's) as an OpenSim 4 model (.osim).

OpenSim runs in a subprocess (``python -m nmt_ros.osim.export``): it cannot share a process
with casadi, which the CLI process may already have loaded. ``--subject FILE`` (a subject
YAML, or a bag folder holding ``subject.yaml``, as ``nmt import-lab`` writes them) exports
the jumper scaled to that subject (``nmt_ros.model.subject``): its model data file is written
beside the output (``OUT.data.yaml``) and exported.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import subprocess
import sys

import yaml


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', required=True, help='output .osim file')
    parser.add_argument('--with-contact-spheres', action='store_true',
                        help='also add APPROXIMATE smooth contact spheres at heel and toe '
                             '(visualisation/Moco only; not our contact law)')
    parser.add_argument('--data-file', default=None,
                        help='model data file (default: the packaged jumper.yaml)')
    parser.add_argument('--subject', default=None, metavar='FILE',
                        help="a subject's model: subject.yaml (or a bag folder holding one)")


def subject_data_file(subject: str, out: str | Path) -> Path:
    """The model data file of the jumper scaled to ``subject``, written as ``OUT.data.yaml``."""
    from nmt_ros.model.parameters import load_parameters, parameters_data
    from nmt_ros.model.subject import read_subject, scale_parameters, subject_file

    found = subject_file(subject)
    if found is None:
        raise ValueError(f'{subject}: no subject file (subject.yaml)')
    person, scale = read_subject(found)
    data = parameters_data(scale_parameters(load_parameters(), scale))
    data['subject'] = {'name': person.name, 'mass_kg': person.mass_kg, 'file': str(found),
                       'source': person.source, 'scale': scale.as_dict()}
    path = Path(str(out) + '.data.yaml')
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'# The jumper scaled to {person.name} ({found}) by nmt_ros.model.subject\n'
                    + yaml.safe_dump(data, sort_keys=False, width=99), encoding='utf-8')
    return path


def run(args: argparse.Namespace) -> int:
    data_file = getattr(args, 'data_file', None)
    if getattr(args, 'subject', None):
        if data_file:
            print('nmt export-osim: error: give --subject or --data-file, not both',
                  file=sys.stderr)
            return 2
        try:
            data_file = subject_data_file(args.subject, args.out)
        except ValueError as err:
            print(f'nmt export-osim: error: {err}', file=sys.stderr)
            return 2
    cmd = [sys.executable, '-m', 'nmt_ros.osim.export', '--out', str(args.out)]
    if args.with_contact_spheres:
        cmd.append('--with-contact-spheres')
    if data_file:
        cmd += ['--data-file', str(data_file)]
    return subprocess.run(cmd, check=False).returncode
