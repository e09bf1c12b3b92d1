"""``nmt reproduce --out DIR [--quick]``: the paper's study offline, with figures and report.

From the shipped reference (``bags/reference_jump``) by default, or a fresh parameter
optimisation with ``--fresh-reference``. Writes ``DIR/metrics.json``, ``DIR/report.md`` (the
table of results next to the paper's), Figs. 3-5 and the estimates bag.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import shutil
import sys
import time

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / 'bags' / 'reference_jump'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', required=True, type=Path, help='output directory')
    parser.add_argument('--quick', action='store_true',
                        help='fewer seeds, sweep points and windows (and a quick PO with '
                        '--fresh-reference)')
    parser.add_argument('--bag', type=Path, default=SHIPPED,
                        help='reference bag (default: the shipped bags/reference_jump)')
    parser.add_argument('--fresh-reference', action='store_true',
                        help='run the parameter optimisation first (nmt reference)')
    parser.add_argument('--force', action='store_true', help='replace DIR')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.study.reproduce import reproduce

    out: Path = args.out
    if out.exists() and any(out.iterdir()):
        if not args.force:
            print(f'error: {out} is not empty (use --force to replace it)', file=sys.stderr)
            return 2
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    def say(msg: str) -> None:
        print(f'[nmt reproduce {time.perf_counter() - start:6.1f} s] {msg}', flush=True)

    bag = args.bag
    po = None
    if args.fresh_reference:
        from nmt_ros.cli import reference as ref_cli

        ns = argparse.Namespace(out=out, name='reference_jump', quick=args.quick, starts=None,
                                seed=0, noise_scale=1.0, force=True)
        if ref_cli.run(ns) != 0:
            return 1
        bag = out / 'reference_jump'
    record = bag / 'reference.json'
    if record.exists():
        po = json.loads(record.read_text()).get('po')
        po = {k: po[k] for k in ('cpu_s', 'wall_s', 'iterations', 'jump_height_m') if k in po}
    metrics = reproduce(out, bag, quick=args.quick, say=say, po=po)
    from nmt_ros.study.report import summary_lines

    print('\n'.join(summary_lines(metrics)))
    return 0
