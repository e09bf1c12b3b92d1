"""Batch NMT on a bag: read the observations, estimate, write the estimates and the metrics.

What ``nmt track BAG --out DIR`` runs (and the first step of ``nmt reproduce``): Stage 1
(by default optimal tracking of all observations with the joint torques made by the model's
muscles, from the paper's skeletal motion tracker's result, or the moving-horizon estimator
when that tracker loses control or the record is long; ``'optimal'``: free joint torques;
``'skt'``: the paper's tracker alone; ``'mhe'``: the moving-horizon estimator), the IVD
baseline, Stage 2 and the NMT simulation (``nmt_ros.study.pipeline.run_nmt``). Writes
``DIR/estimates/`` (a bag of the /nmt/* topics stamped with observation time),
``DIR/opensim/`` (the estimates as OpenSim files, ``nmt_ros.study.opensim_results``) and,
when the bag carries ``/truth/*``, ``DIR/metrics.json`` (``stage1_method`` says which
Stage 1; its ``skt`` block holds the Stage-1 results either way) and the paper-style figures.

Any bag: the model is the bag's subject (``BAG/subject.yaml``, written by ``nmt import-lab``;
the shipped jumper when there is none); the rates are the observations' own (the output grid
is the force plate's samples); tracking starts where ``nmt_ros.study.trial_start.plan_start``
says (a given ``start_s``, the step-off after an unmeasured support, or the first sample), and
the estimates keep the recording's time (stamped like the observations).
"""
from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path

import numpy as np

from nmt_ros.io.bags import bag_info
from nmt_ros.io.opensim_files import read_table
from nmt_ros.io.trial_bag import has_truth, read_observations, read_truth, write_estimates_bag
from nmt_ros.model.subject import load_subject_model, subject_file
from nmt_ros.study.metrics import compute_metrics
from nmt_ros.study.observation_fit import format_fit, id_agreement, observation_fit
from nmt_ros.study.opensim_results import write_opensim_estimates
from nmt_ros.study.pipeline import STAGE1_LABELS, NMTSettings, run_nmt
from nmt_ros.study.trial_start import plan_start
from nmt_ros.tracking.conditioning import nominal_rate, sample_rate
from nmt_ros.tracking.moving_horizon.settings import (
    MovingHorizonSettings,
    airborne_translation_diffusion_for,
    excitation_rate_weight_for,
    joint_torques_for,
    landing_rate_sd_scale_for,
)
from nmt_ros.tracking.optimal_tracker import OptimalTrackingSettings
from nmt_ros.tracking.skeletal_tracker import SKTSettings
from nmt_ros.tracking.stage2 import load_stage2_settings

#: Stage 1's foot-angle weight in flight for trials that start in flight (Table 1's shank
#: weight: in the air the foot is a segment like the others; see
#: ``SKTSettings.flight_foot_weight``).
FLIGHT_FOOT_WEIGHT = 0.7


def _quiet(_msg: str) -> None:
    """Default progress sink: say nothing."""


def _rate(t: np.ndarray, what: str, bag: Path) -> float:
    try:
        return nominal_rate(sample_rate(t))
    except ValueError as err:
        raise ValueError(f'{bag}: {what}: {err}') from None


