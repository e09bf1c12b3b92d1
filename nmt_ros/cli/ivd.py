"""``nmt ivd``: inverse dynamics on OpenSim files (coordinates .sto + ground reaction .mot).

    nmt ivd --coordinates X.sto --grf Y.mot --out tau.sto [--lowpass HZ] [--residuals foot|hat]
            [--spline-ends natural|not-a-knot]

The coordinates are those of the exported model (``nmt export-osim``: foot_tilt, foot_tx,
foot_ty, ankle_angle, knee_angle, hip_flexion; ``inDegrees`` honoured); the .mot holds the
ground force, its point of application and free torque in ground (columns
``ground_force_v*``, ``ground_force_p*``, ``ground_torque_*``), applied to the foot. The output
uses OpenSim's InverseDynamicsTool column names (see ``nmt_ros.io.ivd_opensim``).
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--coordinates', required=True, type=Path,
                        help='coordinates .sto/.mot of the exported model')
    parser.add_argument('--grf', required=True, type=Path,
                        help='ground reaction .mot (force, point, torque in ground)')
    parser.add_argument('--out', required=True, type=Path, help='output .sto')
    parser.add_argument('--lowpass', type=float, default=None, metavar='HZ',
                        help='zero-lag low-pass cut-off for the coordinates (default: none, '
                             "like OpenSim's -1)")
    parser.add_argument('--residuals', choices=('foot', 'hat'), default='foot',
                        help="where the residual wrench goes: 'foot' (OpenSim's ID with the "
                             "foot as root, default) or 'hat' (bottom-up)")
    parser.add_argument('--spline-ends', choices=('natural', 'not-a-knot'), default='natural',
                        help="end conditions of the quintic spline that differentiates the "
                             "coordinates: 'natural' = OpenSim's (default)")
    parser.add_argument('--grf-prefix', default='ground_force',
                        help='force/point column prefix in the .mot (default ground_force)')
    parser.add_argument('--torque-prefix', default='ground_torque',
                        help='torque column prefix in the .mot (default ground_torque)')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.io.ivd_opensim import inverse_dynamics_files

    try:
        res = inverse_dynamics_files(args.coordinates, args.grf, args.out,
                                     lowpass_hz=args.lowpass, residuals=args.residuals,
                                     prefix=args.grf_prefix, torque_prefix=args.torque_prefix,
                                     spline_ends=args.spline_ends)
    except (OSError, ValueError) as err:
        print(f'nmt ivd: error: {err}', file=sys.stderr)
        return 2
    peak = abs(res.tau).max(axis=0)
    print(f'nmt ivd: {res.time.size} samples, {res.time[0]:g}..{res.time[-1]:g} s; '
          f'peak |torque| ankle {peak[0]:.1f}, knee {peak[1]:.1f}, hip {peak[2]:.1f} N m; '
          f'residuals at the {res.residual_at}; wrote {args.out}')
    return 0
