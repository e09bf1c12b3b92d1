"""Batch NMT on a bag: read the observations, estimate, write the estimates and the metrics.

What ``nmt track BAG --out DIR`` runs (and the first step of ``nmt reproduce``): Stage 1
(by default optimal tracking of all observations with the joint torques made by the model's
muscles; ``'optimal'``: free joint torques; ``'skt'``: the paper's skeletal motion tracker,
whose result is also the others' initial guess), the IVD baseline, Stage 2 and the NMT
simulation (``nmt_ros.study.pipeline.run_nmt``). Writes ``DIR/estimates/`` (a bag of the
/nmt/* topics stamped with observation time), ``DIR/opensim/`` (the estimates as OpenSim
files, ``nmt_ros.study.opensim_results``) and, when the bag carries ``/truth/*``,
``DIR/metrics.json`` (``stage1_method`` says which Stage 1; its ``skt`` block holds the
Stage-1 results either way) and the paper-style figures.
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path

from nmt_ros.io.bags import bag_info
from nmt_ros.io.trial_bag import has_truth, read_observations, read_truth, write_estimates_bag
from nmt_ros.model.jumper import default_model
from nmt_ros.study.metrics import compute_metrics
from nmt_ros.study.opensim_results import write_opensim_estimates
from nmt_ros.study.pipeline import STAGE1_LABELS, NMTSettings, run_nmt
from nmt_ros.tracking.neuromuscular_tracker import load_stage2_settings


def _quiet(_msg: str) -> None:
    """Default progress sink: say nothing."""


def track_bag(bag: Path, out: Path, stage2_mode: str = 'full', window: float | None = None,
              figures: bool = True, say: Callable[[str], None] = _quiet,
              stage1: str = 'optimal_muscle', stage2_k_r: float | None = None) -> dict | None:
    """Run the NMT on ``bag``, write the outputs under ``out``; returns the metrics (None
    when the bag has no truth). ``window``: Stage 2 window length H [s] (windowed mode);
    ``stage2_k_r``: Stage 2 effort weight kR (None: stage2.yaml's); ``say``: progress."""
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
    write_opensim_estimates(out / 'opensim', model, run)
    say(f'OpenSim files: {out / "opensim"} (model: nmt export-osim)')
    if not has_truth(bag):
        return None
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
        from nmt_ros.study.figures import plot_fig3, plot_fig4, plot_fig5  # matplotlib

        plot_fig3(truth, obs, run, out / 'fig3_skeletal_tracking.png', STAGE1_LABELS[stage1])
        if run.stage2 is not None:
            plot_fig4(truth, run, out / 'fig4_muscles.png', model.p.muscles.f0)
            plot_fig5(truth, obs, run, model, out / 'fig5_nmt.png')
        say(f'figures: {out}/fig3_skeletal_tracking.png, fig4_muscles.png, fig5_nmt.png')
    return metrics
