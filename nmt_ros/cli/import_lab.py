"""``nmt import-lab``: a lab recording as an observation bag, with its subject's model.

    nmt import-lab --ik IK.mot --grf GRF.mot [--external-loads X.xml] --model S.osim --out BAG
    nmt import-lab --trc M.trc --grf GRF.mot (--model S.osim | --mass KG --height M) --out BAG
    nmt import-lab --c3d F.c3d [--grf GRF.mot] (--model S.osim | --mass KG --height M) --out BAG

Writes BAG (``/mocap/segment_angles``, ``/force_plate/wrench`` at the recording's own rates,
stamped on its own time; subject, sources and what was repaired in ``metadata.yaml``
``custom_data``) and ``BAG/subject.yaml`` (the jumper scaled to the subject), and prints a
summary. See README "Lab recordings".
"""
from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_argument_group('motion (one of)')
    src.add_argument('--ik', type=Path, help='OpenSim inverse-kinematics .mot (needs --model)')
    src.add_argument('--trc', type=Path, help='markers, OpenSim .trc')
    src.add_argument('--c3d', type=Path, help='markers and force plates, .c3d')
    parser.add_argument('--grf', type=Path,
                        help='ground reaction .mot (OpenSim columns; optional with --c3d)')
    parser.add_argument('--external-loads', type=Path,
                        help='OpenSim ExternalLoads .xml naming the plates of --grf')
    parser.add_argument('--model', type=Path, help="the subject's scaled OpenSim model")
    parser.add_argument('--mass', type=float, help='body mass [kg] (without --model)')
    parser.add_argument('--height', type=float, help='stature [m] (without --model)')
    parser.add_argument('--name', default=None, help='subject name (default: file stem)')
    parser.add_argument('--marker-map', type=Path, default=None,
                        help='marker map YAML (default: OpenCap/Rajagopal names); with --model '
                        'it is recalibrated on the model\'s markers when it has them')
    parser.add_argument('--forward', default=None,
                        help='lab axis the subject faces, e.g. +x (default: the marker map\'s; '
                        '+x for --ik)')
    parser.add_argument('--up', default=None, help='lab axis pointing up, e.g. +y or +z')
    parser.add_argument('--max-gap', type=float, default=None,
                        help='longest marker gap filled by interpolation [s] (default 0.1)')
    parser.add_argument('--out', required=True, type=Path, help='bag folder to write')
    parser.add_argument('--force', action='store_true', help='replace an existing --out')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.lab import recording as rec_mod
    from nmt_ros.lab.marker_map import calibrate, load_marker_map, markers_used
    from nmt_ros.lab.opensim_process import measure_model
    from nmt_ros.lab.sagittal import SagittalFrame
    from nmt_ros.model.subject import subject_from_mass_height, subject_from_measures

    routes = [r for r in ('ik', 'trc', 'c3d') if getattr(args, r) is not None]
    try:
        if len(routes) != 1:
            raise ValueError('give exactly one of --ik, --trc, --c3d')
        route = routes[0]
        if route in ('ik', 'trc') and args.grf is None:
            raise ValueError(f'--{route} needs --grf')
        if route == 'ik' and args.model is None:
            raise ValueError('--ik needs --model (the .osim the IK was solved with)')
        if args.out.exists() and any(args.out.iterdir()) if args.out.is_dir() else \
                args.out.exists():
            if not args.force:
                raise ValueError(f'{args.out} exists (use --force to replace it)')
            shutil.rmtree(args.out) if args.out.is_dir() else args.out.unlink()
        source = getattr(args, route)
        name = args.name or source.stem
        measures = None
        if args.model is not None:
            if args.mass is not None or args.height is not None:
                raise ValueError('give --model or --mass/--height, not both')
            measures = measure_model(args.model)
            subject = subject_from_measures(measures, name)
        elif args.mass is not None and args.height is not None:
            subject = subject_from_mass_height(args.mass, args.height, name)
        else:
            raise ValueError('no subject: give --model SUBJECT.osim, or --mass KG --height M')
        kw = {}
        if args.max_gap is not None:
            kw['max_gap_s'] = args.max_gap
        if route == 'ik':
            frame = SagittalFrame(args.forward or '+x', args.up or '+y')
            rec = rec_mod.import_ik(args.ik, args.grf, args.model, subject, args.external_loads,
                                    frame)
        else:
            mmap = load_marker_map(args.marker_map)
            if measures is not None and all(n in measures['markers_m']
                                            for n in markers_used(mmap)):
                mmap = {**calibrate(mmap, measures), 'source_file': mmap['source_file']}
            frame_map = mmap.get('frame', {})
            frame = SagittalFrame(args.forward or frame_map.get('forward', '+x'),
                                  args.up or frame_map.get('up', '+y'))
            if route == 'trc':
                rec = rec_mod.import_trc(args.trc, args.grf, mmap, subject,
                                         args.external_loads, frame, **kw)
            else:
                rec = rec_mod.import_c3d(args.c3d, mmap, subject, args.grf, args.external_loads,
                                         frame, **kw)
        rec_mod.write_lab_bag(args.out, rec)
    except ValueError as err:
        print(f'nmt import-lab: error: {err}', file=sys.stderr)
        return 2
    for r in rec.facts.get('repairs', []):
        print(f'repaired: {r["what"]} gap {r["t_start_s"]:.3f}..{r["t_end_s"]:.3f} s '
              f'({r["samples"]} samples, cubic spline)')
    print(rec_mod.summary_json(rec))
    print(f'wrote {args.out} (+ subject.yaml)')
    return 0
