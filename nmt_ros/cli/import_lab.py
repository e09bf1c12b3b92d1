"""``nmt import-lab``: a lab recording as an observation bag, with its subject's model.

    nmt import-lab --ik IK.mot --grf GRF.mot [--external-loads X.xml] --model S.osim
                   [--mass KG|implied|model] --out BAG
    nmt import-lab --trc M.trc --grf GRF.mot (--model S.osim [--mass KG] | --mass KG
                   --height M) --out BAG
    nmt import-lab --c3d F.c3d [--grf GRF.mot] (--model S.osim [--mass KG] | --mass KG
                   --height M) --out BAG

Writes BAG (``/mocap/segment_angles``, ``/force_plate/wrench`` and ``/mocap/ankle_position``
at the recording's own rates, stamped on its own time; subject, sources, what was repaired and
the momentum balance (implied body mass, unmeasured support, step-off) in ``metadata.yaml``
``custom_data``) and ``BAG/subject.yaml`` (the jumper scaled to the subject), and prints a
summary and warnings. The work is ``nmt_ros.study.lab_recording.import_lab``; see README
"Lab recordings".
"""
from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys


def _mass(text: str) -> float | str:
    if text in ('implied', 'model'):
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a mass in kg, 'implied' or "
                                         "'model'") from None


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
    parser.add_argument('--mass', type=_mass,
                        help='body mass [kg]; "implied": the mass the force plates imply '
                        '(a quiet stance on them, or the impulse of a contact between two '
                        'flights); "model": the --model\'s own masses. With --model the '
                        'model\'s segment masses are scaled to it (its mass distribution '
                        'kept). Default with --model: the model\'s masses, unless the plates '
                        'imply a mass more than 5 %% away, then the implied one (said)')
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
    parser.add_argument('--jumper-paths', action='store_true',
                        help="keep the scaled jumper's muscles (paths, and strengths by the "
                        "mass rule; default with --model: moment arms, F0 and optimal fibre "
                        "lengths from the model's own muscles, see 'Lab recordings')")
    parser.add_argument('--out', required=True, type=Path, help='bag folder to write')
    parser.add_argument('--force', action='store_true', help='replace an existing --out')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.study import lab_recording as lab

    try:
        out = args.out
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            if not args.force:
                raise ValueError(f'{out} exists (use --force to replace it)')
            shutil.rmtree(out) if out.is_dir() else out.unlink()
        rec = lab.import_lab(ik=args.ik, trc=args.trc, c3d=args.c3d, grf=args.grf,
                             external_loads=args.external_loads, model=args.model,
                             mass_kg=args.mass, height_m=args.height, name=args.name,
                             marker_map=args.marker_map, forward=args.forward, up=args.up,
                             max_gap_s=args.max_gap, subject_paths=not args.jumper_paths)
        lab.write_lab_bag(out, rec)
    except ValueError as err:
        print(f'nmt import-lab: error: {err}', file=sys.stderr)
        return 2
    for r in rec.facts.get('repairs', []):
        how = r.get('how', 'cubic spline')
        print(f'repaired: {r["what"]}{" gap" if how == "cubic spline" else ""} '
              f'{r["t_start_s"]:.3f}..{r["t_end_s"]:.3f} s ({r["samples"]} samples, {how})')
    print(lab.summary_json(rec))
    mb = rec.facts.get('momentum_balance', {})
    if mb.get('implied_mass_kg') is not None:
        print(f'body mass implied by the recording: {mb["implied_mass_kg"]:.1f} kg '
              f'({mb["implied_mass_method"]}); the model: {rec.subject.mass_kg:.1f} kg')
    for w in rec.facts.get('warnings', []):
        print(f'warning: {w}', file=sys.stderr)
    print(f'wrote {out} (+ subject.yaml)')
    return 0
