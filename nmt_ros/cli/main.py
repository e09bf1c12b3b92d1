"""The ``nmt`` command: one entry point, one module per subcommand.

Each subcommand module ``nmt_ros.cli.<name>`` provides ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported lazily so that ``nmt --help`` stays fast and a
subcommand's heavy dependencies (casadi, rclpy, opensim) load only when it runs.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

# One BLAS/OpenMP thread per process unless the user chose (before numpy loads): the
# estimators' factorisations are small, and a multithreaded OpenBLAS on 2 shared cores was
# measured ~100x slower on them (nmt launch passes the same to the node processes).
for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    'demo': ('nmt_ros.cli.demo', 'replay the shipped bag through the live graph and report'),
    'reproduce': ('nmt_ros.cli.reproduce', "the paper's study offline, with figures"),
    'reference': ('nmt_ros.cli.reference', 'parameter optimisation of the reference jump'),
    'routine': ('nmt_ros.cli.routine', 'a long synthetic routine (stance, jumps, landings)'),
    'track': ('nmt_ros.cli.track', 'batch NMT (Stage 1 + IVD + Stage 2) on a bag'),
    'ivd': ('nmt_ros.cli.ivd', 'inverse dynamics on OpenSim .sto/.mot files'),
    'export-osim': ('nmt_ros.cli.export_osim', 'write the model as an OpenSim 4 .osim file'),
    'launch': ('nmt_ros.cli.launch', 'run the whole node graph, one process per node'),
    'run': ('nmt_ros.cli.run_node', 'run one node'),
    'echo': ('nmt_ros.cli.echo', 'print messages of a topic (ros2 topic echo style)'),
    'bag': ('nmt_ros.cli.bag', 'bag tools: info, play, reindex'),
    'import-lab': ('nmt_ros.cli.import_lab',
                   'a lab recording (IK/GRF .mot, TRC, C3D) as an observation bag + subject'),
    'view': ('nmt_ros.cli.view', 'live view (Foxglove WebSocket) of the graph or of a bag'),
    'render': ('nmt_ros.cli.render', 'a movie (mp4/gif) of a bag: body, muscles, ground force'),
}


def ros_environment_defaults() -> None:
    """Keep DDS on loopback unless the user chose otherwise; find the wheels' .msg files."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_LOCALHOST_ONLY', '1')
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='nmt', description='nmt_ros: neuromusculoskeletal tracking (Seth & Pandy 2007)')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module_name)
        if name in argv[:1]:  # only the chosen subcommand's module is imported
            importlib.import_module(module_name).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    ros_environment_defaults()
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args, extra = parser.parse_known_args(argv)
    if not getattr(args, 'command', None):
        parser.print_help()
        return 2
    module = importlib.import_module(args._module)
    if extra and not getattr(module, 'ACCEPTS_EXTRA_ARGS', False):
        parser.error('unrecognized arguments: ' + ' '.join(extra))
    args.extra = extra
    return int(module.run(args) or 0)


if __name__ == '__main__':
    sys.exit(main())
