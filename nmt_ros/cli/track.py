"""``nmt track BAG --out DIR``: batch NMT (Stage 1, IVD, Stage 2, NMT simulation) on a bag.

Stage 1 is by default optimal tracking of all observations with the joint torques made by the
model's muscles (``--stage1 optimal``: free joint torques; ``--stage1 skt``: the paper's
skeletal motion tracker, whose result is also the others' initial guess); ``metrics.json`` says
which (``stage1_method``; its ``skt`` block holds the Stage-1 results either way).

Writes ``DIR/estimates/`` (a bag of the /nmt/* topics stamped with observation time),
``DIR/opensim/`` (the estimates as OpenSim files, ``nmt_ros.study.opensim_results``) and, when
the bag carries ``/truth/*``, ``DIR/metrics.json`` and the paper-style figures.
"""
from __future__ import annotations

import argparse
import json
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
    parser.add_argument('--stage1', choices=('optimal_muscle', 'optimal', 'skt'),
                        default='optimal_muscle',
                        help='Stage 1: optimal tracking of all observations over the trial with '
                        'muscle-made joint torques (default: the most accurate, offline), the '
                        "same with free joint torques, or the paper's skeletal motion tracker "
                        '(what the live graph runs)')
    parser.add_argument('--stage2-kr', type=float, default=None,
                        help='Stage 2 effort weight kR (default: stage2.yaml, the paper\'s 1000; '
                        'lower tracks the Stage-1 torques more closely)')
    parser.add_argument('--no-figures', action='store_true')
    parser.add_argument('--force', action='store_true', help='replace existing outputs')


def _say(msg: str) -> None:
    print(f'[nmt track] {msg}', flush=True)


def track_bag(bag: Path, out: Path, stage2_mode: str = 'full', window: float | None = None,
              figures: bool = True, say: callable = _say, stage1: str = 'optimal_muscle',
              stage2_k_r: float | None = None) -> dict | None:
    """Run the NMT on ``bag``, write the outputs; returns the metrics (None without truth)."""
    from nmt_ros.io.bags import bag_info
    from nmt_ros.io.trial_bag import has_truth, read_observations, read_truth, write_estimates_bag
    from nmt_ros.model.jumper import default_model
    from nmt_ros.study.pipeline import STAGE1_LABELS, NMTSettings, run_nmt
    from nmt_ros.tracking.neuromuscular_tracker import load_stage2_settings

    model = default_model()
    obs = read_observations(bag)
    say(f'{bag}: {obs.t_angles.size} angle samples, {obs.t_wrench.size} wrench samples, '
        f'{obs.t_wrench[-1]:.3f} s')
    run = run_nmt(model, obs, NMTSettings(stage1=stage1, stage2_mode=stage2_mode,
                                          window_length_s=window, stage2_k_r=stage2_k_r),
                  progress=say)
    out.mkdir(parents=True, exist_ok=True)
    write_estimates_bag(out / 'estimates', model, run.estimates(), obs.info['epoch_ns'])
    say(f'estimates: {out / "estimates"}')
    from nmt_ros.study.opensim_results import write_opensim_estimates

    write_opensim_estimates(out / 'opensim', model, run)
    say(f'OpenSim files: {out / "opensim"} (model: nmt export-osim)')
    if not has_truth(bag):
        return None
    from nmt_ros.study.metrics import compute_metrics

    truth = read_truth(bag)
    po = None
    record = Path(bag) / 'reference.json'
    if record.exists():
        po = json.loads(record.read_text()).get('po')
    metrics = compute_metrics(model, run, truth, po)
    metrics['source_bag'] = str(bag)
    metrics['stage1_method'] = stage1
    metrics['stage2_k_r'] = (stage2_k_r if stage2_k_r is not None
                             else load_stage2_settings().k_r)
    metrics['custom_data'] = dict(bag_info(bag).custom_data or {})
    (out / 'metrics.json').write_text(json.dumps(metrics, indent=1, default=float))
    say(f'metrics: {out / "metrics.json"}')
    if figures:
        from nmt_ros.study.figures import plot_fig3, plot_fig4, plot_fig5

        plot_fig3(truth, obs, run, out / 'fig3_skeletal_tracking.png', STAGE1_LABELS[stage1])
        if run.stage2 is not None:
            plot_fig4(truth, run, out / 'fig4_muscles.png', model.p.muscles.f0)
            plot_fig5(truth, obs, run, model, out / 'fig5_nmt.png')
        say(f'figures: {out}/fig3_skeletal_tracking.png, fig4_muscles.png, fig5_nmt.png')
    return metrics


def run(args: argparse.Namespace) -> int:
    est = args.out / 'estimates'
    if est.exists():
        if not args.force:
            print(f'error: {est} exists (use --force to replace it)', file=sys.stderr)
            return 2
        shutil.rmtree(est)
    metrics = track_bag(args.bag, args.out, args.stage2_mode, args.window,
                        figures=not args.no_figures, stage1=args.stage1,
                        stage2_k_r=args.stage2_kr)
    if metrics:
        from nmt_ros.study.report import summary_lines

        print('\n'.join(summary_lines(metrics)))
    return 0
