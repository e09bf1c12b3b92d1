"""``nmt track BAG --out DIR``: batch NMT (Stage 1, IVD, Stage 2, NMT simulation) on a bag.

Arguments and printing only; the work is ``nmt_ros.study.batch.track_bag`` (what it writes is
described there).
"""
from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', type=Path, help='bag folder (or .mcap) with the observations')
    parser.add_argument('--out', required=True, type=Path, help='output directory')
    parser.add_argument('--stage2-mode', choices=('full', 'windowed'), default='full',
                        help="Stage 2 over the whole horizon (the paper) or receding windows")
    parser.add_argument('--window', type=float, default=None,
                        help='Stage 2 window length H in s (windowed mode)')
    parser.add_argument('--stage1', choices=('auto', 'mhe', 'optimal_muscle', 'optimal',
                                             'skt'),
                        default='auto',
                        help='Stage 1: optimal tracking of all observations over the trial with '
                        'muscle-made joint torques (the most accurate, for a clip: up to 1080 '
                        'force-plate samples), '
                        'the moving-horizon estimator the live graph runs (any length), the '
                        "same optimal tracking with free joint torques, or the paper's "
                        'skeletal motion tracker; auto (default): optimal_muscle up to 1080 '
                        "samples when the paper's tracker (its initial guess) follows the "
                        'whole record, else mhe')
    parser.add_argument('--stage2-kr', type=float, default=None,
                        help='Stage 2 effort weight kR (default: stage2.yaml, the paper\'s 1000; '
                        'lower tracks the Stage-1 torques more closely)')
    parser.add_argument('--start', type=float, default=None, metavar='S',
                        help='start tracking at S s of the recording (default: the step-off '
                        'after an unmeasured support when one is detected, else the first '
                        'sample)')
    parser.add_argument('--wrench-cutoff', type=float, default=None, metavar='HZ',
                        help="moving-horizon estimator: the estimated ground wrench's "
                        'smoothness, the cut-off of its smoothing-spline prior (default 70 Hz, '
                        "at most 0.8 x the force plate's Nyquist frequency; lower it for "
                        'noisy lab plates); the live node\'s wrench_cutoff_hz')
    parser.add_argument('--joint-torques', choices=('auto', 'muscle', 'net'), default='auto',
                        help="moving-horizon estimator: the joint torques reported, the "
                        "muscles' or the net torques of the estimated motion (default auto: "
                        "net for a lab recording's subject, the muscles' for the shipped "
                        "jumper); the live node's joint_torques")
    parser.add_argument('--excitation-rate-weight', type=float, default=0.0, metavar='W',
                        help="moving-horizon estimator: the excitations' rate prior w_du "
                        "(default 0 = auto: 2 for a lab recording's subject, 10 for the "
                        "shipped jumper); the live node's excitation_rate_weight")
    parser.add_argument('--no-figures', action='store_true')
    parser.add_argument('--force', action='store_true', help='replace existing outputs')


def _say(msg: str) -> None:
    print(f'[nmt track] {msg}', flush=True)


def run(args: argparse.Namespace) -> int:
    est = args.out / 'estimates'
    if est.exists():
        if not args.force:
            print(f'error: {est} exists (use --force to replace it)', file=sys.stderr)
            return 2
        shutil.rmtree(est)
    from nmt_ros.study.batch import track_bag

    try:
        metrics = track_bag(args.bag, args.out, args.stage2_mode, args.window,
                            figures=not args.no_figures, say=_say, stage1=args.stage1,
                            stage2_k_r=args.stage2_kr, start_s=args.start,
                            wrench_cutoff_hz=args.wrench_cutoff,
                            joint_torques=args.joint_torques,
                            excitation_rate_weight=args.excitation_rate_weight)
    except ValueError as err:
        print(f'nmt track: error: {err}', file=sys.stderr)
        return 2
    if metrics and 'stage1_phases' in metrics:       # a long stream: scores by phase
        from nmt_ros.study.phase_scores import format_phase_scores

        for key, title in (('stage1_phases', 'Stage 1 (refined)'),
                           ('stage2_phases', 'Stage 2 muscle forces')):
            if key in metrics:
                print(f'{title} vs truth by phase (RMS):')
                print(format_phase_scores(metrics[key]))
    elif metrics:
        from nmt_ros.study.report import summary_lines

        print('\n'.join(summary_lines(metrics)))
    return 0
