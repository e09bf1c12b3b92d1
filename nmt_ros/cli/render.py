"""``nmt render BAG --out FILE.mp4|gif``: the body scene of a bag as a movie.

    nmt render BAG --out FILE.gif [--start S] [--duration S] [--fps F]
               [--source auto|estimates|truth] [--subject BAG|SUBJECT.yaml]

The same scene as the live view (``nmt_ros.study.body_scene``: stick figure, muscles coloured
and widened by force, the ground force at the centre of pressure) drawn with matplotlib,
beside time-synchronised plots of the ground force and the main muscle forces. ``.mp4``
needs ffmpeg; ``.gif`` is written with Pillow.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag folder (or .mcap) with estimates or /truth/* topics')
    parser.add_argument('--out', required=True, metavar='FILE',
                        help='the movie: .mp4 (ffmpeg) or .gif (Pillow)')
    parser.add_argument('--start', type=float, default=0.0, metavar='S',
                        help='start this many seconds after the first coordinates')
    parser.add_argument('--duration', type=float, default=None, metavar='S',
                        help='length of the movie [s] (default: to the end)')
    parser.add_argument('--fps', type=float, default=30.0, help='frames per second (30)')
    parser.add_argument('--dpi', type=int, default=80, help='resolution (80: 640x320 px)')
    parser.add_argument('--source', choices=('auto', 'estimates', 'truth'), default='auto',
                        help='draw the estimates, the truth, or estimates when present (auto)')
    parser.add_argument('--subject', default=None, metavar='BAG|SUBJECT.yaml',
                        help="the subject's model (default: the bag's subject.yaml, else the "
                             'shipped jumper; an `nmt track` estimates bag has none: give the '
                             'observation bag)')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.study.body_movie import render_bag

    if not args.fps > 0:
        print('error: --fps must be positive', file=sys.stderr)
        return 2
    start = time.monotonic()
    try:
        out = render_bag(args.bag, args.out, fps=args.fps, start_s=args.start,
                         duration_s=args.duration, source=args.source, dpi=args.dpi,
                         subject=args.subject)
    except (OSError, ValueError, KeyError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    size = Path(out).stat().st_size
    print(f'wrote {out} ({size / 1e6:.2f} MB) in {time.monotonic() - start:.1f} s')
    return 0
