"""A simulated routine written out: its truth record, observations, bag, OpenSim truth files,
figure and facts (what ``nmt routine`` writes into one folder)."""
from __future__ import annotations

from dataclasses import asdict
import json
from pathlib import Path

import numpy as np

from nmt_ros.io.routine_bag import as_float32, write_routine_bag
from nmt_ros.model.contact import LIFTOFF_FORCE_N
from nmt_ros.model.jumper import JumperModel
from nmt_ros.records import Observations, Truth, truth_from_simulation
from nmt_ros.study.opensim_results import write_motion
from nmt_ros.study.routine import Routine
from nmt_ros.study.routine_figures import plot_routine
from nmt_ros.study.routine_observations import (
    RoutineObservationSettings,
    make_routine_observations,
)


def routine_truth(model: JumperModel, routine: Routine, rounded: bool = True) -> Truth:
    """The routine's truth as a trial record (``x0`` holds the anchors per sample [n, 2];
    ``liftoff_s`` the first lift-off); ``rounded``: every array rounded to float32 precision
    (relative 6e-8: below the integrator's tolerance; the bags compress ~2x better). The
    OpenSim files take the unrounded truth: OpenSim differentiates the coordinates twice, and
    float32 steps at 1080 Hz would add ~1 % of the joint torques' peak."""
    first = next((c.liftoff_s for c in routine.cycles if np.isfinite(c.liftoff_s)),
                 float('nan'))
    truth = truth_from_simulation(model, routine.t, routine.x, routine.u, routine.anchors,
                                  first)
    if rounded:
        for name in ('q', 'qd', 'qdd', 'a', 'u', 'f', 'tau', 's', 'point_forces', 'x0'):
            setattr(truth, name, as_float32(getattr(truth, name)))
    return truth


#: Resolution of the stored observations: the force plate's A/D step (1/64 N, 1/512 N m:
#: a 16-bit converter over +-2 kN is ~0.06 N) and the mocap angles' (2^-16 rad, 1.5e-5 rad),
#: far below the noise (15 N, 0.017 rad); the bias components at 2^-12 N, 2^-14 N m, 2^-20 rad.
#: Dyadic steps: observation - truth - bias is then exact in float64.
WRENCH_STEP = np.array([2.0 ** -6, 2.0 ** -6, 2.0 ** -9])
ANGLE_STEP = 2.0 ** -16
WRENCH_BIAS_STEP = np.array([2.0 ** -12, 2.0 ** -12, 2.0 ** -14])
ANGLE_BIAS_STEP = 2.0 ** -20


def quantize(x: np.ndarray, step: float | np.ndarray) -> np.ndarray:
    """x rounded to multiples of ``step`` (NaN kept)."""
    return np.round(np.asarray(x, dtype=float) / step) * step


def rounded_observations(truth: Truth, settings: RoutineObservationSettings,
                         body_weight: float) -> tuple[Observations, dict]:
    """``make_routine_observations`` with the observations and the bias components rounded
    to their resolutions (``*_STEP``) and the noise recomputed as observation - truth - bias,
    so that the identity holds exactly in the bag."""
    obs, comp = make_routine_observations(truth, settings, body_weight)
    for key in ('wrench_bias', 'wrench_drift', 'wrench_spikes', 'smooth_wrench_bias'):
        if key in comp:
            comp[key] = quantize(comp[key], WRENCH_BIAS_STEP)
    for key in ('angle_bias', 'angle_spikes'):
        if key in comp:
            comp[key] = quantize(comp[key], ANGLE_BIAS_STEP)
    if 'wrench_drift' in comp:     # the parts sum exactly to the published bias
        comp['wrench_bias'] = (comp['smooth_wrench_bias'] + comp['wrench_drift']
                               + comp['wrench_spikes'])
        comp['angle_bias'] = comp['smooth_angle_bias'] + comp['angle_spikes']
    nan_a, nan_w = np.isnan(obs.angles), np.isnan(obs.wrench)
    obs.angles = quantize(truth.q[comp['angle_index'], :4] + comp['angle_bias']
                          + comp['angle_noise'], ANGLE_STEP)
    obs.wrench = quantize(truth.s[comp['wrench_index']] + comp['wrench_bias']
                          + comp['wrench_noise'], WRENCH_STEP)
    obs.angles[nan_a] = np.nan
    obs.wrench[nan_w] = np.nan
    comp['angle_noise'] = obs.angles - truth.q[comp['angle_index'], :4] - comp['angle_bias']
    comp['wrench_noise'] = obs.wrench - truth.s[comp['wrench_index']] - comp['wrench_bias']
    return obs, comp


def contact_intervals(t: np.ndarray, fy: np.ndarray,
                      threshold_n: float = LIFTOFF_FORCE_N) -> list[list[float]]:
    """[start, end] [s] of the intervals where the vertical force exceeds the threshold (the
    lift-off rule's, interpolated at both ends)."""
    above = fy > threshold_n
    edges = np.flatnonzero(np.diff(above.astype(int)))
    out = []
    start = float(t[0]) if above[0] else None
    for i in edges:
        tc = float(t[i] + (t[i + 1] - t[i]) * (fy[i] - threshold_n) / (fy[i] - fy[i + 1]))
        if above[i + 1]:
            start = tc
        elif start is not None:
            out.append([start, tc])
            start = None
    if start is not None:
        out.append([start, float(t[-1])])
    return out