def track_bag(bag: Path, out: Path, stage2_mode: str = 'full', window: float | None = None,
              figures: bool = True, say: Callable[[str], None] = _quiet,
              stage1: str = 'auto', stage2_k_r: float | None = None,
              start_s: float | None = None,
              wrench_cutoff_hz: float | None = None,
              joint_torques: str = 'auto', excitation_rate_weight: float = 0.0,
              ) -> dict | None:
    """Run the NMT on ``bag``, write the outputs under ``out``; returns the metrics (None
    when the bag has no truth). ``window``: Stage 2 window length H [s] (windowed mode);
    ``stage2_k_r``: Stage 2 effort weight kR (None: stage2.yaml's); ``start_s``: start
    tracking there (recording time, s; None: ``plan_start``'s choice); ``wrench_cutoff_hz``:
    the moving-horizon estimator's ground-wrench smoothness [Hz] (None: its default);
    ``joint_torques``: 'muscle', 'net' or 'auto' (``settings.joint_torques_for``);
    ``excitation_rate_weight``: the estimator's w_du (0: auto,
    ``settings.excitation_rate_weight_for``);
    ``say``: progress."""
    bag = Path(bag)
    model = load_subject_model(bag)
    subject = subject_file(bag)
    who = f'the subject of {subject}' if subject is not None else 'the shipped jumper'
    say(f'model: {who} ({model.p.total_mass:.2f} kg)')
    obs = read_observations(bag)
    rate_a = _rate(obs.t_angles, 'segment angles', bag)
    rate_w = _rate(obs.t_wrench, 'force plate', bag)
    say(f'{bag}: {obs.t_angles.size} angle samples at {rate_a:.6g} Hz, {obs.t_wrench.size} '
        f'wrench samples at {rate_w:.6g} Hz, {obs.t_wrench[0]:.3f}..{obs.t_wrench[-1]:.3f} s')
    if stage1 == 'auto':
        # the whole-trial optimal tracking is for a clip (its NLP grows with the record and
        # is refused beyond max_intervals force-plate samples); a long stream is tracked by
        # the moving-horizon estimator, as live
        n = int((obs.t_wrench >= (start_s or obs.t_wrench[0]) - 1e-9).sum())
        limit = OptimalTrackingSettings().max_intervals
        if n > limit:
            stage1 = 'mhe'
            say(f'Stage 1: mhe ({n} force-plate samples to track; optimal tracking up to '
                f'{limit})')
        else:
            say(f'Stage 1: optimal_muscle from the skeletal tracker\'s result, or mhe if the '
                f'tracker loses control ({n} force-plate samples to track)')
    start = plan_start(model, obs, start_s, needs_state=stage1 != 'mhe')
    if start.balance is not None:
        b = start.balance
        if b.get('implied_mass_kg') is not None:
            say(f'momentum balance: the forces imply {b["implied_mass_kg"]:.1f} kg '
                f'({b["implied_mass_method"]}), the model has {b["model_mass_kg"]:.1f} kg')
        if b.get('unmeasured_support_s') is not None:
            a0, a1 = b['unmeasured_support_s']
            say(f'unmeasured support {a0:.3f}..{a1:.3f} s (motion and forces disagree: the '
                f'plates read no load while the COM does not fall); step-off {a1:.3f} s')
    say(f'tracking starts at {start.t_s:.4f} s ({start.reason})')
    for note in start.notes:
        say(note)
    skt = SKTSettings()
    if start.in_flight:          # the foot is not held by the ground until the landing
        skt = skt.with_(flight_foot_weight=FLIGHT_FOOT_WEIGHT)
        say(f'Stage 1 in flight: foot angle weight {FLIGHT_FOOT_WEIGHT:g} while unloaded '
            f'(Table 1: {skt.weights[0]:g} on the ground)')
    # the moving-horizon estimator at the bag's rates, as the live node gets them
    mhe = MovingHorizonSettings(
        angle_rate_hz=rate_a, wrench_rate_hz=rate_w,
        joint_torques=joint_torques_for(joint_torques, subject is not None),
        excitation_rate_weight=excitation_rate_weight_for(excitation_rate_weight,
                                                          subject is not None),
        landing_rate_sd_scale=landing_rate_sd_scale_for(subject is not None),
        airborne_translation_diffusion_m_sqrt_s=airborne_translation_diffusion_for(
            subject is not None))
    if wrench_cutoff_hz is not None:
        mhe = mhe.with_(wrench_cutoff_hz=wrench_cutoff_hz)
    mhe.validate()                 # a bad option is refused before any work
    cutoff, lowered = mhe.wrench_cutoff()
    if stage1 in ('mhe', 'auto', 'optimal_muscle'):   # (they fall back on it)
        say(f'moving-horizon estimator: ground wrench smoothed at {cutoff:g} Hz'
            + (f' ({lowered})' if lowered else '') + f'; joint torques: {mhe.joint_torques}'
            + (' (the net torques of the estimated motion: a lab subject)'
               if mhe.joint_torques == 'net' else ' (the muscles\')')
            + f'; excitation rate weight {mhe.excitation_rate_weight:g}'
            + (' (a lab subject)' if subject is not None and not excitation_rate_weight
               else ''))
    run = run_nmt(model, obs, NMTSettings(stage1=stage1, stage2_mode=stage2_mode,
                                          window_length_s=window, stage2_k_r=stage2_k_r,
                                          rate_hz=rate_w, skt=skt, mhe=mhe),
                  progress=say, start=start.state, t_start_s=start.t_s)
    stage1 = run.stage1_method
    out.mkdir(parents=True, exist_ok=True)
    estimates = run.estimates().shifted(start.t_s)       # back on the recording's time
    facts = {'nmt.track': {'start_s': start.t_s, 'start_reason': start.reason,
                           'start_in_flight': start.in_flight, 'notes': start.notes,
                           'mhe_wrench_cutoff_hz': cutoff,
                           'conditioning': list(run.cond.notes), 'rate_hz': rate_w,
                           'model_mass_kg': model.p.total_mass,
                           'stage1_status': run.skt.status,
                           'stage1_events': estimates.stage1.events}}
    if start.balance is not None:
        facts['nmt.momentum_balance'] = start.balance
    write_estimates_bag(out / 'estimates', model, estimates, obs.info['epoch_ns'],
                        custom_data=facts)
    say(f'estimates: {out / "estimates"}')
    write_opensim_estimates(out / 'opensim', model, run, t_offset_s=start.t_s)
    say(f'OpenSim files: {out / "opensim"} (model: nmt export-osim'
        f'{"" if subject is None else f" --subject {subject}"})')
    s1 = estimates.stage1
    fit = {'observation_fit': observation_fit(obs, s1.t, s1.q[:, :4], s1.s,
                                              model.p.body_weight)}
    # OpenSim's inverse dynamics of the recording when the bag carries it (README "Lab
    # recordings"): opensim_id.sto unfiltered, opensim_id_15hz.sto with coordinates and
    # plates low-passed alike at 15 Hz
    id_tables = {}
    for key, name in (('opensim_id', 'opensim_id.sto'),
                      ('opensim_id_15hz', 'opensim_id_15hz.sto')):
        id_file = bag / name if bag.is_dir() else None
        if id_file is not None and id_file.exists():
            id_tables[key] = read_table(id_file)
            fit[key] = {'file': str(id_file),
                        **id_agreement(obs, s1.t, s1.tau, id_tables[key])}
    say(format_fit(fit['observation_fit'], fit.get('opensim_id'), fit.get('opensim_id_15hz')))
    (out / 'observation_fit.json').write_text(json.dumps(fit, indent=1))
    if not has_truth(bag):
        if figures:
            from nmt_ros.study.figures import plot_lab_fit  # matplotlib

            shown = 'opensim_id_15hz' if 'opensim_id_15hz' in id_tables else 'opensim_id'
            plot_lab_fit(obs, estimates, out / 'fig_lab_fit.png', model.p.body_weight,
                         model.p.muscles.f0, id_tables.get(shown),
                         title=f'{bag.name}: estimate vs measurement '
                         f'({STAGE1_LABELS[stage1]})',
                         id_label='OpenSim ID, 15 Hz' if shown == 'opensim_id_15hz'
                         else 'OpenSim ID')
            say(f'figure: {out / "fig_lab_fit.png"}')
        return None
    if start.t_s != 0.0:
        say(f'metrics skipped: tracking started at {start.t_s:.3f} s, the truth at 0')
        return None
    truth = read_truth(bag)
    po = None
    record = Path(bag) / 'reference.json'
    if record.exists():
        po = json.loads(record.read_text()).get('po')
    if stage1 == 'mhe':
        # a long stream (routine): the estimates against the truth phase by phase
        from nmt_ros.study.phase_scores import format_phase_scores, phase_scores

        metrics = {'stage1_phases': phase_scores(model, truth, run.skt.t, run.skt.tau,
                                                 run.skt.muscles['f'])}
        if run.stage2 is not None:
            metrics['stage2_phases'] = phase_scores(model, truth, run.stage2.t, None,
                                                    run.stage2.f)
        say('Stage 1 (refined) vs truth by phase:\n' +
            format_phase_scores(metrics['stage1_phases']))
        figures = False
    else:
        metrics = compute_metrics(model, run, truth, po)
    metrics.update(fit)
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