def centre_of_pressure(model: JumperModel, truth: Truth, fy_min: float = 50.0) -> np.ndarray:
    """Centre of pressure x [m] on the ground line (NaN where F_y < fy_min N)."""
    pts, = model.batch(model.positions, truth.q)[4:5]
    fy = truth.point_forces[:, :, 1]
    total = fy.sum(axis=1)
    cop = (pts[:, 0, :] * fy).sum(axis=1) / np.where(total > 0, total, 1.0)
    return np.where(total >= fy_min, cop, np.nan)


def routine_facts(model: JumperModel, routine: Routine, truth: Truth) -> dict:
    """Contact intervals, cycles, impact peaks and sway per stance window."""
    bw = model.p.body_weight
    fy = truth.s[:, 1]
    cop = centre_of_pressure(model, truth)
    com, = model.batch(model.com, truth.q)
    sway = []
    for a, b in routine.stances:
        sel = (truth.t >= a + 1.5) & (truth.t <= b - 1.0)    # settled, before the next jump
        if sel.sum() < 100:
            continue
        sway.append({'start_s': a, 'end_s': b,
                     'cop_range_mm': float(1000 * np.ptp(cop[sel])),
                     'cop_sd_mm': float(1000 * np.nanstd(cop[sel])),
                     'com_range_mm': float(1000 * np.ptp(com[sel, 0]))})
    intervals = contact_intervals(truth.t, fy)
    landings = []
    for c in routine.cycles:
        for t_td in ([c.landing_s] if c.kind == 'cmj' else
                     [c.touchdowns_s[0] if c.touchdowns_s else np.nan, c.landing_s]):
            if not np.isfinite(t_td):
                continue
            sel = (truth.t >= t_td) & (truth.t <= t_td + 0.25)
            landings.append({'touchdown_s': float(t_td),
                             'peak_bw': float(fy[sel].max() / bw)})
    return {
        'body_weight_n': bw,
        'cycles': [c.as_dict() for c in routine.cycles],
        'contact_intervals_s': intervals,
        'stance_windows_s': [list(w) for w in routine.stances],
        'touchdowns': [{'t_s': td.t, 'point': ['heel', 'toe'][td.point],
                        'anchor_m': td.anchor_m} for td in routine.touchdowns],
        'landing_peaks': landings,
        'sway': sway,
        'standing_com_height_m': model.standing_com_height,
        'settings': asdict(routine.settings),
        'simulation_cpu_s': routine.cpu_s,
    }


def write_routine_folder(folder: str | Path, model: JumperModel, routine: Routine,
                         faults: bool = False, generation_cpu_s: float | None = None,
                         truth_rate_hz: float = 1080.0, opensim: bool = True,
                         with_truth: bool = True) -> dict:
    """Bag + OpenSim truth files (``opensim``) + figure of a routine in ``folder``; returns
    its facts. ``truth_rate_hz``: rate of the kinematic and muscle truth topics;
    ``with_truth`` False leaves the truth topics out (the faulty twin of a clean bag)."""
    folder = Path(folder)
    truth = routine_truth(model, routine)
    obs_settings = RoutineObservationSettings(faults=faults, seed=routine.settings.seed)
    obs, comp = rounded_observations(truth, obs_settings, model.p.body_weight)
    facts = routine_facts(model, routine, truth)
    if generation_cpu_s is not None:
        facts['generation_cpu_s'] = generation_cpu_s
    # CPU times differ between runs: kept out of the bag (same seed, same bytes), in a
    # file beside it
    timing = {k: facts[k] for k in ('simulation_cpu_s', 'generation_cpu_s') if k in facts}
    timing['plan_cpu_s'] = [c.get('plan_cpu_s') for c in facts['cycles']]
    custom = {f'nmt.routine.{k}': v for k, v in facts.items() if k not in timing}
    custom['nmt.routine.cycles'] = [{k: v for k, v in c.items() if k != 'plan_cpu_s'}
                                    for c in facts['cycles']]
    custom['nmt.routine.observations'] = obs.info
    if not with_truth:
        custom['nmt.routine.truth'] = ('not in this bag: that of the clean routine bag of the '
                                       'same seed')
    info = write_routine_bag(folder, obs, truth, comp, truth.x0, custom_data=custom,
                             truth_rate_hz=truth_rate_hz, with_truth=with_truth)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'generation_cpu.json').write_text(json.dumps(timing, indent=1) + '\n')
    if opensim:
        exact = routine_truth(model, routine, rounded=False)
        write_motion(folder, model, 'truth', exact.t, exact.q, exact.qd, exact.a, exact.x0)
    bw = model.p.body_weight
    plot_routine(truth.t, truth.s[:, 1] / bw, centre_of_pressure(model, truth),
                 facts['cycles'], routine.stances, folder / 'routine.png',
                 obs_t=obs.t_wrench, obs_fy_bw=obs.wrench[:, 1] / bw,
                 title='Routine' + (' (observations with faults)' if faults else ''))
    facts['messages'] = info.message_count
    facts['bag_bytes'] = sum(p.stat().st_size for p in folder.glob('*.mcap'))
    return facts
